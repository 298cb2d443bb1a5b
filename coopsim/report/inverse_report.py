"""Studies behind `coopsim inverse` and `coopsim capacity`: every stage run in order on one scenario,
plain-data summaries for the text and JSON outputs, and the MCAP series (no I/O here).

    scenario → trajectory (forward run or object-motion IK) → InverseProblem
      → resolutions (the registry `coopsim.inverse.resolutions.RESOLUTIONS`; plus the forward input torques)
      → object stress (grasp-line components, box section loads) → [replay]
      → capacity (closed form per resolution, LP bound, optimised weights, [brute-force check])
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from coopsim.control.controller import closed_loop
from coopsim.core.digest import content_digest
from coopsim.core.joints import type_names
from coopsim.core.labels import joint_labels
from coopsim.core.model import Model, torque_limits
from coopsim.forward.simulate import simulate
from coopsim.inverse import capacity as cap
from coopsim.inverse.distributions import distribution_of_torques, grasp_line_frames, virtual_masses
from coopsim.inverse.problem import InverseResult, failure_text, inverse_problem, shared_inverse_problem
from coopsim.inverse.replay import replay
from coopsim.inverse.resolutions import LINEAR_METHODS, METHODS
from coopsim.inverse.solve import cost_of, default_bounds, energy, nan_peak, resolution_for, resolve, result_of
from coopsim.inverse.stress import SectionLoads, decompose_internal, section_loads
from coopsim.inverse.trajectory import JointTrajectory, from_simulation, shared_object_motion_trajectory
from coopsim.io.mcap_codec import Series, nonfinite_name

DEFINITIONS = ("paper", "nonsqueezing")
Progress = Callable[[str, float], None]   # progress(stage, fraction done), e.g. a `coopsim.apps.progress.ProgressBar`


def _report(progress: Progress | None, stage: str, fraction: float) -> None:
    if progress is not None:
        progress(stage, fraction)


def trajectory_of(model: Model, duration: float | None = None, progress: Progress | None = None):
    """The scenario's trajectory to invert: its forward run or the IK of its prescribed object motion.

    Args:
        model: the Model (its inverse.trajectory: 'forward' or 'object_motion').
        duration: s, in place of the scenario's duration (a forward-run trajectory); None: the
            scenario's.
        progress: hears the stage "forward" or "ik" (module `Progress`); None: silent.

    Returns:
        tuple: the JointTrajectory, and the forward run's SimResult (None for an object motion).
    """
    if model.inverse.trajectory == "object_motion":
        _report(progress, "ik", 0.0)
        traj = shared_object_motion_trajectory(model, model.inverse.object_motion)
        _report(progress, "ik", 1.0)
        return traj, None
    res = simulate(closed_loop(model), duration=duration,
                   progress=None if progress is None else lambda f: progress("forward", f))
    return from_simulation(res), res


@dataclass(frozen=True, eq=False)
class InverseStudy:
    """Everything `coopsim inverse` reports (N samples, n joints, r arms; SI units, world axes).

    Attributes:
        model: the Model.
        traj: the JointTrajectory inverted.
        sim: the forward run's SimResult, or None (an object-motion trajectory).
        problem: the InverseProblem along traj.
        resolutions: {method: Resolution}.
        results: {method: InverseResult}; also 'forward', the forward run's input torques, when there is
            one.
        components: {method: {definition: {axial, shear, torsion, bending} (N, r)}}, the internal-wrench
            components along the grasp lines (N, N·m) by each definition ('paper', 'nonsqueezing').
        stress: {method: SectionLoads} (box objects only; else empty).
        limits: (τ_min, τ_max) (N, n) N·m, the motor lines of eq. 36 along traj.
        replays: {method: Replay} (empty unless asked for).
        curve: the energy–stress trade-off (list of dicts, `coopsim.inverse.capacity.energy_stress_curve`;
            empty unless asked for).
        bounds: (force N, moment N·m), the 'bounded' resolution's internal-wrench bounds.
    """

    model: Model
    traj: JointTrajectory
    sim: object
    problem: object
    resolutions: dict
    results: dict
    components: dict
    stress: dict
    limits: tuple
    replays: dict
    curve: list
    bounds: tuple


def inverse_study(model: Model, methods=METHODS, duration: float | None = None, with_replay: bool = False,
                  bounds: tuple[float | None, float | None] = (None, None), curve: bool = True,
                  progress: Progress | None = None, engine: str = "compiled") -> InverseStudy:
    """The scenario's inverse-dynamics study, as `coopsim inverse` runs it.

    Args:
        model: the Model; its trajectory is the object motion's IK or a forward run.
        methods: the resolutions to run (names in `coopsim.inverse.resolutions.METHODS`).
        duration: s, in place of the model's (a forward-run trajectory).
        with_replay: feed each resolution's torques back through the forward model.
        bounds: (N, N·m) the 'bounded' resolution's internal-wrench bounds; None: the defaults.
        curve: also the energy–stress trade-off curve.
        progress: hears the stages forward (or ik), inverse, replay and curve.
        engine: 'compiled' or 'reference' (`solve_study`).

    Returns:
        InverseStudy: the trajectory, each resolution's result, internal-wrench components and object
        stress, the torque limits, replays and the curve where asked.
    """
    return add_checks(solve_study(model, methods, duration, bounds, progress, engine), with_replay, curve, progress)


def solve_study(model: Model, methods=METHODS, duration: float | None = None,
                bounds: tuple[float | None, float | None] = (None, None),
                progress: Progress | None = None, engine: str = "compiled") -> InverseStudy:
    """The inverse study without its checks (no replays, no trade-off curve).

    Trajectory, every resolution of `methods`, internal wrenches and stress — all that `inverse_series`
    logs.

    Args:
        model: the Model.
        methods: the resolutions to run (names in `coopsim.inverse.resolutions.METHODS`).
        duration: s, in place of the scenario's (a forward-run trajectory); None: the scenario's.
        bounds: (N, N·m) the 'bounded' resolution's internal-wrench bounds; None entries: the
            scenario's, else the defaults (`coopsim.inverse.solve.default_bounds`).
        progress: hears the stages forward (or ik) and inverse; None: silent.
        engine: 'compiled' (the linear resolutions and the section loads in compiled passes) or
            'reference' (the NumPy functions) (`coopsim.inverse.problem.ENGINES`).

    Returns:
        InverseStudy: with empty replays and curve.
    """
    traj, sim = trajectory_of(model, duration, progress)
    prob = inverse_problem(model, traj)
    base = resolution_for(model, "min_energy")
    f_b = bounds[0] if bounds[0] is not None else model.inverse.internal_force_bound
    m_b = bounds[1] if bounds[1] is not None else model.inverse.internal_moment_bound
    if f_b is None or m_b is None:
        d_f, d_m = default_bounds(prob, base, engine=engine)
        f_b, m_b = (d_f if f_b is None else f_b), (d_m if m_b is None else m_b)
    resolutions = {k: replace(base, method=k, force_bound=f_b, moment_bound=m_b) for k in methods}
    results: dict[str, InverseResult] = {}
    if sim is not None:
        f, _ = distribution_of_torques(prob, sim.tau)
        results["forward"] = result_of(prob, "forward", f, base)
    for i, (k, res) in enumerate(resolutions.items()):
        _report(progress, "inverse", i / len(resolutions))
        results[k] = resolve(prob, res, engine)
    _report(progress, "inverse", 1.0)
    components, stress = {}, {}
    axes = grasp_line_frames(prob)[:, :, 0]
    box = np.any(model.object.box > 0)
    for k, r in results.items():
        components[k] = {d: decompose_internal(getattr(r, f"internal_{d}"), axes) for d in DEFINITIONS}
        if box:
            stress[k] = section_loads(model.object.mass, model.object.box, model.object.grasp_pos, prob.R_o,
                                      prob.twist, prob.acc, model.gravity, r.grasp_wrench, model.rows, engine=engine)
    return InverseStudy(model, traj, sim, prob, resolutions, results, components, stress,
                        torque_limits(model.motors, traj.qd), {}, [], (f_b, m_b))


def add_checks(study: InverseStudy, with_replay: bool = False, curve: bool = True,
               progress: Progress | None = None) -> InverseStudy:
    """`study` with its checks: replays through the forward dynamics and the energy–stress trade-off curve.

    Args:
        study: the InverseStudy (`solve_study`).
        with_replay: replay each resolution's torques through the forward dynamics.
        curve: compute the energy–stress trade-off curve of the bounded minimum-energy resolution.
        progress: hears the stages replay and curve; None: silent.

    Returns:
        InverseStudy: a copy with replays and curve filled in as asked.
    """
    replays = {}
    for i, (k, res) in enumerate(study.resolutions.items() if with_replay else ()):
        _report(progress, "replay", i / len(study.resolutions))
        replays[k] = replay(study.model, study.traj, res)
    if with_replay:
        _report(progress, "replay", 1.0)
    trade = []
    if curve:
        _report(progress, "curve", 0.0)
        base = resolution_for(study.model, "min_energy")
        trade = cap.energy_stress_curve(study.problem, base, default_bounds(study.problem, base, fraction=1.0))
        _report(progress, "curve", 1.0)
    return replace(study, replays=replays, curve=trade)


def _trajectory_summary(model: Model, traj: JointTrajectory) -> dict:
    return {"source": traj.source, "start_s": float(traj.t[0]), "end_s": float(traj.t[-1]),
            "samples": len(traj.t), "max_abs_rate_rad_s": np.max(np.abs(traj.qd), axis=0).tolist(),
            "max_abs_acceleration_rad_s2": np.max(np.abs(traj.qdd), axis=0).tolist()}


def _failures(failures) -> list[dict]:
    return [{"time_s": f.time, "reason": f.reason} for f in failures]


def inverse_summary(study: InverseStudy) -> dict:
    """JSON-ready summary of an inverse study (SI units).

    Samples a resolution could not solve are listed under its "failed_samples" (every statistic leaves
    them out; its energy, an integral over the whole trajectory, is then nan); "complete" is false when
    any method or replay has one.

    Args:
        study: the InverseStudy.

    Returns:
        dict: scenario, joints, joint_types, trajectory, complete, energy_definition, nonsqueezing
        (virtual masses kg, centroid offset m), bounded (bounds N, N·m), methods {method: energy,
        torque and internal-wrench peaks, stress, replay errors, failures} and energy_stress_curve.
    """
    m = study.model
    e_min = energy(study.results["min_energy"]) if "min_energy" in study.results else None
    methods = {}
    for k, r in study.results.items():
        e = energy(r)
        entry = {
            "energy": e,
            "energy_ratio_to_min_energy": None if not e_min else e / e_min,
            "max_abs_torque_Nm": nan_peak(np.abs(r.tau), axis=0).tolist(),
            "max_torque_norm_Nm": float(nan_peak(np.linalg.norm(r.tau, axis=1))),
            "max_cost": float(nan_peak(r.cost)),
            "failed_samples": _failures(r.failures),
            "internal": {},
        }
        for d in DEFINITIONS:
            F_I, comp = getattr(r, f"internal_{d}"), study.components[k][d]
            entry["internal"][d] = {
                "max_abs_component": float(nan_peak(np.abs(F_I))),
                "max_force_N": float(nan_peak(np.linalg.norm(F_I[..., :3], axis=-1))),
                "max_moment_Nm": float(nan_peak(np.linalg.norm(F_I[..., 3:], axis=-1))),
                "max_stretch_N": float(max(0.0, nan_peak(comp["axial"]))),
                "max_squeeze_N": float(max(0.0, nan_peak(-comp["axial"]))),
                "max_shear_N": float(nan_peak(comp["shear"])),
                "max_torsion_Nm": float(nan_peak(np.abs(comp["torsion"]))),
                "max_bending_Nm": float(nan_peak(comp["bending"])),
            }
        if k in study.stress:
            s = study.stress[k]
            entry["stress"] = {"peak_normal_Pa": float(nan_peak(s.peak_normal)),
                               "peak_shear_Pa": float(nan_peak(s.peak_shear)),
                               "max_axial_N": float(nan_peak(np.abs(s.axial))),
                               "max_bending_Nm": float(nan_peak(s.bending))}
        if np.any(m.motors.passive):
            entry["max_abs_passive_torque_Nm"] = float(nan_peak(np.abs(r.tau[:, m.motors.passive])))
        if k in study.replays:
            rep = study.replays[k]
            entry["replay"] = {"max_angle_error_rad": rep.max_angle_error, "max_rate_error_rad_s": rep.max_rate_error}
            if rep.failures:
                entry["replay"]["failed_stage_times"] = _failures(rep.failures)
        methods[k] = entry
    masses, offset = virtual_masses(m.object.grasp_pos, m.object.mass, m.inverse.nonsqueezing_masses)
    complete = not any(e["failed_samples"] or e.get("replay", {}).get("failed_stage_times") for e in methods.values())
    return {
        "scenario": m.name,
        "joints": joint_labels(m), "joint_types": type_names(m.joint_type),
        "trajectory": _trajectory_summary(m, study.traj),
        "complete": complete,
        "energy_definition": "integral of 0.5 tau^T Q tau dt (trapezoidal), Q = diag(energy_weights)",
        "nonsqueezing": {"virtual_masses_kg": masses.tolist(), "centroid_offset_m": offset.tolist()},
        "bounded": {"force_bound_N": study.bounds[0], "moment_bound_Nm": study.bounds[1],
                    "definition": "nonsqueezing"},
        "methods": methods,
        "energy_stress_curve": study.curve,
    }


def format_inverse_summary(s: dict) -> str:
    """Short text version of `inverse_summary`.

    Args:
        s: the summary dict (`inverse_summary`).

    Returns:
        str: the lines of the report, joined by newlines.
    """
    tr = s["trajectory"]
    lines = [f"scenario        {s['scenario']}: {tr['source']} trajectory, {tr['start_s']:g}..{tr['end_s']:g} s, "
             f"{tr['samples']} samples",
             f"non-squeezing   virtual masses "
             f"{', '.join(f'{x:.4g}' for x in s['nonsqueezing']['virtual_masses_kg'])} kg, "
             f"centroid offset {np.linalg.norm(s['nonsqueezing']['centroid_offset_m']):.3g} m",
             f"bounded         |internal| <= {s['bounded']['force_bound_N']:.4g} N, "
             f"{s['bounded']['moment_bound_Nm']:.4g} N·m "
             f"(grasp-line components, non-squeezing definition)",
             "",
             _row("method", *METHOD_COLUMNS), _row("", *METHOD_UNITS)]
    for k, e in s["methods"].items():
        lines.append(_row(k, _cell(e["energy"], ".4g"), _cell(e["energy_ratio_to_min_energy"], ".3f"),
                          _cell(e["max_torque_norm_Nm"], ".4g"),
                          _cell(e["internal"]["paper"]["max_abs_component"], ".3g"),
                          _cell(e["internal"]["nonsqueezing"]["max_abs_component"], ".3g"),
                          _cell(e.get("stress", {}).get("peak_normal_Pa"), ".4g"),
                          _cell(e.get("replay", {}).get("max_angle_error_rad"), ".2g")))
    for k, e in s["methods"].items():
        if e["failed_samples"]:
            lines.append(f"{k}: NO SOLUTION at {len(e['failed_samples'])} of {tr['samples']} samples, left out (nan): "
                         + _failure_list(e["failed_samples"]))
        if e.get("replay", {}).get("failed_stage_times"):
            lines.append(f"{k}: replay not run: no torques at {len(e['replay']['failed_stage_times'])} stage times: "
                         + _failure_list(e["replay"]["failed_stage_times"]))
    if s["energy_stress_curve"]:
        lines += ["", "energy against the internal-wrench bound (bounded minimum energy):"]
        for c in s["energy_stress_curve"]:
            lines.append(f"  {c['fraction']:>5.2f} x peak: |F_I| <= {c['force_bound_N']:.4g} N, "
                         f"{c['moment_bound_Nm']:.4g} N·m"
                         f"  energy {c['energy']:.5g}"
                         + (f"  (no solution at {c['failed_samples']} samples)" if c["failed_samples"] else ""))
    return "\n".join(lines)


METHOD_COLUMNS = ("energy", "ratio", "max|tau|", "F_I paper", "F_I E&H", "sigma max", "replay")
METHOD_UNITS = ("N²m²s", "", "N·m", "N, N·m", "N, N·m", "Pa", "rad")
COLUMN_WIDTH = 10   # fits any .4g number ("-1.234e+05"); columns are also separated by two spaces


def _cell(x, spec: str) -> str:
    """x formatted with `spec`; "—" when it was not computed (None: e.g. the replay not asked for)."""
    return "—" if x is None else format(x, spec)


def _row(first: str, *cells: str) -> str:
    """One line of the method table: the name left-aligned in 14 columns, then right-aligned cells of
    at least COLUMN_WIDTH characters, two spaces apart (long values never run into each other)."""
    return f"{first:<14}" + "".join(f"  {c:>{COLUMN_WIDTH}}" for c in cells)


def _failure_list(failures: list[dict]) -> str:
    return failure_text([(f["time_s"], f["reason"]) for f in failures])


# ------------------------------------------------------------------------------------------------
# Capacity
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class CapacityStudy:
    """Everything `coopsim capacity` reports (N samples, n joints; SI units).

    Attributes:
        model: the Model.
        traj: the JointTrajectory along which the capacity holds.
        problem: the InverseProblem along traj (with the payload position, if any).
        modes: the capacity modes computed: ('scaled',) or ('scaled', 'payload').
        caps: {(method, mode): Capacity}.
        tau_at: {(method, mode): τ (N, n) N·m at the capacity (at the nominal mode's zero where the
            capacity is not finite)}.
        lp: {mode: Capacity}, the LP bound over all distributions (empty unless asked for).
        optimised: (weights (n,), Capacity, τ (N, n) N·m at it) of the optimised minimum-energy weights
            ('scaled'), or None.
        energies: {method: energy N²·m²·s at the nominal mass}.
        checks: {(method, mode): brute-force check dict} or {}.
        limits: (τ_min, τ_max) (N, n) N·m, the motor lines of eq. 36 along traj.
        payload_position: (3,) m, object frame, the payload's position, or None.
    """

    model: Model
    traj: JointTrajectory
    problem: object
    modes: tuple
    caps: dict
    tau_at: dict
    lp: dict
    optimised: tuple | None
    energies: dict
    checks: dict
    limits: tuple
    payload_position: np.ndarray | None


def capacity_study(model: Model, duration: float | None = None, payload_position=None, with_lp: bool = True,
                   optimise: bool = True, check: bool = False, methods=LINEAR_METHODS,
                   progress: Progress | None = None, engine: str = "compiled") -> CapacityStudy:
    """The dynamic load carrying capacity (eq. 36 motor lines) along the scenario's trajectory, as
    `coopsim capacity` runs it.

    Args:
        model: the Model (its motors' stall torques and no-load speeds).
        duration: s, in place of the model's (a forward-run trajectory).
        payload_position: (3,) m, object frame: also the capacity for a point payload there.
        with_lp: also the LP bound (the best distribution at every sample).
        optimise: also the minimum-energy weights that carry the most.
        check: also the brute-force check of each capacity.
        methods: the linear resolutions (`coopsim.inverse.resolutions.LINEAR_METHODS`).
        progress: hears the stages forward (or ik), capacity, lp and weights.
        engine: 'compiled' (one pass over the samples for every resolution and mode) or 'reference' (the
            NumPy functions, one call per resolution and mode) (`coopsim.inverse.problem.ENGINES`).

    Returns:
        CapacityStudy: per (resolution, mode) the Capacity (kg, the saturating motor, time and side)
        and the torques at it; the LP bound per mode, the optimised weights and the checks where asked.
    """
    traj, _ = trajectory_of(model, duration, progress)
    payload = payload_position if payload_position is not None else model.inverse.payload_position
    prob = shared_inverse_problem(model, traj, payload)
    modes = ("scaled",) if payload is None else cap.MODES
    _report(progress, "capacity", 0.0)
    caps, affine, energies = _linear_capacities(model, prob, methods, modes, engine)
    tau_at, checks = {}, {}
    for (k, mode), c in caps.items():
        a, b = affine[k, mode]
        tau_at[k, mode] = a + (c.mass if np.isfinite(c.mass) else 0.0) * b
        if check and c.feasible and np.isfinite(c.mass):
            checks[k, mode] = cap.brute_force_check(model, traj, resolution_for(model, k), mode, c, payload)
    _report(progress, "capacity", 1.0)
    zero_ok = all(caps[k, m].feasible and caps[k, m].lower == 0.0 for k in methods for m in modes)
    lp = {}
    for i, mode in enumerate(modes if with_lp else ()):
        _report(progress, "lp", i / len(modes))
        lp[mode] = _lp_capacity(model, traj, prob, mode, zero_ok)
    if with_lp:
        _report(progress, "lp", 1.0)
    optimised = None
    if optimise:
        _report(progress, "weights", 0.0)
        base = resolution_for(model, "min_energy")
        w, c = cap.optimise_weights(prob, base, model.motors)
        a, b = cap.affine_torques(prob, replace(base, weights=w), "scaled", engine)
        optimised = (w, c, a + c.mass * b)
        _report(progress, "weights", 1.0)
    return CapacityStudy(model, traj, prob, modes, caps, tau_at, lp, optimised, energies, checks,
                         torque_limits(model.motors, traj.qd), payload)


SCALED_LP_INDEPENDENT = frozenset({"name", "torques", "mujoco", "validation", "control",
                                   "inverse.payload_position"})   # what the 'scaled' LP bound does not read
SHARED_LPS = 8                    # the most 'scaled' LP bounds a process keeps for sharing
_shared_lps: OrderedDict[tuple, cap.Capacity] = OrderedDict()


def _lp_capacity(model: Model, traj, prob, mode: str, zero_ok: bool) -> cap.Capacity:
    """The LP bound of `mode` (`coopsim.inverse.capacity.lp_capacity`); the 'scaled' one, which the point
    payload's position does not change, computed once per content of the model less SCALED_LP_INDEPENDENT,
    the trajectory and zero_ok, and shared (each caller its own copy of per_sample): the points of a sweep
    over the payload's position solve its LPs once."""
    def solve() -> cap.Capacity:
        return cap.lp_capacity(prob, model.motors, model.motors.passive, mode, zero_feasible=zero_ok)

    key = (content_digest(model, SCALED_LP_INDEPENDENT), content_digest(traj), bool(zero_ok))
    if mode != "scaled" or None in key:
        return solve()
    if key in _shared_lps:
        _shared_lps.move_to_end(key)
    else:
        _shared_lps[key] = solve()
        while len(_shared_lps) > SHARED_LPS:
            _shared_lps.popitem(last=False)
    kept = _shared_lps[key]
    return replace(kept, per_sample=None if kept.per_sample is None else kept.per_sample.copy())


def _linear_capacities(model: Model, prob, methods, modes, engine: str) -> tuple[dict, dict, dict]:
    """({(method, mode): Capacity}, {(method, mode): (a, b)}, {method: energy at the nominal mass}) of the
    linear resolutions with the scenario's settings: one compiled pass, or the reference's calls."""
    if engine == "compiled":
        base = resolution_for(model, "min_energy")
        lin = cap.linear_study(prob, base, methods, model.motors, modes)
        energies = {k: float(np.trapezoid(cost_of(lin.torques[k], base.weights), prob.t)) for k in methods}
        return lin.caps, lin.affine, energies
    caps, affine, energies = {}, {}, {}
    for k in methods:
        res = resolution_for(model, k)
        energies[k] = energy(resolve(prob, res, engine))
        for mode in modes:
            caps[k, mode] = cap.method_capacity(prob, res, model.motors, mode, engine=engine)
            affine[k, mode] = cap.affine_torques(prob, res, mode, engine)
    return caps, affine, energies


def _capacity_entry(model: Model, c: cap.Capacity) -> dict:
    names = joint_labels(model)
    return {"mass_kg": c.mass, "lower_kg": c.lower, "feasible": bool(c.feasible),
            "saturating_motor": None if c.joint is None else names[c.joint],
            "stacked_joint": c.joint, "time_s": c.time, "line": None if c.side is None else
            ("tau_max" if c.side == "upper" else "tau_min"), "note": c.note}


def capacity_summary(study: CapacityStudy) -> dict:
    """JSON-ready summary of a capacity study (SI units).

    Args:
        study: the CapacityStudy.

    Returns:
        dict: scenario, joints, joint_types, trajectory, assumptions, nominal_object_mass_kg, capacity
        {mode: {method: entry}}, lp_bound {mode: entry}, energy {method: N²·m²·s}, and where computed
        energy_ratio_to_min_energy, optimised_weights and brute_force_check; an entry gives mass_kg,
        lower_kg, feasible, the saturating motor, its stacked joint, time_s, line and note.
    """
    m = study.model
    out = {
        "scenario": m.name,
        "joints": joint_labels(m), "joint_types": type_names(m.joint_type),
        "trajectory": _trajectory_summary(m, study.traj),
        "assumptions": {
            "scaled": "the whole object scaled at constant geometry (density), mass_kg is the object's mass; "
                      "the trajectory is held fixed",
            "payload": None if study.payload_position is None else
            f"a point mass at {list(map(float, study.payload_position))} m (object frame) added to the nominal "
            f"{m.object.mass:.6g} kg object; mass_kg is the payload's",
            "motor_lines": "eq. 36: tau_max = tau_s - (tau_s/omega_s) qd, tau_min = -tau_s - (tau_s/omega_s) qd "
                           "(N·m against rad/s; a prismatic joint's: N against m/s)",
            "nonsqueezing": "virtual bodies fixed at the nominal object's",
        },
        "nominal_object_mass_kg": m.object.mass,
        "capacity": {mode: {k: _capacity_entry(m, c) for (k, md), c in study.caps.items() if md == mode}
                     for mode in study.modes},
        "lp_bound": {mode: _capacity_entry(m, c) for mode, c in study.lp.items()},
        "energy": {k: e for k, e in study.energies.items()},
    }
    if "min_energy" in study.energies:
        e = study.energies["min_energy"]
        out["energy_ratio_to_min_energy"] = {k: v / e for k, v in study.energies.items()}
    if study.optimised is not None:
        w, c, _ = study.optimised
        start = study.caps.get(("min_energy", "scaled"))   # with the scenario's energy_weights (equal by default)
        out["optimised_weights"] = {"weights": w.tolist(), **_capacity_entry(m, c),
                                    "scenario_weights_mass_kg": None if start is None else start.mass}
    if study.checks:
        out["brute_force_check"] = {f"{k}/{mode}": v for (k, mode), v in study.checks.items()}
    return out


def format_capacity_summary(s: dict) -> str:
    """Short text version of `capacity_summary`.

    Args:
        s: the summary dict (`capacity_summary`).

    Returns:
        str: the lines of the report, joined by newlines.
    """
    lines = [f"scenario        {s['scenario']}: {s['trajectory']['source']} trajectory, "
             f"{s['trajectory']['start_s']:g}..{s['trajectory']['end_s']:g} s; "
             f"nominal object {s['nominal_object_mass_kg']:.4g} kg"]
    for mode, caps in s["capacity"].items():
        what = "object mass (scaled at constant geometry)" if mode == "scaled" else "payload mass"
        lines += ["", f"DLCC, {what}:"]
        rows = list(caps.items()) + ([("LP bound", s["lp_bound"][mode])] if mode in s["lp_bound"] else [])
        if mode == "scaled" and "optimised_weights" in s:
            rows.append(("optimised Q", s["optimised_weights"]))
        for k, c in rows:
            where = (f"{c['saturating_motor']} on {c['line']} at t={c['time_s']:.4g} s" if c["saturating_motor"]
                     else c["note"] or "-")
            if c["feasible"]:
                lines.append(f"  {k:<14}{c['mass_kg']:>10.4f} kg   first saturates: {where}")
            else:
                lines.append(f"  {k:<14}{'none':>10}      {c['note'] or 'infeasible'} (binding: {where})")
    if "energy_ratio_to_min_energy" in s:
        lines += ["", "energy relative to the minimum-energy distribution: " + ", ".join(
            f"{k} {v:.3f}" for k, v in s["energy_ratio_to_min_energy"].items())]
    if "optimised_weights" in s:
        lines.append("optimised weights Q: [" + ", ".join(f"{x:.4g}" for x in s["optimised_weights"]["weights"]) + "]")
    if "brute_force_check" in s:
        bad = [k for k, v in s["brute_force_check"].items() if not v["ok"]]
        lines.append(f"brute-force check at (1 ± 1e-6) x capacity: "
                     f"{'all agree' if not bad else 'FAILED: ' + ', '.join(bad)}")
    return "\n".join(lines)


def json_safe(obj):
    """A copy of a summary that strict JSON can carry, non-finite floats as strings.

    Non-finite floats become the strings "Infinity", "-Infinity" and "NaN" (the spellings coopsim.io.log
    uses), e.g. the capacity of unlimited motors.

    Args:
        obj: a summary: nested dicts, lists and tuples of plain values.

    Returns:
        object: the same structure (tuples as lists) with every non-finite float replaced.
    """
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, (float, np.floating)) and not np.isfinite(obj):
        return nonfinite_name(obj)
    return obj


