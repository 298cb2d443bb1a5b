"""The study behind `coopsim optimize --retime`: the scenario's object path kept, its time law freed.

    scenario → waypoint path → joint path θ(s) on a grid (and a 10× finer one)
      → per resolution (and the LP bound): the inverse dynamics affine in (s̈, ṡ², μ)
      → the minimum time of the nominal load, the heaviest load within T_max, the payload–time curve
      → the exact eq. 36 check on the grid and on the finer grid; the scenario's own capacities (before)
      → the optimised scenario's object motion (a sampled time law), the MCAP series and the summary
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, replace

import numpy as np

from coopsim.core.labels import joint_labels
from coopsim.core.model import Model, ObjectMotion
from coopsim.inverse import retime as rt
from coopsim.inverse.path import WaypointPath, joint_path, path_grid
from coopsim.inverse.resolutions import LINEAR_METHODS
from coopsim.inverse.retime_weights import WeightedLaw, weights_with_law
from coopsim.io.mcap_codec import Series
from coopsim.report.inverse_report import Progress, _report, capacity_study

METHODS = LINEAR_METHODS + (rt.LP_BOUND,)
CURVE_POINTS = 9          # masses on the payload–time curve, from the nominal load to near the heaviest
FINE = rt.FINE           # the check grid's intervals per grid interval


@dataclass(frozen=True, eq=False)
class MethodRetime:
    """One resolution's (or the LP bound's) retiming along the path.

    Attributes:
        dyn: the PathDynamics on the grid.
        bare: the Retiming of the nominal load (its minimum time).
        best: the Retiming of the heaviest load within T_max (None where none is carried).
        chosen: the Retiming of the asked payload (--payload), or None.
        curve: [(mass kg, minimum time s)] from the nominal load up.
        grid_check: `coopsim.inverse.retime.check_time_law` of `best` (or `chosen`) on the grid.
        fine_check: the largest excess over the lines on the 10× finer grid (relative to τ_s), with its s
            and joint.
        saturation: `coopsim.inverse.retime.saturating` of that law.
        mvc: (N,) 1/s, the maximum-velocity curve √b_max(s) of that load (nan for the LP bound).
        evaluations: the minimum-time solves of the heaviest-load search.
        wall_s: s, the wall time of the heaviest-load search; retime_s that of one minimum-time solve.
        retime_s: s, the wall time of the nominal load's minimum-time solve.
        grid_only_mass: kg, the heaviest load within T_max with the rows at the grid points only (no rows
            added between them: what the refinement costs).
    """

    dyn: rt.PathDynamics
    bare: rt.Retiming
    best: rt.Retiming | None
    chosen: rt.Retiming | None
    curve: list
    grid_check: dict
    fine_check: dict
    saturation: dict
    mvc: np.ndarray
    evaluations: int
    wall_s: float
    retime_s: float
    grid_only_mass: float

    @property
    def law_of(self) -> rt.Retiming:
        """The Retiming reported (the asked payload's, else the heaviest load's)."""
        return self.chosen if self.chosen is not None else self.best


@dataclass(frozen=True, eq=False)
class RetimeStudy:
    """Everything `coopsim optimize --retime` reports.

    Attributes:
        model: the Model.
        mode: 'payload' (a point payload at the scenario's payload position) or 'scaled'.
        duration_bound: s, T_max.
        payload: kg, the asked payload (None: none asked).
        method: the resolution whose time law the optimised scenario carries.
        path: the WaypointPath.
        joint: the JointPath on the grid.
        methods: {method: MethodRetime}.
        before: the scenario's own CapacityStudy (its quintic or cubic time law).
        motion: the optimised ObjectMotion (a sampled time law).
        intervals: the grid's intervals per waypoint segment.
        weights: the minimum energy's weights optimised with its time law (`--weights`), else None.
    """

    model: Model
    mode: str
    duration_bound: float
    payload: float | None
    method: str
    path: WaypointPath
    joint: object
    methods: dict
    before: object
    motion: ObjectMotion
    intervals: int
    weights: WeightedLaw | None = None


def retime_study(model: Model, duration: float | None = None, payload: float | None = None,
                 method: str = "min_energy", intervals: int = 50, methods=METHODS, weights: bool = False,
                 progress: Progress | None = None) -> RetimeStudy:
    """The retiming study of the scenario's object path, as `coopsim optimize --retime` runs it.

    Args:
        model: the Model (an `inverse.object_motion` and finite motor limits).
        duration: s, T_max; None: the scenario's object-motion duration.
        payload: kg, also the minimum time of this load (the payload's mass, or the object's in the
            scaled mode); None: not asked.
        method: the resolution (or 'lp') whose time law goes into the optimised scenario.
        intervals: grid intervals per waypoint segment.
        methods: the resolutions (and 'lp') retimed.
        weights: optimise the minimum energy's weights Q with its time law
            (`coopsim.inverse.retime_weights.weights_with_law`); its entry is then retimed with them.
        progress: hears the stages ik, retime and check.

    Returns:
        RetimeStudy.

    Raises:
        coopsim.inverse.retime.RetimeError: no motion meets the bound, the motors cannot hold the load.
        coopsim.inverse.trajectory.TrajectoryError: a waypoint out of reach.
    """
    motion = model.inverse.object_motion
    if motion is None:
        raise rt.RetimeError("inverse.object_motion: --retime needs the scenario's object motion")
    if method not in methods:
        methods = tuple(methods) + (method,)
    mode = "payload" if model.inverse.payload_position is not None else "scaled"
    T_max = float(motion.times[-1] - motion.times[0]) if duration is None else float(duration)
    path = WaypointPath.of(motion)
    _report(progress, "ik", 0.0)
    s, piece = path_grid(path.knots, intervals)
    guess = model.q0 if motion.initial_guess is None else motion.initial_guess
    jp = joint_path(model, path, s, piece, guess, motion.rest_posture, motion.path_gain)
    fs, fpiece = path_grid(path.knots, FINE * intervals)
    fine = joint_path(model, path, fs, fpiece, guess, motion.rest_posture, motion.path_gain)
    _report(progress, "ik", 1.0)
    out, wl = {}, None
    field = "--duration" if duration is not None else "inverse.object_motion.waypoints"
    for i, k in enumerate(methods):
        _report(progress, "retime", i / len(methods))
        m = model
        if weights and k == "min_energy":
            wl = weights_with_law(model, jp, T_max, mode, field, joint_labels(model))
            m = wl.model
        out[k] = _method_retime(m, jp, fine, k, mode, T_max, payload, field)
    _report(progress, "retime", 1.0)
    _report(progress, "check", 0.0)
    before = capacity_study(model, optimise=False)
    _report(progress, "check", 1.0)
    law = out[method].law_of
    if law is None:
        raise rt.RetimeError(f"--method {method}: no time law carries the load within {T_max:g} s")
    new = rt.retimed_motion(motion, law.law)
    return RetimeStudy(model, mode, T_max, payload, method, path, jp, out, before, new, intervals, wl)


def _method_retime(model: Model, jp, fine, method: str, mode: str, T_max: float, payload: float | None, field: str):
    fdyn = rt.path_dynamics(model, fine, method, mode, fine=None)
    dyn = rt.path_dynamics(model, jp, method, mode, fine=fdyn)
    t0 = time.perf_counter()
    bare = rt.retime(dyn, dyn.nominal_mass)
    t1 = time.perf_counter()
    mass, best, evals = rt.max_payload(dyn, T_max, field=field, names=joint_labels(model))
    t2 = time.perf_counter()
    grid_only = rt.max_payload(dyn, T_max, field=field, names=joint_labels(model), refine=False, at_least=mass)[0]
    chosen = None
    if payload is not None:
        chosen = rt.retime(dyn, float(payload))
        if not chosen.feasible:
            raise rt.RetimeError(f"--payload: no motion carries {payload:g} kg along the path "
                                 f"(static capacity {rt.static_capacity(dyn):.6g} kg)")
    for r in (bare, best, chosen):
        if r is not None and not r.converged:
            raise rt.RetimeError(f"{method}: the linearisation of the motor lines did not converge at {r.mass:.6g} kg "
                                 f"(status: not converged after {r.iterations} linearisations, last relative change "
                                 f"of ṡ² {r.stats.get('relative_change', float('nan')):.3g}); nothing written")
    curve = [(float(dyn.nominal_mass), bare.duration)]
    for mu in np.linspace(dyn.nominal_mass, mass, CURVE_POINTS)[1:-1]:
        r = rt.retime(dyn, float(mu), start=bare.law.b)
        curve.append((float(mu), r.duration))
    curve.append((float(mass), best.duration))
    use = chosen if chosen is not None else best
    return MethodRetime(dyn, bare, best, chosen, curve, rt.check_time_law(dyn, use), fine_check(fdyn, use),
                        rt.saturating(dyn, use), max_velocity_curve(dyn, use), evals, t2 - t1, t1 - t0, grid_only)


def fine_check(fine: rt.PathDynamics, r: rt.Retiming) -> dict:
    """The largest excess over eq. 36 of a time law on a finer grid of the same path (between the points).

    Args:
        fine: the PathDynamics on the finer grid (the same pieces).
        r: the Retiming (its TimeLaw: a constant on each interval, b linear).

    Returns:
        dict: max_excess (relative to τ_s), s and joint of the worst point (the LP bound: with the best
        grasp wrenches at each point, `coopsim.inverse.retime.best_excess`), and max_speed_excess.
    """
    a, b = r.law.at(fine.path.s, fine.path.points.piece)
    f = None
    if fine.method == rt.LP_BOUND:                 # the best distribution at each point, its own LP
        best, f = rt.best_excess(fine, r.mass, a, b)
        i = int(np.argmax(best))
        ex, j = rt.line_excess(fine, r.mass, a[i:i + 1], b[i:i + 1], f[i:i + 1])
        return {"max_excess": float(best[i]), "s": float(fine.path.s[i]), "joint": int(j[int(np.argmax(ex[0]))]),
                "max_speed_excess": rt.speed_excess(fine, b)}
    ex, j = rt.line_excess(fine, r.mass, a, b, f)
    i, jj = np.unravel_index(int(np.argmax(ex)), ex.shape)
    return {"max_excess": float(ex[i, jj]), "s": float(fine.path.s[i]), "joint": int(j[jj]),
            "max_speed_excess": rt.speed_excess(fine, b)}


def max_velocity_curve(dyn: rt.PathDynamics, r: rt.Retiming) -> np.ndarray:
    """√b_max (N,) 1/s: the fastest ṡ each point alone allows (any s̈), the motor lines linearised at the law.

    Args:
        dyn: the PathDynamics of a linear resolution (nan for the LP bound).
        r: the Retiming (its mass and b, where the lines are linearised).

    Returns:
        np.ndarray: (N,) 1/s (inf: no limit at the point).
    """
    N = len(dyn.path.s)
    if dyn.method == rt.LP_BOUND:
        return np.full(N, np.nan)
    b = r.law.b
    G, H, E, _ = rt.motor_rows(dyn, r.mass, rt._tangent(np.maximum(b, 1e-300), max(float(b.max()), 1e-300)))
    scale = max(float(np.max(b)), 1e-12) * 1e6
    G, H, E = rt._boxed(np.concatenate([G, np.zeros((N, 1))], 1), np.concatenate([H, -np.ones((N, 1))], 1),
                        np.concatenate([E, np.zeros((N, 1))], 1), scale, scale)
    _, vb = rt._vertices(G, H, E, 1e-12 * np.max(np.abs(E), axis=1))
    top = np.nanmax(np.where(np.isnan(vb), -np.inf, vb), axis=1)
    return np.sqrt(np.where(top >= scale * (1 - 1e-9), np.inf, np.maximum(top, 0.0)))


# ------------------------------------------------------------------------------------------------
# Summary, series, metadata
# ------------------------------------------------------------------------------------------------

def _retiming_entry(model: Model, r: rt.Retiming | None) -> dict | None:
    if r is None:
        return None
    return {"mass_kg": r.mass, "duration_s": r.duration, "converged": bool(r.converged),
            "linearisations": r.iterations, "solver": r.solver}


def _refinement_entry(mr: MethodRetime, r: rt.Retiming) -> dict | None:
    """The rows the reported law carries between the grid points (`coopsim.inverse.retime.retime`) and the
    payload they cost (the heaviest load within T_max with and without them)."""
    f = r.refine
    if f is None:
        return None
    return {"rounds": f["rounds"], "rows_added": int(len(f["rows"])), "intervals": f["intervals"],
            "max_excess_check_points": f["max_excess"], "within": f["within"], "tolerance": rt.REFINE_TOL,
            "payload_grid_rows_only_kg": mr.grid_only_mass, "payload_kg": mr.best.mass,
            "payload_cost_kg": mr.grid_only_mass - mr.best.mass}


def _certificate_entry(mr: MethodRetime, r: rt.Retiming, names: list[str]) -> dict | None:
    """The grid LP's dual certificate at the law (`coopsim.inverse.retime.certificate`) with its largest dual's
    joint by name."""
    c = (r.stats or {}).get("certificate") or rt.certificate(mr.dyn, r)
    if not c:
        return None
    c = dict(c)
    if "largest" in c:
        big = dict(c["largest"])
        big.pop("point")
        j = big.pop("joint")
        big["motor"] = None if j is None else names[j]
        c["largest"] = big
    return c


def retime_summary(study: RetimeStudy) -> dict:
    """JSON-ready summary of a retiming study (SI units).

    Args:
        study: the RetimeStudy.

    Returns:
        dict: scenario, mode, duration bound, grid, the method carried by the optimised scenario, and per
        method: before (the scenario's own time law: capacity kg, saturating motor), after (heaviest load
        within T_max, its duration, the critical point and motor), bare-object minimum time, asked payload,
        payload–time curve, the exact check on the grid and the finer grid, the saturating motor at each
        grid point, the grid LP's dual certificate (primal and dual objectives, their gap, the binding motor
        line of largest dual), solver statistics and wall times.
    """
    m = study.model
    names = joint_labels(m)
    before = study.before
    out_methods = {}
    for k, mr in study.methods.items():
        b = before.lp.get(study.mode) if k == rt.LP_BOUND else before.caps.get((k, study.mode))
        use = mr.law_of
        sat = mr.saturation
        crit = sat["critical"]
        out_methods[k] = {
            "before": None if b is None else {"mass_kg": b.mass, "duration_s": float(before.traj.t[-1] - before.traj.t[0]),
                                              "saturating_motor": None if b.joint is None else names[b.joint],
                                              "time_s": b.time},
            "after": {**_retiming_entry(m, mr.best), "critical_s": crit["s"],
                      "critical_motor": names[crit["joint"]],
                      "critical_excess": float(sat["excess"][crit["index"]])},
            "bare_object": _retiming_entry(m, mr.bare),
            "payload": _retiming_entry(m, mr.chosen),
            "payload_time_curve": [{"mass_kg": a, "duration_s": t} for a, t in mr.curve],
            "check_grid": {"max_excess": mr.grid_check["max_excess"], "s": mr.grid_check["s"],
                           "max_speed_excess": mr.grid_check["max_speed_excess"],
                           "motor": None if mr.grid_check["joint"] is None else names[mr.grid_check["joint"]],
                           "law": "payload" if mr.chosen is not None else "after"},
            "check_fine_grid": {"max_excess": mr.fine_check["max_excess"], "s": mr.fine_check["s"],
                                "max_speed_excess": mr.fine_check["max_speed_excess"],
                                "motor": names[mr.fine_check["joint"]], "points_per_interval": FINE,
                                "refinement": _refinement_entry(mr, use)},
            "saturating_motor_per_point": [names[j] for j in sat["joint"]],
            "on_line_per_point": [bool(x) for x in sat["on_line"]],
            "solver": {"name": use.solver, "heaviest_load_evaluations": mr.evaluations,
                       "heaviest_load_wall_s": mr.wall_s, "bare_object_retime_wall_s": mr.retime_s,
                       **({} if not use.stats else {kk: v for kk, v in use.stats.items()
                                                    if kk not in ("f", "f_fine", "certificate")})},
            "dual_certificate": _certificate_entry(mr, use, names),
        }
        if k == "min_energy" and study.weights is not None:
            out_methods[k]["energy_weights"] = _weights_entry(study.weights, names)
    return {
        "scenario": m.name, "mode": study.mode,
        "mass_meaning": ("a point payload at inverse.payload.position (object frame), kg" if study.mode == "payload"
                         else "the whole object scaled at constant geometry, kg"),
        "duration_bound_s": study.duration_bound,
        "grid": {"intervals_per_segment": study.intervals, "points": len(study.joint.s),
                 "segments": len(study.path.knots) - 1},
        "method": study.method,
        "time_law": {"kind": "sampled", "samples": len(study.motion.samples.t),
                     "waypoint_times_s": study.motion.times.tolist()},
        "methods": out_methods,
    }


def _weights_entry(wl: WeightedLaw, names: list[str]) -> dict:
    """The optimised energy weights by joint and the heaviest load of each kept round (the first: the
    scenario's own weights)."""
    return {"weights": {n: float(w) for n, w in zip(names, wl.weights)},
            "rounds": [{"mass_kg": float(mass), "weights": [float(x) for x in w]} for w, mass in wl.rounds],
            "gain": float(wl.mass / wl.rounds[0][1])}


def format_retime_summary(s: dict) -> str:
    """Short text version of `retime_summary`.

    Args:
        s: the summary dict.

    Returns:
        str: the lines of the report.
    """
    lines = [f"scenario        {s['scenario']}: path of {s['grid']['segments']} segments, "
             f"{s['grid']['points']} grid points; T_max {s['duration_bound_s']:g} s; mass: {s['mass_meaning']}",
             "",
             f"{'method':<14}{'before kg':>12}{'after kg':>12}{'bare min s':>12}{'grid excess':>13}"
             f"{'fine excess':>13}  critical motor"]
    for k, e in s["methods"].items():
        before = e["before"]["mass_kg"] if e["before"] else float("nan")
        lines.append(f"{k:<14}{before:>12.4f}{e['after']['mass_kg']:>12.4f}{e['bare_object']['duration_s']:>12.4f}"
                     f"{e['check_grid']['max_excess']:>13.2e}{e['check_fine_grid']['max_excess']:>13.2e}  "
                     f"{e['after']['critical_motor']} at s={e['after']['critical_s']:.4g}")
    ew = s["methods"].get("min_energy", {}).get("energy_weights")
    if ew is not None:
        lines.append(f"min_energy weights optimised with the law: {ew['rounds'][0]['mass_kg']:.4f} -> "
                     f"{ew['rounds'][-1]['mass_kg']:.4f} kg in {len(ew['rounds']) - 1} rounds, Q = "
                     + " ".join(f"{w:.3g}" for w in ew["weights"].values()))
    lines.append(f"optimised scenario: the {s['method']} time law ({s['time_law']['samples']} samples), "
                 f"waypoints at {', '.join(f'{t:.4g}' for t in s['time_law']['waypoint_times_s'])} s")
    return "\n".join(lines)


def retime_series(study: RetimeStudy) -> list:
    """Series for the MCAP log of a retiming study.

    /optimize/<method>/law (per grid point: s, ṡ, s̈, the maximum-velocity curve; at the law's times),
    /optimize/<method>/torque (τ and the motor lines at the law's grid points, right side) and
    /optimize/<method>/before (τ at the scenario's own capacity and the lines, at its samples).

    Args:
        study: the RetimeStudy.

    Returns:
        list[Series]: SI units.
    """
    out = []
    for k, mr in study.methods.items():
        r = mr.law_of
        law = r.law
        keep = np.concatenate([np.diff(law.t) > 0, [True]])       # one sample per time (knots once)
        tau = mr.dyn.torques(r.mass, law.point_accel(), law.b, rt.point_wrenches(r))
        qd = mr.dyn.path.d1 * np.sqrt(law.b)[:, None]
        drop = mr.dyn.slope * qd
        out.append(Series(f"/optimize/{k}/law", "coopsim.optimize.Law", law.t[keep],
                          {"s": law.s[keep], "sdot": np.sqrt(law.b[keep]), "sddot": law.a[keep],
                           "max_sdot": mr.mvc[keep]}))
        out.append(Series(f"/optimize/{k}/torque", "coopsim.optimize.Torque", law.t[keep],
                          {"tau": tau[keep], "qd": qd[keep], "tau_max": (mr.dyn.stall - drop)[keep],
                           "tau_min": (-mr.dyn.stall - drop)[keep]}))
        before = study.before
        key = (k, study.mode)
        if key in before.tau_at:
            lo, hi = before.limits
            out.append(Series(f"/optimize/{k}/before", "coopsim.optimize.Torque", before.traj.t,
                              {"tau": before.tau_at[key], "qd": before.traj.qd, "tau_max": hi, "tau_min": lo}))
    return out


def retime_metadata(summary: dict) -> dict:
    """MCAP metadata records of a retiming study: "optimize.<method>" (before, after, bare object, curve).

    Args:
        summary: the retiming summary.

    Returns:
        dict: record name → a dict of the summary.
    """
    return {f"optimize.{k}": {"before_mass_kg": None if e["before"] is None else e["before"]["mass_kg"],
                              "after_mass_kg": e["after"]["mass_kg"], "critical_motor": e["after"]["critical_motor"],
                              "bare_duration_s": e["bare_object"]["duration_s"],
                              "curve_mass_kg": [c["mass_kg"] for c in e["payload_time_curve"]],
                              "curve_duration_s": [c["duration_s"] for c in e["payload_time_curve"]]}
            for k, e in summary["methods"].items()} | {"optimize": {"duration_bound_s": summary["duration_bound_s"],
                                                                  "mode": summary["mode"],
                                                                  "method": summary["method"]}}


def optimised_scenario(data: dict, motion: ObjectMotion) -> dict:
    """The scenario's data with its object motion retimed: waypoint times and a sampled time law.

    Args:
        data: the scenario file's data (as read, with any --set applied).
        motion: the optimised ObjectMotion (time law 'sampled').

    Returns:
        dict: a copy; inverse.object_motion's waypoints carry the new times, time_law 'sampled',
        rest_pull and rest_gain (the motion's: 'path', and the gain that keeps the pull per unit path, for a
        retimed one) and time_law_samples {t, s, rate}.
    """
    out = copy.deepcopy(data)
    om = out["inverse"]["object_motion"]
    for wp, t in zip(om["waypoints"], motion.times):
        wp["time"] = float(t)
    om["time_law"] = "sampled"
    om["rest_pull"], om["rest_gain"] = motion.rest_pull, float(motion.rest_gain)
    om["time_law_samples"] = {"t": [float(x) for x in motion.samples.t], "s": [float(x) for x in motion.samples.s],
                              "rate": [float(x) for x in motion.samples.rate]}
    return out


def with_energy_weights(data: dict, model: Model, weights) -> dict:
    """The scenario's data with every arm's `energy_weights` set from the stacked weights.

    Args:
        data: the scenario file's data.
        model: the Model (its arms' joint counts, in stacking order).
        weights: (n_total,) the energy weights Q, arm after arm.

    Returns:
        dict: a copy; arms[i].energy_weights the arm's slice.
    """
    out = copy.deepcopy(data)
    start = 0
    for arm, a in zip(out["arms"], model.arms):
        arm["energy_weights"] = [float(w) for w in weights[start:start + a.n]]
        start += a.n
    return out


def with_motion(model: Model, motion: ObjectMotion) -> Model:
    """The model with its object motion replaced.

    Args:
        model: the Model.
        motion: the ObjectMotion.

    Returns:
        Model: a copy.
    """
    return replace(model, inverse=replace(model.inverse, object_motion=motion))
