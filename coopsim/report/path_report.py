"""The study behind `coopsim optimize --path`: the object path freed between the first and last waypoint poses.

    scenario → the B-spline path NLP under the scenario's time law (`coopsim.inverse.free_path`)
      → the retimed stage (path and time law in turn, `coopsim.inverse.retime.max_payload`)
      → independent checks: the optimum's capacity recomputed on the scenario's grid and a 4× finer one,
        the inverse dynamics rerun at (1 ∓ 1e-6) × that capacity, the retimed law against eq. 36 exactly,
        a forward-dynamics replay of the optimum's torques
      → the optimised scenario's object motion (two waypoints, the B-spline path, the sampled retimed law),
        the MCAP series of the paths before and after, the summary
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace

import numpy as np

from coopsim.core.labels import joint_labels
from coopsim.core.model import Model, ObjectMotion, torque_limits
from coopsim.core.spatial import rot_log
from coopsim.inverse import capacity as cap
from coopsim.inverse import retime as rt
from coopsim.inverse.free_path import PathOptimum, end_poses, optimize_path, spline_joint_path, weighted
from coopsim.inverse.path import WaypointPath, joint_path, path_grid
from coopsim.inverse.problem import inverse_problem
from coopsim.inverse.replay import Replay, replay
from coopsim.inverse.spline_path import straight_control_points
from coopsim.inverse.trajectory import object_motion_trajectory
from coopsim.io.mcap_codec import Series
from coopsim.report.inverse_report import Progress, _report
from coopsim.report.optimize_report import fine_check

FINER = 4                 # the recheck grid: the scenario's output_dt / FINER
FINE_LAW = 10             # the retimed law's check grid: this many points per grid interval


@dataclass(frozen=True, eq=False)
class PathStudy:
    """Everything `coopsim optimize --path` reports.

    Attributes:
        model: the Model.
        method: the resolution optimised for.
        optimum: the PathOptimum.
        own: the Capacity of the scenario's own path and time law (its output_dt grid).
        own_retimed_kg: kg, the heaviest payload the scenario's own path carries within the duration bound
            with its time law free (`coopsim.inverse.retime.max_payload`, its waypoint path); None when not
            asked (without the retimed stage).
        duration_bound: s, T_max.
        checks: the independent checks (see `path_checks`).
        motion: the optimised scenario's ObjectMotion: the retimed stage's path and sampled law, or the
            first stage's path under the scenario's time law.
    """

    model: Model
    method: str
    optimum: PathOptimum
    own: cap.Capacity
    own_retimed_kg: float | None
    duration_bound: float
    checks: dict
    motion: ObjectMotion


def path_study(model: Model, method: str = "min_energy", weights: bool = False, duration: float | None = None,
               retime: bool = True, replay_check: bool = True, progress: Progress | None = None) -> PathStudy:
    """The free-path study of a scenario, as `coopsim optimize --path` runs it.

    Args:
        model: the Model (an inverse.object_motion, finite motor limits; inverse.optimize).
        method: a linear resolution ('paper', 'nonsqueezing', 'min_energy') or 'lp' (the LP bound).
        weights: with 'min_energy', optimise its energy weights with the path.
        duration: s, T_max of the retimed stage; None: the waypoints' span.
        retime: also the retimed stage (and the scenario's own path retimed, for the gain).
        replay_check: also the forward-dynamics replay of the optimum (never for 'lp': no torques to replay).
        progress: hears the stages path, retime and check.

    Returns:
        PathStudy.

    Raises:
        coopsim.inverse.free_path.PathOptimizationError: the straight path is refused, or no start ends on
            a path the IK accepts.
        coopsim.inverse.retime.RetimeError: no motion carries the bare object within the bound.
    """
    om = model.inverse.object_motion
    T = float(om.times[-1] - om.times[0]) if duration is None else float(duration)
    opt = optimize_path(model, method, weights=weights, duration=T, retime=retime,
                        progress=lambda f: _report(progress, "path", f))
    _report(progress, "check", 0.0)
    res = opt.resolution
    own = trajectory_capacity(model, object_motion_trajectory(model, om), res, opt.mode)
    own_retimed = own_path_retimed(model, res, opt.mode, T) if retime else None
    motion = opt.motion if opt.retimed is None else rt.retimed_motion(opt.retimed_motion, opt.retimed.law)
    checks = path_checks(model, opt, motion, replay_check and method != rt.LP_BOUND)
    _report(progress, "check", 1.0)
    return PathStudy(model, method, opt, own, own_retimed, T, checks, motion)


def trajectory_capacity(model: Model, traj, res, mode: str) -> cap.Capacity:
    """The capacity of a resolution along a trajectory at its samples: `coopsim.inverse.capacity.method_capacity`,
    for the LP bound (res.method 'lp') `coopsim.inverse.capacity.lp_capacity`.

    Args:
        model: the Model (its payload position, motors).
        traj: the JointTrajectory.
        res: the Resolution (`coopsim.inverse.free_path.lp_resolution` for the LP bound).
        mode: 'scaled' or 'payload'.

    Returns:
        Capacity.
    """
    prob = inverse_problem(model, traj, model.inverse.payload_position)
    if res.method == rt.LP_BOUND:
        return cap.lp_capacity(prob, model.motors, res.passive, mode)
    return cap.method_capacity(prob, res, model.motors, mode)


def own_path_retimed(model: Model, res, mode: str, duration: float) -> float:
    """kg, the heaviest payload the scenario's own waypoint path carries within `duration`, its time law free.

    The grid has as many intervals per waypoint segment as the free path's grid has per unit of time
    (inverse.optimize.sample_dt), so both retimings are equally fine.

    Args:
        model: the Model.
        res: the Resolution (its method and weights).
        mode: 'scaled' or 'payload'.
        duration: s, T_max.

    Returns:
        float: kg (`coopsim.inverse.retime.max_payload`).

    Raises:
        coopsim.inverse.retime.RetimeError: no motion carries the bare object within the bound.
    """
    om = model.inverse.object_motion
    path = WaypointPath.of(om)
    span = float(om.times[-1] - om.times[0])
    per = max(1, int(round(span / model.inverse.optimize.sample_dt / (len(om.times) - 1))))
    s, piece = path_grid(path.knots, per)
    m = weighted(model, res)
    guess = model.q0 if om.initial_guess is None else om.initial_guess
    jp = joint_path(m, path, s, piece, guess, om.rest_posture, om.path_gain)
    return rt.max_payload(rt.path_dynamics(m, jp, res.method, mode), duration)[0]


def path_checks(model: Model, opt: PathOptimum, motion: ObjectMotion, replay_check: bool = True) -> dict:
    """Checks of the optimum that do not share the optimiser's grid or its closed form.

    * the first stage's path under the scenario's time law: its capacity recomputed on the scenario's
      output_dt grid and on one FINER times finer, and the inverse dynamics rerun with the payload (or
      object) at (1 ∓ 1e-6) × the scenario-grid capacity (`coopsim.inverse.capacity.brute_force_check`);
    * the retimed law: eq. 36 exactly at every grid point on both sides (`check_time_law`) and on a grid
      FINE_LAW times finer between them (`coopsim.report.optimize_report.fine_check`), and the capacity of
      the optimised scenario's motion (the sampled law) at its output_dt samples;
    * with `replay_check`, the first stage's torques at the scenario-grid capacity replayed open loop
      through the forward dynamics (`coopsim.inverse.replay.replay`): the largest joint-angle error and
      the largest excess of a torque over its line at the samples.

    Args:
        model: the Model.
        opt: the PathOptimum.
        motion: the optimised scenario's ObjectMotion.
        replay_check: also the replay.

    Returns:
        dict: scenario_grid_kg, finer_grid_kg, finer_dt_s, saturating_motor and saturating_time_s,
        brute_force (dict; None for the LP bound, which has no torque distribution to rerun), and with the retimed stage retimed_grid_excess, retimed_fine_excess (relative to
        τ_s) and retimed_scenario_kg, and with the replay replay_max_angle_error_rad, replay_max_line_excess
        (relative to τ_s).
    """
    m, res, mode = model, opt.resolution, opt.mode
    pos = model.inverse.payload_position
    traj = object_motion_trajectory(m, opt.motion)
    c = trajectory_capacity(m, traj, res, mode)
    dt = opt.motion.output_dt / FINER
    fine = trajectory_capacity(m, object_motion_trajectory(m, replace(opt.motion, output_dt=dt)), res, mode)
    out = {"scenario_grid_kg": c.mass, "finer_grid_kg": fine.mass, "finer_dt_s": dt,
           "saturating_motor": None if c.joint is None else joint_labels(m)[c.joint], "saturating_time_s": c.time,
           "brute_force": None if res.method == rt.LP_BOUND else cap.brute_force_check(m, traj, res, mode, c, pos)}
    if opt.retimed is not None:
        r = opt.retimed
        mw = weighted(m, res)
        grid = spline_joint_path(mw, opt.retimed_motion, r.law.s, r.law.piece)
        out["retimed_grid_excess"] = rt.check_time_law(rt.path_dynamics(mw, grid, res.method, mode), r)["max_excess"]
        fs, fp = path_grid(np.array([0.0, 1.0]), FINE_LAW * (len(r.law.s) - 1))
        fdyn = rt.path_dynamics(mw, spline_joint_path(mw, opt.retimed_motion, fs, fp), res.method, mode)
        out["retimed_fine_excess"] = fine_check(fdyn, r)["max_excess"]
        out["retimed_scenario_kg"] = trajectory_capacity(m, object_motion_trajectory(m, motion), res, mode).mass
    if replay_check:
        out |= _replay(m, traj, res, mode, c.mass)
    return out


def _replay(model: Model, traj, res, mode: str, mass: float) -> dict:
    """The torques of `res` with the load at `mass` replayed open loop along traj: angle error, line excess."""
    rep, excess = carried_replay(model, traj, res, mode, mass)
    return {"replay_max_angle_error_rad": float(rep.max_angle_error), "replay_max_line_excess": float(excess)}


def loaded_model(model: Model, mode: str, mass: float) -> Model:
    """The forward model carrying the load (`coopsim.inverse.capacity.scaled_model` or `payload_model`).

    Args:
        model: the Model (nominal object).
        mode: 'scaled' (mass: the whole object's) or 'payload' (mass: the point payload's, at the scenario's
            payload position).
        mass: kg.

    Returns:
        Model: the loaded model.
    """
    return (cap.scaled_model(model, mass) if mode == "scaled"
            else cap.payload_model(model, model.inverse.payload_position, mass))


def carried_replay(model: Model, traj, res, mode: str, mass: float, wrenches=None) -> tuple[Replay, float]:
    """The torques of `res` with the load at `mass` replayed open loop along a trajectory, and their excess.

    The forward model carries the load as one rigid body (`coopsim.inverse.capacity.scaled_model`, or
    `payload_model` at the scenario's payload position), which the MuJoCo twin holds as well (explicit
    inertia); the distribution's virtual bodies are the nominal object's, as in the capacity.

    Args:
        model: the Model (nominal object).
        traj: the JointTrajectory, at evenly spaced times.
        res: the Resolution (of the nominal model).
        mode: 'scaled' (mass: the whole object's) or 'payload' (mass: the point payload's).
        mass: kg.
        wrenches: InverseProblem ↦ grasp wrenches in place of res's distribution (the LP bound's,
            `coopsim.inverse.replay.stage_torques`); None: res's.

    Returns:
        tuple[Replay, float]: the Replay (`coopsim.inverse.replay.replay`; its SimResult's model is the
        loaded forward model) and the largest excess of a replayed torque over its motor line at the
        samples, relative to τ_s (≤ 0: within; nan without a simulation).
    """
    rep = replay(loaded_model(model, mode, mass), traj, res, wrenches)
    tau = rep.sim.tau if rep.sim is not None else np.full_like(traj.q, np.nan)
    lo, hi = torque_limits(model.motors, traj.qd)
    act = ~res.passive & np.isfinite(model.motors.stall_torque)
    return rep, float(np.max((np.maximum(tau - hi, lo - tau) / model.motors.stall_torque)[:, act]))


def path_summary(study: PathStudy) -> dict:
    """JSON-ready summary of a free-path study (SI units): optimize.json's "path" entry.

    Args:
        study: the PathStudy.

    Returns:
        dict: method, mode, duration bound, control points and unknowns, the payloads (the scenario's own
        path and law and the free path under it on the scenario's output_dt grid; the straight path and the
        free path on the optimiser's grid; the own path and the free path retimed on their retiming grids)
        and the gains of the free path retimed, the grids, the solver (SLSQP) statistics per run, the
        gradient cost, the checks, wall time.
    """
    o = study.optimum
    own, free = study.own.mass, study.checks["scenario_grid_kg"]
    retimed = None if o.retimed is None else o.retimed.mass
    best = retimed if retimed is not None else free

    def gain(over):
        return None if over is None or not np.isfinite(over) or over <= 0 else best / over

    return {
        "method": study.method, "mode": o.mode, "duration_bound_s": study.duration_bound,
        "control_points": len(o.motion.path.positions), "unknowns": o.unknowns,
        "weights": [float(w) for w in o.resolution.weights],
        "payload_kg": {"own_path": own, "own_path_retimed": study.own_retimed_kg, "straight_path": o.straight.mass,
                       "free_path_scenario_law": free, "free_path_scenario_law_optimiser_grid": o.capacity.mass,
                       "free_path_retimed": retimed},
        "grids": {"scenario_law_s": study.model.inverse.object_motion.output_dt,
                  "optimiser_s": study.model.inverse.optimize.sample_dt,
                  "retimed_intervals": None if o.retimed is None else len(o.retimed.law.s) - 1},
        "gain": {"over_own_path": gain(own), "over_own_path_retimed": gain(study.own_retimed_kg)},
        "success": bool(o.best.success),
        "solver": {"name": "scipy SLSQP", "runs": [vars(r) | {"kind": "fixed_law" if i >= _first_stage(o) else "start"}
                                                   for i, r in enumerate(o.starts)],
                   "starts": study.model.inverse.optimize.starts, "seed": study.model.inverse.optimize.seed,
                   "retime_rounds": [{"mass_kg": r["mass_kg"], "duration_s": r["retiming"].duration}
                                     | ({"note": r["note"]} if "note" in r else {}) for r in o.retime_rounds]},
        "gradient": {"evaluation_s": o.eval_s, "jacobian_s": o.jacobian_s,
                     "jacobian_evaluations": o.unknowns + 1, "method": "forward differences"},
        "checks": study.checks,
        "wall_s": o.wall_s,
    }


def _first_stage(o: PathOptimum) -> int:
    """The number of first-stage runs (the rest are the retimed rounds' fixed-law runs)."""
    return len(o.starts) - sum(r["run"] is not None for r in o.retime_rounds)


def format_path_summary(s: dict) -> str:
    """Short text version of `path_summary`.

    Args:
        s: the summary dict.

    Returns:
        str: the lines of the report.
    """
    p, c = s["payload_kg"], s["checks"]

    def kg(x):
        return "—" if x is None else f"{x:.4f} kg"

    lines = [f"free path       {s['method']}, {s['mode']} mass, {s['control_points']} control points "
             f"({s['unknowns']} unknowns), T_max {s['duration_bound_s']:g} s, {len(s['solver']['runs'])} SLSQP runs, "
             f"{s['wall_s']:.1f} s",
             f"  own path {kg(p['own_path'])}, retimed {kg(p['own_path_retimed'])}; straight {kg(p['straight_path'])}; "
             f"free path {kg(p['free_path_scenario_law'])} (scenario's law), {kg(p['free_path_retimed'])} (retimed)",
             f"  check: optimiser grid {kg(p['free_path_scenario_law_optimiser_grid'])}, {c['finer_dt_s']:g} s grid "
             f"{kg(c['finer_grid_kg'])}, "
             + ("brute force n/a (the LP bound has no torque distribution to rerun)" if c["brute_force"] is None
                else f"brute force {'ok' if c['brute_force']['ok'] else 'FAILED'}")]
    if "retimed_grid_excess" in c:
        lines.append(f"  retimed law: eq. 36 excess {c['retimed_grid_excess']:.2e} (grid), "
                     f"{c['retimed_fine_excess']:.2e} (10x finer); the written scenario carries "
                     f"{kg(c['retimed_scenario_kg'])} at its samples")
    if "replay_max_angle_error_rad" in c:
        lines.append(f"  replay: {c['replay_max_angle_error_rad']:.2e} rad, line excess "
                     f"{c['replay_max_line_excess']:.2e}")
    return "\n".join(lines)


def path_series(study: PathStudy) -> list:
    """Series for the MCAP log of a free-path study: the object's path before and after.

    /optimize/path/{own, straight, free, free_retimed}: p_C (m, world) and the rotation vector from the
    first waypoint's orientation (rad, world axes) at the samples of each motion.

    Args:
        study: the PathStudy.

    Returns:
        list[Series]: SI units.
    """
    m, o = study.model, study.optimum
    om = m.inverse.object_motion
    ends = end_poses(om)
    motions = {"own": om, "straight": replace(ends, path=straight_control_points(ends, len(o.motion.path.positions))),
               "free": o.motion}
    if o.retimed is not None:
        motions["free_retimed"] = study.motion
    out = []
    for name, motion in motions.items():
        traj = object_motion_trajectory(m, motion)
        prob = inverse_problem(m, traj)
        phi = np.array([rot_log(R @ om.rotations[0].T) for R in prob.R_o])
        out.append(Series(f"/optimize/path/{name}", "coopsim.optimize.Path", traj.t - traj.t[0],
                          {"p_C": prob.p_C, "rotation_vector": phi}))
    return out


def path_scenario(data: dict, motion: ObjectMotion) -> dict:
    """The scenario's data with its object motion replaced by the optimised free path.

    Args:
        data: the scenario file's data (as read, with any --set applied).
        motion: the optimised ObjectMotion (two waypoints, a B-spline path; a sampled or the scenario's
            time law).

    Returns:
        dict: a copy; inverse.object_motion keeps its other keys, its waypoints are the first and the last
        (their times the motion's), path {kind: bspline, control_points}, and a sampled law's
        time_law_samples when the motion has one.
    """
    out = copy.deepcopy(data)
    om = out["inverse"]["object_motion"]
    wps = [om["waypoints"][0], om["waypoints"][-1]]
    for wp, t in zip(wps, motion.times):
        wp["time"] = float(t)
    om["waypoints"] = wps
    om["path"] = {"kind": "bspline", "control_points": [
        {"position": [float(x) for x in p], "rotation_vector": [float(x) for x in f]}
        for p, f in zip(motion.path.positions, motion.path.rotation_vectors)]}
    om.pop("time_law_samples", None)
    if motion.time_law == "sampled":
        om["time_law"] = "sampled"
        om["rest_pull"], om["rest_gain"] = motion.rest_pull, float(motion.rest_gain)
        om["time_law_samples"] = {"t": [float(x) for x in motion.samples.t], "s": [float(x) for x in motion.samples.s],
                                  "rate": [float(x) for x in motion.samples.rate]}
    return out


def path_metadata(summary: dict) -> dict:
    """MCAP metadata record "optimize_path" of a free-path study (not "optimize.path": the optimize.<method>
    records are the retiming's): the payloads and the solver's outcome.

    Args:
        summary: the free-path summary (`path_summary`).

    Returns:
        dict: record name → a dict of the summary.
    """
    return {"optimize_path": {"method": summary["method"], "mode": summary["mode"], **summary["payload_kg"],
                              "success": summary["success"], "wall_s": summary["wall_s"]}}