# ------------------------------------------------------------------------------------------------
# MCAP series
# ------------------------------------------------------------------------------------------------

def inverse_series(study: InverseStudy) -> list:
    """Series for the MCAP log of an inverse study.

    /inverse/trajectory (θ, θ̇, θ̈, motor lines), and per method /inverse/<method>/torque (τ, ½τᵀQτ,
    |τ|), /inverse/<method>/grasp_wrench (F_e), and /inverse/<method>/internal (both definitions and the
    grasp-line components of each), plus /inverse/<method>/stress (box section peaks) when the object is
    a box.

    Args:
        study: the InverseStudy.

    Returns:
        list[Series]: the series, sampled at the trajectory's times (N,) s, SI units.
    """
    t = study.traj.t
    lo, hi = study.limits
    out = [Series("/inverse/trajectory", "coopsim.inverse.Trajectory", t,
                  {"q": study.traj.q, "qd": study.traj.qd, "qdd": study.traj.qdd, "tau_min": lo, "tau_max": hi})]
    for k, r in study.results.items():
        out.append(Series(f"/inverse/{k}/torque", "coopsim.inverse.Torque", t,
                          {"tau": r.tau, "cost": r.cost, "torque_norm": np.linalg.norm(r.tau, axis=1)}))
        out.append(Series(f"/inverse/{k}/grasp_wrench", "coopsim.inverse.GraspWrench", t, {"wrench": r.grasp_wrench}))
        fields = {}
        for d in DEFINITIONS:
            fields[d] = getattr(r, f"internal_{d}")
            for part, v in study.components[k][d].items():
                fields[f"{d}_{part}"] = v
        out.append(Series(f"/inverse/{k}/internal", "coopsim.inverse.Internal", t, fields))
        if k in study.stress:
            s: SectionLoads = study.stress[k]
            out.append(Series(f"/inverse/{k}/stress", "coopsim.inverse.Stress", t,
                              {"peak_normal": s.peak_normal, "peak_shear": s.peak_shear,
                               "max_axial": np.max(np.abs(s.axial), axis=1), "max_bending": np.max(s.bending, axis=1)}))
    return out


