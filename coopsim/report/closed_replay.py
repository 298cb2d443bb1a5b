"""The optimum of `coopsim optimize --replay` replayed in closed loop, where open loop it does not hold.

A pose held against gravity (the Panda carry) is open-loop unstable: the optimum's torques replayed open
loop drift away from the optimised path at the rate of its unstable modes, however exact they are. The
closed-loop replay puts feedback about the optimised motion around the optimum's torques, by one of two laws
(`coopsim.control.controller.Controller` in the loop, compiled, native and twin from the same state).

Computed torque, where the scenario's `control:` law is computed_torque and its arms allow it (as many
joints as constrained rows; the Controller refuses a redundant arm such as the Panda's): the scenario's law
on the loaded model (the controller's model exact: mass_scale 1), its reference the optimum's object motion
(the retimed sampled law or the B-spline path, as written to the optimised scenario), its distribution the
optimum's resolution (`OptimumReplay.resolution`: its weights and virtual bodies), no squeeze, the
scenario's object and grasp gains. The loaded model merges a point payload into the object body, whose frame
sits at the composite centre of mass, c = m p / (m_o + m) from the nominal C in object axes
(`coopsim.inverse.capacity.payload_centre`; zero when the object is scaled); the law's reference is moved to
that body point (`coopsim.inverse.trajectory.body_point_state`), so that the frame follows p_C(t) + R(t) c
and the nominal C the optimised path. At zero error the law's torque is then the loaded closed-chain inverse
dynamics of the optimised motion distributed by the optimum's resolution: τ_opt itself (at the samples;
between them τ_opt is that of the joint path's quintic Hermite interpolant), so the optimum is the law's
feedforward and the torque tables are dropped.

Joint PD otherwise (no control: section, a joint_pd law, or arms computed torque refuses):

    τ(t, θ, θ̇) = τ_opt(t) + Kp (θ_r(t) − θ) + Kd (θ̇_r(t) − θ̇),

τ_opt the resolution's torques with the load (the open-loop replay's tables, feedforward), θ_r the
optimised joint path (the closed-chain IK of the optimum, not the loaded plant's own IK: the merged body's
frame sits at the composite centre of mass), run as the scenario's joint_pd law with reference the given
trajectory and compensation none (the feedforward replaces it). The gains:

  * the scenario's `control:` joint_pd gains (kp, kd) when it has that law;
  * otherwise Kp = ω² I_jj, Kd = 2ζω I_jj, I_jj the diagonal of each arm's joint-space inertia
    (`coopsim.dynamics.gibbs_appell.mass_matrix`) at the first sample — a computed-torque law with the
    inertia frozen and diagonal — with ω², 2ζω the scenario's computed_torque object gains (object_kp,
    object_kd, linear) when it has that law, else ζ = 1 and ω the first of OMEGAS (10, 30 rad/s) whose
    native closed loop stays within the scenario's validation.max_angle_error of the optimised path (the
    last where none does; each try is reported). A frozen diagonal law ignores the gravity stiffness and
    the closed chain's coupling: a pair hanging from the ceiling with a heavy load (the UR5 pair) grows
    under ω = 10 rad/s as its open loop does, only slower. Stiffer is not better where the loop is stable
    (the error is then the feedforward's between the law's grid points), and the native run takes fixed
    steps of one sample: the diagonal law's fastest closed-chain mode is faster than ω, and at 50 rad/s
    on 20 ms samples (the Panda carry) the fixed-step native loop diverges; hence no third try.

Either way `saturate` is the scenario's (default off, so that the total torque's excess over its lines is
reported, not hidden), and the scenario's torque tables, squeeze and mass_scale do not apply (with joint PD
neither do its distribution and grasp gains): the feedforward is the optimum's, on the loaded model. The
native joint PD loop takes fixed DOP853 steps of one sample, as the open loop; the native computed-torque
loop adaptive ones at a hundredth of the scenario's tolerances (CT_TOLERANCE): a sampled law's acceleration
jumps at its samples, which fall between the replay's, and the law follows it; a step across a jump loses
its order, and at the scenario's own tolerances the error estimate lets such steps through. The tracking is
measured against the optimised path: the joint angles against its joint path, the loaded object's frame
against its forward kinematics along it, and with computed torque the law's own pose error at the tracked
point.

Both closed-loop runs go into the optimum's run log beside the open loop's (`closed_series`: the topics
under `coopsim.io.log.CLOSED_LOOP`, read back by `coopsim.io.log.read_run_log` and drawn by
`coopsim animate LOG --closed-loop`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from coopsim.control.controller import ControlError, Controller, record
from coopsim.core.model import COMPILED_DISTRIBUTIONS, ControlSettings, Model, TorqueFeedback, TorqueTable, torque_at, torque_limits
from coopsim.core.spatial import orientation_error, rots_to_quats
from coopsim.dynamics.closed_chain import arm_poses
from coopsim.dynamics.gibbs_appell import mass_matrix
from coopsim.forward.simulate import SimResult, simulate
from coopsim.inverse.capacity import payload_centre
from coopsim.io.log import CLOSED_LOOP, control_series, simulation_series, twin_series
from coopsim.inverse.problem import inverse_problem
from coopsim.report.optimum_replay import OptimumReplay, format_replay_summary, replay_summary
from coopsim.twin.compare import Comparison, compare
from coopsim.twin.mujoco_run import TwinResult, run_twin

CLOSED_NATIVE, CLOSED_TWIN = CLOSED_LOOP + "/native", CLOSED_LOOP + "/mujoco"   # the closed loop's topic prefixes
LAWS = {"joint_pd": "tau_opt(t) + Kp (q_r - q) + Kd (qd_r - qd)",       # the laws as the summary and the log name them
        "computed_torque": "the scenario's computed torque about the optimum's object motion (tracked at the loaded "
                           "frame's point), distributed by the optimum's resolution: tau_opt at zero error"}
OMEGAS = (10.0, 30.0)   # rad/s, the default law's natural frequencies (critically damped), tried in turn
DEFAULT_OMEGA = OMEGAS[0]
CT_TOLERANCE = 1e-2     # the native computed-torque loop's integrator tolerances relative to the scenario's


@dataclass(frozen=True, eq=False)
class ClosedReplay:
    """The optimum replayed under feedback about the optimised motion (module docstring).

    Attributes:
        why: why it was run: 'open loop outside the thresholds', "the scenario's control: section" or 'asked'.
        gains: where the gains come from (a sentence).
        kp, kd: joint_pd: (n,) N·m/rad, N·m·s/rad (N/m, N·s/m on a prismatic joint); computed_torque: the
            object gains (2,) [linear, angular] 1/s², 1/s.
        native: the native closed-loop SimResult (joint_pd: fixed DOP853 steps of one sample, as the open loop;
            computed_torque: adaptive DOP853 at CT_TOLERANCE times the scenario's tolerances, module docstring).
        twin: the twin's closed-loop TwinResult.
        comparison: the twin against the native closed loop (the scenario's thresholds).
        feedforward: (N, n) N·m, τ_opt at the samples.
        tau: (N, n) N·m, the native closed loop's applied torques at the samples.
        twin_tau: (N, n) N·m, the twin's applied torques at its samples.
        reference: (p (N, 3) m, quaternions (N, 4) [w, x, y, z]) of the loaded object along the optimised
            joint path (its forward kinematics).
        saturation_events: (sample, joint) pairs the motor lines clipped (native), with `saturate`.
        control: the law evaluated along each run (`coopsim.control.controller.record`: joint_pd's reference
            and angle error, computed_torque's object pose and twist errors, command, applied torque), native
            and twin.
        tries: ((ω rad/s, the native closed loop's largest joint error rad), …) of the default law's tries
            in order, the last the one kept; empty with the scenario's gains.
        law: 'joint_pd' or 'computed_torque'.
        point: (3,) m, computed_torque's tracked point c, object axes from the nominal C (the loaded frame's
            origin); zeros with joint_pd.
    """

    why: str
    gains: str
    kp: np.ndarray
    kd: np.ndarray
    native: SimResult
    twin: TwinResult
    comparison: Comparison
    feedforward: np.ndarray
    tau: np.ndarray
    twin_tau: np.ndarray
    reference: tuple
    saturation_events: int
    control: tuple = ()
    tries: tuple = ()
    law: str = "joint_pd"
    point: np.ndarray = field(default_factory=lambda: np.zeros(3))


def closed_loop_reason(model: Model, rep: OptimumReplay, asked: bool = False) -> str | None:
    """Why the optimum is also replayed in closed loop, or None.

    Args:
        model: the scenario's Model (its validation thresholds and control section).
        rep: the open-loop `coopsim.report.optimum_replay.OptimumReplay`.
        asked: the user asked for it (--closed-loop).

    Returns:
        str | None: 'asked', 'open loop outside the thresholds' (the native run farther than
        validation.max_angle_error from the optimised path, or the twin failing a threshold), "the scenario's
        control: section", or None.
    """
    if asked:
        return "asked"
    if rep.native.max_angle_error > model.validation.max_angle_error or not rep.cross.comparison.passed:
        return "open loop outside the thresholds"
    if model.control is not None:
        return "the scenario's control: section"
    return None


def feedback_gains(model: Model, q0: np.ndarray, omega: float = DEFAULT_OMEGA) -> tuple[np.ndarray, np.ndarray, str]:
    """The feedback gains of the closed-loop replay (module docstring).

    Args:
        model: the scenario's Model (its control section, its arms).
        q0: (n,) rad, the first sample of the optimised joint path (where the inertia is frozen).
        omega: rad/s, the default law's natural frequency (without a control: section).

    Returns:
        tuple: kp (n,) N·m/rad, kd (n,) N·m·s/rad, and a sentence saying where they come from.
    """
    c = model.control
    if c is not None and c.law == "joint_pd":
        return np.asarray(c.kp, float), np.asarray(c.kd, float), "the scenario's control: joint_pd gains"
    inertia = np.concatenate([np.diag(mass_matrix(arm, pose)) for arm, pose in zip(model.arms, arm_poses(model, q0))])
    if c is not None:
        w2, zw = float(c.object_kp[0]), float(c.object_kd[0])
        where = f"the scenario's computed_torque object gains ({w2:g}/s², {zw:g}/s) per unit joint inertia"
    else:
        w2, zw = omega**2, 2.0 * omega
        where = f"ω = {omega:g} rad/s, ζ = 1 per unit joint inertia (no control: section)"
    return w2 * inertia, zw * inertia, f"Kp = ω² I_jj, Kd = 2ζω I_jj, I_jj each arm's inertia diagonal at the " \
                                       f"first sample: {where}"


def closed_loop_replay(model: Model, rep: OptimumReplay, why: str) -> ClosedReplay:
    """Replay the optimum in closed loop, native and twin: under the scenario's computed_torque law where it can
    run (`computed_torque_loop`), else τ_opt(t) + joint PD about the optimised joint path (module docstring).

    Args:
        model: the scenario's Model (its control section, saturate).
        rep: the open-loop OptimumReplay (its tables: the native model's at the DOP853 stage times, the
            twin's at its RK4 stage times; its joint path, motion and resolution).
        why: `closed_loop_reason`'s answer.

    Returns:
        ClosedReplay (joint PD without a control: section: the first of OMEGAS whose native loop holds
        validation.max_angle_error, else the last; `tries` lists them).
    """
    ct = computed_torque_loop(model, rep)
    if ct is not None:
        c = model.control
        where = f"the scenario's computed_torque object gains ({c.object_kp[0]:g}, {c.object_kp[1]:g}/s²; " \
                f"{c.object_kd[0]:g}, {c.object_kd[1]:g}/s) on the loaded model, the {rep.method} resolution"
        return replace(_closed_run(model, rep, why, np.asarray(c.object_kp, float), np.asarray(c.object_kd, float),
                                   where, *ct), law="computed_torque", point=ct[0].point)
    if model.control is not None:
        kp, kd, where = feedback_gains(model, rep.traj.q[0])
        return _closed_run(model, rep, why, kp, kd, where, *_native_loop(model, rep, kp, kd))
    tries = []
    for omega in OMEGAS:                      # the native loop decides; the twin runs once, at the gains kept
        kp, kd, where = feedback_gains(model, rep.traj.q[0], omega)
        loop = _native_loop(model, rep, kp, kd)
        tries.append((omega, float(np.max(np.abs(loop[2].q - rep.traj.q)))))
        if tries[-1][1] <= model.validation.max_angle_error:
            break
    return replace(_closed_run(model, rep, why, kp, kd, where, *loop), tries=tuple(tries))


def tracked_point(model: Model, rep: OptimumReplay) -> np.ndarray:
    """Where the loaded model's object frame sits relative to the nominal centre of mass C.

    Args:
        model: the scenario's Model (nominal object, inverse.payload_position).
        rep: the OptimumReplay (its mode and load).

    Returns:
        np.ndarray: (3,) m, object axes: the composite centre of a point payload (`payload_centre`), zero
        for a scaled object.
    """
    if rep.mode != "payload":
        return np.zeros(3)
    return payload_centre(model, model.inverse.payload_position, rep.mass)


def computed_torque_loop(model: Model, rep: OptimumReplay):
    """The native closed loop under the scenario's computed_torque law about the optimum (module docstring).

    Args:
        model: the scenario's Model (its control section, its arms).
        rep: the open-loop OptimumReplay (its loaded model, motion and resolution).

    Returns:
        tuple | None: (the native loop's Controller, its Model, its SimResult: adaptive DOP853 at CT_TOLERANCE
        times the scenario's tolerances, sampled as the open loop); None where the scenario's law is not
        computed_torque, its Controller refuses the arms, or the optimum is the LP bound's (the law distributes
        by a resolution; the LP's wrenches exist only as the replay's tables, so joint PD carries them).
    """
    c = model.control
    if c is None or c.law != "computed_torque" or rep.method not in COMPILED_DISTRIBUTIONS:
        return None
    settings = replace(c, distribution=rep.method, squeeze=0.0, mass_scale=1.0)
    try:
        native_model = _in_the_loop(rep.native.sim.model, settings, rep, tracked_point(model, rep))
    except ControlError:
        return None
    it = native_model.integrator
    native = simulate(native_model, settings=replace(it, rtol=CT_TOLERANCE * it.rtol, atol=CT_TOLERANCE * it.atol))
    return native_model.torques.fn, native_model, native


def _native_loop(model: Model, rep: OptimumReplay, kp, kd):
    """The native joint PD loop with the gains kp, kd (n,): (its Controller, its Model, its SimResult)."""
    traj = rep.traj
    # compensation 'none' never evaluates the distribution; the LP bound has none of its own: 'paper' stands in
    dist = rep.method if rep.method in COMPILED_DISTRIBUTIONS else "paper"
    settings = ControlSettings("joint_pd", kp, kd, compensation="none", distribution=dist,
                               reference="object_motion", saturate=model.control is not None and model.control.saturate)
    native_model = _in_the_loop(rep.native.sim.model, settings, rep)
    return native_model.torques.fn, native_model, simulate(native_model, fixed_step=float(traj.t[1] - traj.t[0]))


def _closed_run(model: Model, rep: OptimumReplay, why: str, kp, kd, where: str, ctrl, native_model,
                native) -> ClosedReplay:
    """The closed-loop replay of a native loop (`_native_loop`, `computed_torque_loop`) with its twin."""
    traj = rep.traj
    twin_model = _in_the_loop(rep.twin_model, ctrl.settings, rep, ctrl.point)
    twin = run_twin(twin_model, native.initial.q, native.initial.qd, native.t)
    cmd = record(ctrl, native.t, native.q, native.qd)
    twin_cmd = record(twin_model.torques.fn, twin.t, twin.q, twin.qd)
    ff = np.array([torque_at(rep.native.sim.model.torques, t) for t in native.t])
    prob = inverse_problem(rep.native.sim.model, traj)
    return ClosedReplay(why, where, kp, kd, native, twin, compare(native, twin), ff, cmd.tau, twin.tau,
                        (prob.p_C, rots_to_quats(prob.R_o)), cmd.saturation_events, (cmd, twin_cmd))


def _in_the_loop(model: Model, settings: ControlSettings, rep: OptimumReplay, point=None) -> Model:
    """The replay's model with the feedback law in the loop: joint_pd about the optimised joint path on top of
    its torque tables (the feedforward); computed_torque in their place (zero tables), with the optimum's
    resolution and the reference moved to `point` (3,) m (`tracked_point`).

    Raises:
        ControlError: computed_torque on arms it refuses.
    """
    if settings.law == "joint_pd":
        m = replace(model, control=settings)
        return replace(m, torques=TorqueFeedback(Controller(m, trajectory=rep.traj)))
    zero = tuple(TorqueTable(np.zeros(1), np.zeros((1, sl.stop - sl.start))) for sl in model.dof_slices)
    m = replace(model, control=settings, torques=zero)
    return replace(m, torques=TorqueFeedback(Controller(m, resolution=rep.resolution, point=point)))


def _tracking(q, p, quat, traj, reference) -> dict:
    """The largest joint, object position and orientation errors of a run against the optimised path."""
    return {"max_angle_error_rad": float(np.max(np.abs(q - traj.q))),
            "final_angle_error_rad": float(np.max(np.abs(q[-1] - traj.q[-1]))),
            "max_object_position_error_m": float(np.max(np.linalg.norm(p - reference[0], axis=1))),
            "max_object_orientation_error_rad": float(np.max(orientation_error(quat, reference[1])))}


def _line_excess(motors, tau, qd, active) -> float:
    """The largest excess of a torque over its motor line at its own rate, relative to τ_s (≤ 0: within)."""
    lo, hi = torque_limits(motors, qd)
    return float(np.max((np.maximum(tau - hi, lo - tau) / motors.stall_torque)[:, active]))


def closed_summary(cr: ClosedReplay, traj) -> dict:
    """optimize.json's replay "closed_loop" entry (SI units).

    Args:
        cr: the ClosedReplay.
        traj: the optimised joint path (the open-loop replay's).

    Returns:
        dict: why, the law ("control_law": joint_pd or computed_torque, "law": a sentence) and its gains (and
        their source), the native and twin tracking errors against the optimised path (joint angle max and
        final, object position and orientation max; with computed_torque also the law's own pose error at its
        tracked point, "tracked_point_m" in object axes from the nominal C), the feedback
        torque's share (its peak relative to τ_s and its RMS over the total's), the total torque's largest
        excess over its line relative to τ_s (native and twin) and whether it is within (≤ 1e-9), the
        saturation events, the twin against the native closed loop (the scenario's thresholds), and with the
        default law "omega_tries": each ω tried and its native loop's largest joint error.
    """
    motors = cr.native.model.motors
    active = ~motors.passive & np.isfinite(motors.stall_torque)
    fb = cr.tau - cr.feedforward
    excess = {"native": _line_excess(motors, cr.tau, cr.native.qd, active),
              "twin": _line_excess(motors, cr.twin_tau, cr.twin.qd, active)}
    return {
        "why": cr.why, "control_law": cr.law,
        "law": LAWS[cr.law] + (", q_r the optimised joint path" if cr.law == "joint_pd" else ""),
        "gains": cr.gains, "kp": cr.kp.tolist(), "kd": cr.kd.tolist(),
        "native": _tracking(cr.native.q, cr.native.object_pos, cr.native.object_quat, traj, cr.reference)
        | _law_error(cr, 0),
        "twin": _tracking(cr.twin.q, cr.twin.object_pos, cr.twin.object_quat, traj, cr.reference) | _law_error(cr, 1),
        "feedback": {"peak_rel_stall": float(np.max(np.abs(fb[:, active]) / motors.stall_torque[active])),
                     "rms_share": float(np.linalg.norm(fb) / max(np.linalg.norm(cr.tau), 1e-300))},
        "line_excess": excess, "within_lines": bool(max(excess.values()) <= 1e-9),
        "saturation_events": cr.saturation_events,
        "twin_vs_native": {"passed": cr.comparison.passed, "agreement": cr.comparison.as_dict()},
    } | ({"omega_tries": [{"omega_rad_s": w, "native_max_angle_error_rad": e} for w, e in cr.tries]}
         if cr.tries else {}) | ({"tracked_point_m": cr.point.tolist()} if cr.law == "computed_torque" else {})


def _law_error(cr: ClosedReplay, side: int) -> dict:
    """computed_torque's largest pose error at its tracked point along run `side` (0 native, 1 twin), {} else."""
    if cr.law != "computed_torque":
        return {}
    e = cr.control[side].object_error
    return {"max_tracked_position_error_m": float(np.max(np.linalg.norm(e[:, :3], axis=1))),
            "max_tracked_orientation_error_rad": float(np.max(np.linalg.norm(e[:, 3:], axis=1)))}


def format_closed_summary(s: dict) -> str:
    """Short text version of `closed_summary`.

    Args:
        s: the "closed_loop" entry.

    Returns:
        str: one line per model and one for the torques.
    """
    n, t = s["native"], s["twin"]
    return (f"  closed loop ({s['why']}), {s['control_law']}: native {n['max_angle_error_rad']:.2e} rad, "
            f"{n['max_object_position_error_m']:.2e} m from the optimised path; twin {t['max_angle_error_rad']:.2e} "
            f"rad, {t['max_object_position_error_m']:.2e} m ({'PASS' if s['twin_vs_native']['passed'] else 'FAIL'} "
            f"against the native loop)\n"
            f"  feedback peak {s['feedback']['peak_rel_stall']:.2e} τ_s (RMS share {s['feedback']['rms_share']:.2e}); "
            f"total torque {'within' if s['within_lines'] else 'OVER'} its lines (excess "
            f"{max(s['line_excess'].values()):.2e} τ_s)")


def closed_replay_of(model: Model, rep: OptimumReplay, asked: bool = False) -> ClosedReplay | None:
    """The closed-loop replay of an optimum where `closed_loop_reason` says so, else None.

    Args:
        model: the scenario's Model.
        rep: the open-loop OptimumReplay.
        asked: --closed-loop given.

    Returns:
        ClosedReplay | None.
    """
    why = closed_loop_reason(model, rep, asked)
    return None if why is None else closed_loop_replay(model, rep, why)


def replay_entry(rep: OptimumReplay, closed: ClosedReplay | None = None) -> dict:
    """optimize.json's "replay" entry of an optimum: the open loop (`replay_summary`), and with a closed loop
    its "closed_loop" (`closed_summary`, with "topics": its runs' prefixes in the run log).

    Args:
        rep: the open-loop OptimumReplay.
        closed: its ClosedReplay (`closed_replay_of`), or None.

    Returns:
        dict: the entry.
    """
    out = replay_summary(rep)
    if closed is not None:
        out["closed_loop"] = closed_summary(closed, rep.traj) | {
            "topics": {"native": CLOSED_NATIVE, "twin": CLOSED_TWIN}}
    return out


def closed_series(cr: ClosedReplay) -> list:
    """The closed-loop runs' series for the optimum's run log (`replay_run_log`'s extra series).

    Args:
        cr: the ClosedReplay.

    Returns:
        list: CLOSED_LOOP/native/… (`coopsim.io.log.simulation_series` of the native loop: joint state with the
        applied torques, object, wrenches, constraint), CLOSED_LOOP/mujoco/… (`twin_series`), and each one's
        /control (`coopsim.io.log.control_series`: joint_pd's optimised joint path as reference and angle
        error, computed_torque's pose and twist errors at its tracked point; the command and the applied
        torque), at each run's sample times.
    """
    out = simulation_series(cr.native, CLOSED_NATIVE) + twin_series(cr.twin, CLOSED_TWIN)
    return out + [control_series(rec, res.t, prefix, cr.law)
                  for rec, res, prefix in zip(cr.control, (cr.native, cr.twin), (CLOSED_NATIVE, CLOSED_TWIN))]


def closed_metadata(cr: ClosedReplay) -> dict:
    """The run log's "closed_loop" metadata record: why, the law, the gains and their source, the topics.

    Args:
        cr: the ClosedReplay.

    Returns:
        dict: {"closed_loop": {why, control_law, law, gains, kp, kd (joint_pd (n,), computed_torque (2,)),
        native, twin (topic prefixes), twin_vs_native_passed, omega_tries, tracked_point_m}}.
    """
    return {"closed_loop": {"why": cr.why, "control_law": cr.law, "law": LAWS[cr.law], "gains": cr.gains,
                            "kp": cr.kp, "kd": cr.kd, "native": CLOSED_NATIVE,
                            "twin": CLOSED_TWIN, "twin_vs_native_passed": cr.comparison.passed,
                            "omega_tries": [list(t) for t in cr.tries], "tracked_point_m": cr.point}}


def format_replay_entry(s: dict) -> str:
    """Short text of a "replay" entry: the open loop's lines, then the closed loop's where there is one.

    Args:
        s: the entry (`replay_entry`).

    Returns:
        str: the lines.
    """
    return format_replay_summary(s) + ("\n" + format_closed_summary(s["closed_loop"]) if "closed_loop" in s else "")
