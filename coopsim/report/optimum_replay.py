"""The optimum of `coopsim optimize --replay` replayed through the forward dynamics, native and MuJoCo twin,
open loop: the retimed fixed path (`--retime`) and the free path (`--path`) alike.

    the optimised scenario's motion (the retimed path's time law, the asked payload's else the heaviest
      load's; or the free path's B-spline and sampled law) and its load
      → the joint path sampled evenly over the law's duration (the closed-chain IK of the retimed motion)
      → the resolution's torques with the load carried as one rigid body, tabulated at the native
        integrator's stage times (`coopsim.report.path_report.carried_replay`)
      → the native run from the first sample (DOP853 at fixed steps of one sample interval)
      → the twin from the same state on the same torques (`coopsim.twin.harness.cross_validate`)
      → the agreement against the scenario's thresholds, and the run log `coopsim animate` draws
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from coopsim.core.model import Model, ObjectMotion, TorqueTable
from coopsim.forward.simulate import SimResult
from coopsim.inverse import retime as rt
from coopsim.inverse.free_path import lp_resolution
from coopsim.inverse.lp_replay import LPWrenches, lp_distribution, lp_wrenches, sample_wrenches
from coopsim.inverse.problem import inverse_problem
from coopsim.inverse.problem import Resolution
from coopsim.inverse.replay import Replay, stage_torques
from coopsim.inverse.solve import resolution_for
from coopsim.inverse.trajectory import JointTrajectory, object_motion_trajectory
from coopsim.io.log import run_log
from coopsim.report.inverse_report import Progress, _report
from coopsim.report.optimize_report import RetimeStudy, with_motion
from coopsim.report.path_report import PathStudy, carried_replay, loaded_model
from coopsim.twin.harness import CrossValidation, cross_validate
from coopsim.twin.weld import twin_step

RUN_LOG = "optimum_run.mcap"            # the retimed optimum's run log in the optimize output set
PATH_RUN_LOG = "optimum_path_run.mcap"  # the free path's


@dataclass(frozen=True, eq=False)
class OptimumReplay:
    """The optimum replayed open loop: the native run against the optimised joint path, the twin against it.

    Attributes:
        source: 'retimed' (the fixed path retimed, `--retime`) or 'free_path' (`--path`).
        method: the resolution whose torques are replayed (the optimised scenario's).
        mode: 'payload' (mass: a point payload's) or 'scaled' (mass: the whole object's).
        mass: kg, the load carried.
        traj: the JointTrajectory of the optimised path under the time law, evenly sampled.
        native: the native Replay (its SimResult's model: the loaded forward model with the torque tables).
        line_excess: the largest excess of a replayed torque over its motor line at the samples, relative
            to τ_s (≤ 0: within).
        cross: the CrossValidation of the twin against the native replay (scenario thresholds).
        twin_model: the twin's Model (its step, the torques tabulated at its RK4 stage times).
        log: the run log's file name in the output set.
        resolution: the Resolution whose torques are replayed (its weights and virtual bodies).
        distribution: the LP bound's distribution at the samples (`lp_distribution_summary`), or None (a
            linear resolution).
    """

    source: str
    method: str
    mode: str
    mass: float
    traj: JointTrajectory
    native: Replay
    line_excess: float
    cross: CrossValidation
    twin_model: Model
    log: str = RUN_LOG
    resolution: Resolution | None = None
    distribution: dict | None = None


def optimum_replay(study: RetimeStudy, progress: Progress | None = None) -> OptimumReplay:
    """Replay the retiming study's optimum (the law the optimised scenario carries) native and in the twin.

    Args:
        study: the RetimeStudy (method a linear resolution or the LP bound).
        progress: hears the stages replay (the IK and native run) and mujoco.

    Returns:
        OptimumReplay (`motion_replay` of the study's motion at its law's mass; with `--weights` the minimum
        energy's torques with the weights optimised with the law; the LP bound's wrenches those of its law,
        `coopsim.inverse.lp_replay`).

    Raises:
        coopsim.inverse.retime.RetimeError: the resolution has no torques somewhere along the law.
    """
    law = study.methods[study.method].law_of
    if study.method == rt.LP_BOUND:
        return motion_replay(study.model, study.motion, lp_resolution(study.model), study.mode, law.mass, "retimed",
                             progress, lp_wrenches(law))
    weighted = study.weights is not None and study.method == "min_energy"
    res = resolution_for(study.weights.model if weighted else study.model, study.method)
    return motion_replay(study.model, study.motion, res, study.mode, law.mass, "retimed", progress)


def path_replay(study: PathStudy, progress: Progress | None = None) -> OptimumReplay:
    """Replay the free-path study's optimum (the written scenario's B-spline path and law) native and in the twin.

    The load is the retimed stage's payload (without that stage: the first stage's capacity on the
    scenario's grid), carried with the optimised resolution (its weights, with `--weights`; the LP bound: the
    retimed law's wrenches, without that stage each sample's least-excess distribution).

    Args:
        study: the PathStudy.
        progress: hears the stages replay and mujoco.

    Returns:
        OptimumReplay (`motion_replay`, source 'free_path', log PATH_RUN_LOG).

    Raises:
        coopsim.inverse.retime.RetimeError: the resolution has no torques somewhere along the law.
    """
    o = study.optimum
    mass = o.retimed.mass if o.retimed is not None else study.checks["scenario_grid_kg"]
    lp = lp_wrenches(o.retimed) if o.resolution.method == rt.LP_BOUND and o.retimed is not None else None
    return motion_replay(study.model, study.motion, o.resolution, o.mode, mass, "free_path", progress, lp)


def motion_replay(model: Model, motion: ObjectMotion, res: Resolution, mode: str, mass: float, source: str,
                  progress: Progress | None = None, lp: LPWrenches | None = None) -> OptimumReplay:
    """Replay an optimised object motion carrying `mass` with the torques of `res`, native and MuJoCo twin.

    The samples are spaced evenly at the motion's output_dt shortened so that a whole number of them spans
    the law's duration, and a scenario's `mujoco.timestep` is shortened so that whole steps span a sample
    (the twin's steps must divide every interval).

    Args:
        model: the Model (nominal object; its validation thresholds judge the twin).
        motion: the optimised ObjectMotion (waypoints or a B-spline path; its time law).
        res: the Resolution (a linear one: paper, nonsqueezing, min_energy; its weights; or method 'lp', the LP
            bound: `coopsim.inverse.lp_replay.lp_distribution` with `lp`).
        mode: 'payload' (mass: a point payload's at inverse.payload_position) or 'scaled' (the object's).
        mass: kg, the load carried.
        source: 'retimed' or 'free_path' (the run log's name: RUN_LOG, PATH_RUN_LOG).
        progress: hears the stages replay (the IK and native run) and mujoco.
        lp: the LP bound's wrenches on its law (method 'lp'); None: each sample's least-excess distribution.

    Returns:
        OptimumReplay.

    Raises:
        coopsim.inverse.retime.RetimeError: the resolution has no torques somewhere along the law.
    """
    span = float(motion.times[-1] - motion.times[0])
    dt = span / np.ceil(span / motion.output_dt - 1e-9)
    model = with_motion(model, replace(motion, output_dt=dt))
    _report(progress, "replay", 0.0)
    traj = object_motion_trajectory(model, model.inverse.object_motion)
    wrenches = None
    if res.method == rt.LP_BOUND:
        rel = replace(traj, t=traj.t - traj.t[0])
        lp = None if lp is None else lp.resampled(rel.t)
        knots = sample_wrenches(inverse_problem(loaded_model(model, mode, mass), rel), lp, model.motors, res.passive)

        def wrenches(prob):
            return lp_distribution(prob, knots, model.motors, res.passive, correct=False).f
    rep, excess = carried_replay(model, traj, res, mode, mass, wrenches)
    if rep.sim is None:
        raise rt.RetimeError(f"--replay: the {res.method} resolution has no torques at t = "
                             f"{rep.failures[0].time:.6g} s of the optimum")
    _report(progress, "replay", 1.0)
    native = rep.sim
    twin_model = _twin_model(native, traj, res, wrenches)
    cv = cross_validate(native.model, native=native, twin_model=twin_model, progress=progress)
    dist = None if wrenches is None else lp_distribution_summary(native.model, traj, lp, res)
    return OptimumReplay(source, res.method, mode, mass, traj, rep, excess, cv, twin_model,
                         RUN_LOG if source == "retimed" else PATH_RUN_LOG, res, dist)


def lp_distribution_summary(model: Model, traj: JointTrajectory, lp: LPWrenches | None, res: Resolution) -> dict:
    """The LP bound's distribution at the replay's samples (`coopsim.inverse.lp_replay.lp_distribution`).

    Args:
        model: the loaded forward model (the native replay's).
        traj: the JointTrajectory replayed.
        lp: the LP bound's wrenches on its law, or None.
        res: the Resolution (method 'lp'; its passive joints).

    Returns:
        dict: interpolated (the LP's wrenches interpolated between its grid points, else the least-norm ones),
        samples, corrected_samples (those whose nearest wrenches within the lines replaced the interpolant),
        without_distribution_samples (those where no distribution keeps the lines widened by
        `coopsim.inverse.retime.REFINE_TOL`), interpolant_max_line_excess and max_line_excess (relative to τ_s;
        ≤ 0: within), and
        max_wrench_residual (max |A f − y| over |y|'s peak, with the passive torques: the object wrench equation).
    """
    prob = inverse_problem(model, replace(traj, t=traj.t - traj.t[0]))
    d = lp_distribution(prob, lp, model.motors, res.passive)
    Aeq = np.concatenate([prob.A, prob.JT[:, res.passive, :]], 1)
    rhs = np.concatenate([prob.y, -prob.tau_arms[:, res.passive]], 1)
    miss = float(np.max(np.abs(np.einsum("nqi,ni->nq", Aeq, d.f) - rhs)) / max(float(np.max(np.abs(rhs))), 1e-300))
    return {"interpolated": lp is not None, "samples": len(d.f), "corrected_samples": int(np.sum(d.corrected)),
            "without_distribution_samples": int(np.sum(np.isfinite(d.least))),
            "interpolant_max_line_excess": float(np.max(d.interpolant_excess)),
            "max_line_excess": float(np.max(d.excess)), "max_wrench_residual": miss}


def _twin_model(native: SimResult, traj: JointTrajectory, res: Resolution, wrenches=None) -> Model:
    """The twin's model: its step (`coopsim.twin.weld.twin_step`) and the same torques tabulated at the native
    knots (the native tables' values) and at every RK4 stage time of the twin's steps too, so that neither reads
    an interpolated torque (`wrenches`: the grasp wrenches in place of res's, `stage_torques`)."""
    model, _ = twin_step(_dividing_step(native.model), native)
    h, t = model.mujoco.timestep, native.t
    steps = np.maximum(np.round(np.diff(t) / h).astype(int), 1)
    stages = [t0 + (t1 - t0) * np.arange(2 * k + 1) / (2 * k) for t0, t1, k in zip(t[:-1], t[1:], steps)]
    old = native.model.torques[0].times
    knots = np.unique(np.concatenate([old, *stages]))
    new = ~np.isin(knots, old)
    tau = np.empty((len(knots), model.n_total))
    tau[~new] = np.hstack([tt.values for tt in native.model.torques])
    tau[new] = stage_torques(native.model, traj, res, knots[new], wrenches=wrenches)
    return replace(model, torques=tuple(TorqueTable(knots, tau[:, sl]) for sl in model.dof_slices))


def _dividing_step(model: Model) -> Model:
    """The model with its `mujoco.timestep` (when set) shortened to the largest step that divides its output_dt
    into whole steps (None: left to `twin_step`)."""
    h, dt = model.mujoco.timestep, model.integrator.output_dt
    if h is None:
        return model
    return replace(model, mujoco=replace(model.mujoco, timestep=dt / np.ceil(dt / h - 1e-9)))


def replay_summary(rep: OptimumReplay) -> dict:
    """optimize.json's "replay" entry (SI units).

    Args:
        rep: the OptimumReplay.

    Returns:
        dict: source, method, mode, mass, duration, samples and their interval; native (the largest joint angle
        and rate errors against the optimised joint path, the largest line excess relative to τ_s); twin
        (its step, the agreement with the native replay against the scenario's thresholds,
        `coopsim.twin.compare.Comparison.as_dict`, its largest joint angle error and whether it passed);
        the run log's name; for the LP bound "lp_distribution" (`lp_distribution_summary`).
    """
    cv = rep.cross
    angle = next(m for m in cv.comparison.metrics if m.name == "joint angle error")
    return {
        "source": rep.source, "method": rep.method, "mode": rep.mode, "mass_kg": rep.mass,
        "duration_s": float(rep.traj.t[-1] - rep.traj.t[0]), "samples": len(rep.traj.t),
        "output_dt_s": float(rep.traj.t[1] - rep.traj.t[0]), "open_loop": True,
        "native": {"max_angle_error_rad": rep.native.max_angle_error, "max_rate_error_rad_s": rep.native.max_rate_error,
                   "max_line_excess": rep.line_excess, "integrator": "dop853, fixed step = output_dt_s"},
        "twin": {"timestep_s": (cv.mujoco or cv.native.model.mujoco).timestep,
                 "max_angle_error_rad": angle.max, "threshold_rad": angle.threshold,
                 "passed": cv.comparison.passed, "agreement": cv.comparison.as_dict()},
        "log": rep.log,
    } | ({} if rep.distribution is None else {"lp_distribution": rep.distribution})


def replay_run_log(rep: OptimumReplay, metadata: dict | None = None, extra_series=()) -> tuple[list, dict]:
    """(streams, metadata) of the replay's run log, as `coopsim run` writes one (`coopsim.io.log.run_log`).

    Args:
        rep: the OptimumReplay.
        metadata: `run_metadata`'s extra (e.g. {"scenario": {"file": …, "sha256": …}}, which `coopsim animate`
            takes the geometry from).
        extra_series: more series after the open loop's (the closed-loop replay's,
            `coopsim.report.closed_replay.closed_series`).

    Returns:
        tuple[list, dict]: the native and twin series, `extra_series`, /tf and /scene, and the metadata records (the loaded
        forward model's, with the twin's settings as it ran), with record "payload": mass_kg, mode, source
        and position_m (the point payload's, object frame from the scenario object's centre of mass; null
        when scaled), which `coopsim animate` draws on the scenario's object.
    """
    cv = rep.cross
    model = cv.native.model
    pos = model.inverse.payload_position if rep.mode == "payload" else None
    payload = {"mass_kg": rep.mass, "mode": rep.mode, "source": rep.source,
               "position_m": None if pos is None else np.asarray(pos, dtype=float)}
    return run_log(replace(model, mujoco=cv.mujoco), cv.native, cv.twin, extra_series,
                   dict(metadata or {}) | {"payload": payload})


def format_replay_summary(s: dict) -> str:
    """Short text version of `replay_summary`.

    Args:
        s: the "replay" entry.

    Returns:
        str: two lines, the native replay against the optimised path and the twin against the native run (the LP
        bound: a third, its wrenches between the grid points).
    """
    tw = s["twin"]
    verdict = "PASS" if tw["passed"] else "FAIL: " + "; ".join(
        f"{k} {m['max']:.3g} > {m['threshold']:.3g}" for k, m in tw["agreement"]["metrics"].items() if not m["passed"])
    head = "replay (free)  " if s.get("source") == "free_path" else "replay         "
    return (f"{head} {s['method']}, {s['mass_kg']:.6g} kg over {s['duration_s']:.6g} s open loop: native "
            f"{s['native']['max_angle_error_rad']:.2e} rad from the optimised path, line excess "
            f"{s['native']['max_line_excess']:.2e} τ_s\n"
            f"                twin (step {tw['timestep_s']:.3g} s) {tw['max_angle_error_rad']:.2e} rad from the native "
            f"run (threshold {tw['threshold_rad']:.3g}): {verdict}" + _lp_line(s.get("lp_distribution")))


def _lp_line(d: dict | None) -> str:
    """The LP bound's distribution line of `format_replay_summary` ('' for a linear resolution)."""
    if d is None:
        return ""
    return (f"\n                LP wrenches {'interpolated' if d['interpolated'] else 'least-norm'}, "
            f"{d['corrected_samples']} of {d['samples']} samples moved within the lines (interpolant "
            f"{d['interpolant_max_line_excess']:.2e} τ_s over), {d['without_distribution_samples']} where none is")