def capacity_series(study: CapacityStudy) -> list:
    """Series for the MCAP log of a capacity study.

    /capacity/limits (θ̇, motor lines) and per method and mode /capacity/<method>/<mode> (τ at the
    capacity, the largest mass each sample allows), likewise /capacity/lp/<mode> and
    /capacity/optimised/scaled.

    Args:
        study: the CapacityStudy.

    Returns:
        list[Series]: the series, sampled at the trajectory's times (N,) s, SI units (masses kg).
    """
    t = study.traj.t
    lo, hi = study.limits
    out = [Series("/capacity/limits", "coopsim.capacity.Limits", t,
                  {"qd": study.traj.qd, "tau_min": lo, "tau_max": hi})]
    for (k, mode), c in study.caps.items():
        out.append(Series(f"/capacity/{k}/{mode}", "coopsim.capacity.AtCapacity", t,
                          {"tau": study.tau_at[k, mode], "per_sample_mass": c.per_sample}))
    for mode, c in study.lp.items():
        out.append(Series(f"/capacity/lp/{mode}", "coopsim.capacity.LP", t, {"per_sample_mass": c.per_sample}))
    if study.optimised is not None:
        w, c, tau = study.optimised
        out.append(Series("/capacity/optimised/scaled", "coopsim.capacity.AtCapacity", t,
                          {"tau": tau, "per_sample_mass": c.per_sample}))
    return out


def capacity_metadata(summary: dict) -> dict:
    """MCAP metadata records of a capacity study: one per method and mode ("capacity.<method>.<mode>").

    Also "capacity.lp.<mode>" for the LP bounds and "capacity.optimised.scaled" for the optimised
    weights, where computed.

    Args:
        summary: the capacity summary (`capacity_summary`).

    Returns:
        dict: record name → its capacity entry (a dict of the summary).
    """
    recs = {}
    for mode, caps in summary["capacity"].items():
        for k, c in caps.items():
            recs[f"capacity.{k}.{mode}"] = c
    for mode, c in summary["lp_bound"].items():
        recs[f"capacity.lp.{mode}"] = c
    if "optimised_weights" in summary:
        recs["capacity.optimised.scaled"] = summary["optimised_weights"]
    return recs
