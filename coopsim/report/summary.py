"""Plain-data summaries of results, shared by the CLI's text and JSON outputs (no I/O here)."""

from __future__ import annotations

import numpy as np

from coopsim.core.joints import COORDINATE, type_names, units_of
from coopsim.forward.simulate import SimResult


def kinetic_energy_summary(res: SimResult) -> dict:
    """Kinetic energy ½θ̇ᵀ𝐈θ̇ of the run (J): first, last, and its largest change from the first sample.

    The change is given absolute, and relative to the largest value.

    Args:
        res: the SimResult (its kinetic_energy (N,) J, torques and the model's gravity).

    Returns:
        dict: initial_J, final_J, max_change_J (J), max_relative_change (of the largest |value|; 0 when
        that is 0), and `conserved`: no torque and no gravity act, so any change is the integration's
        (and the stabilization's) drift.
    """
    ke = res.kinetic_energy
    change = float(np.max(np.abs(ke - ke[0])))
    peak = float(np.max(np.abs(ke)))
    conserved = not np.any(res.model.gravity) and not np.any(res.tau)
    return {"initial_J": float(ke[0]), "final_J": float(ke[-1]), "max_change_J": change,
            "max_relative_change": change / peak if peak > 0 else 0.0, "conserved": bool(conserved)}


def simulation_summary(res: SimResult) -> dict:
    """JSON-ready summary of a forward simulation.

    SI units; a prismatic joint's entries of the `_rad` joint vectors are in m; wall_time_s is the only
    non-deterministic entry.

    Args:
        res: the SimResult.

    Returns:
        dict: scenario, arms, joints, joint types, constraint rows, duration, samples, integrator and
        engine, the initial correction, the final q (rad or m) and object position (m, world), peak
        constraint residuals, condition number and internal force (N), each arm's least manipulability,
        `kinetic_energy_summary`, `warnings` (the run's `coopsim.forward.diagnostics.RunWarning`s as
        dicts), the integrator's counts, wall_time_s, and `controller` (`control_counts_summary`) when
        the compiled closed loop counted its controller.
    """
    m, init = res.model, res.initial
    return {
        "scenario": m.name,
        "arms": [a.name for a in m.arms],
        "joints": m.n_total,
        "joint_types": type_names(m.joint_type),
        "constraint_rows": "planar" if m.plane is not None else "spatial",
        "duration_s": float(res.t[-1]),
        "samples": len(res.t),
        "integrator": m.integrator.method,
        "stabilization": m.integrator.stabilization,
        "engine": res.engine,
        "initial_correction": {
            "max_abs_dq_rad": float(np.max(np.abs(init.dq))),
            "max_abs_dqd_rad_s": float(np.max(np.abs(init.dqd))),
            "dq_rad": init.dq.tolist(),
            "residual_before": init.residual_before,
            "residual_after": init.residual_after,
            "iterations": init.iterations,
        },
        "final_q_rad": res.q[-1].tolist(),
        "final_object_position_m": res.object_pos[-1].tolist(),
        "max_constraint_residual": float(np.max(res.residual_pos)),
        "max_velocity_residual": float(np.max(res.residual_vel)),
        "max_condition_number": float(np.max(res.cond)),
        "max_internal_force_N": float(np.max(np.linalg.norm(res.internal_wrench[:, :, :3], axis=2))),
        "min_manipulability": np.min(res.manipulability, axis=0).tolist(),
        "kinetic_energy": kinetic_energy_summary(res),
        "warnings": [w.as_dict() for w in res.warnings],
        "rhs_evaluations": res.stats.n_rhs,
        "steps_accepted": res.stats.n_accepted,
        "steps_rejected": res.stats.n_rejected,
        "wall_time_s": res.wall_time,
    } | ({} if res.control_counts is None else {"controller": control_counts_summary(res.control_counts)})


def control_counts_summary(counts: tuple[int, int, int]) -> dict:
    """The compiled closed loop's controller counts (`SimResult.control_counts`).

    Args:
        counts: (evaluations, evaluations in which the motor lines clipped a joint, clipped (evaluation,
            joint) pairs).

    Returns:
        dict: evaluations, saturated_evaluations, saturated_joint_evaluations.
    """
    return dict(zip(("evaluations", "saturated_evaluations", "saturated_joint_evaluations"), counts))


def run_summary(cv, log_path, plots) -> dict:
    """summary.json of `coopsim run`: the native summary, the agreement metrics, both wall times, the files.

    Args:
        cv: the CrossValidation of the run (`coopsim.twin.harness`).
        log_path: the MCAP log written (str or Path).
        plots: the paths of the figures written.

    Returns:
        dict: native (`simulation_summary`), agreement (`Comparison.as_dict`), wall_time_s (s, native,
        mujoco and their ratio), mujoco (timestep s, integrator, weld solref as the twin ran, and where the
        step was chosen or a failure explained `TwinStep.as_dict`), files, and control
        (`control_summary`) with a controller.
    """
    return {
        "native": simulation_summary(cv.native),
        "agreement": cv.comparison.as_dict(),
        "wall_time_s": {"native": cv.native.wall_time, "mujoco": cv.twin.wall_time,
                        "native_over_mujoco": cv.native.wall_time / cv.twin.wall_time},
        "mujoco": _twin_settings(cv.mujoco or cv.native.model.mujoco)
                  | ({} if cv.step is None else cv.step.as_dict()),
        "files": {"log": str(log_path), "plots": [str(p) for p in plots]},
    } | ({} if cv.control is None else {"control": control_summary(cv)})


def _twin_settings(st) -> dict:
    """The twin's step (s), integrator and welds' solref as it ran."""
    return {"timestep_s": st.timestep, "integrator": st.integrator, "weld_solref": list(st.solref())}


def control_summary(cv) -> dict:
    """The controller along both runs: law, tracking errors, saturation events, the open-loop replay.

    The peak tracking error (joint angles rad, or object position m and orientation rad) at the last
    sample and over the run, the saturation events (sample × joint), and the largest differences of the
    open-loop replay (`coopsim.twin.harness.CrossValidation.replay`).

    Args:
        cv: the CrossValidation of a run with a controller (its control records and replay set).

    Returns:
        dict: law; native and mujoco, each {max_error, final_error, saturation_events}; and
        open_loop_replay_max (the replay's first four metrics' max, in their units).
    """
    out = {"law": cv.native.model.control.law}
    for who, rec in zip(("native", "mujoco"), cv.control):
        if out["law"] == "joint_pd":
            err = {"angle_rad": np.max(np.abs(rec.angle_error), axis=1)}
        else:
            err = {"position_m": np.linalg.norm(rec.object_error[:, :3], axis=1),
                   "orientation_rad": np.linalg.norm(rec.object_error[:, 3:], axis=1)}
        out[who] = {"max_error": {k: float(v.max()) for k, v in err.items()},
                    "final_error": {k: float(v[-1]) for k, v in err.items()},
                    "saturation_events": rec.saturation_events}
    out["open_loop_replay_max"] = {m.name: m.max for m in cv.replay.metrics[:4]}
    return out


def format_simulation_summary(s: dict) -> str:
    """Short human-readable version of `simulation_summary`.

    Args:
        s: the dict `simulation_summary` returns (or its JSON read back).

    Returns:
        str: one line per item, without a trailing newline.
    """
    ic, ke = s["initial_correction"], s["kinetic_energy"]
    unit = units_of(s.get("joint_types") or ["revolute"], COORDINATE, sep=", ")
    lines = [
        f"scenario        {s['scenario']}: {len(s['arms'])} arms, {s['joints']} joints, "
        f"{s['constraint_rows']} constraint rows",
        f"initial state   loop-closure residual {ic['residual_before']:.3g} -> {ic['residual_after']:.3g} "
        f"(max joint correction {ic['max_abs_dq_rad']:.3g} {unit}, {ic['iterations']} Gauss-Newton steps)",
        f"integration     {s['integrator']} + {s['stabilization']}, {s['duration_s']:g} s, "
        f"{s['steps_accepted']} steps "
        f"({s['steps_rejected']} rejected), {s['rhs_evaluations']} evaluations, {s['wall_time_s']:.2f} s wall "
        f"({s.get('engine', 'compiled')} engine)",
        f"{f'final q ({unit})':<15} [{', '.join(f'{x:.6f}' for x in s['final_q_rad'])}]",
        f"final object    [{', '.join(f'{x:.6f}' for x in s['final_object_position_m'])}] m",
        f"constraints     max |phi| {s['max_constraint_residual']:.3g}, "
        f"max |Lambda qd| {s['max_velocity_residual']:.3g}, "
        f"max cond {s['max_condition_number']:.3g}",
        f"internal force  max {s['max_internal_force_N']:.4g} N",
        f"kinetic energy  {ke['initial_J']:.6g} -> {ke['final_J']:.6g} J, max change {ke['max_change_J']:.3g} J "
        f"({ke['max_relative_change']:.3g} of the peak"
        f"{'; nothing does work: this is drift' if ke['conserved'] else ''})",
        f"warnings        {len(s['warnings']) or 'none'}",
    ]
    if "controller" in s:
        c = s["controller"]
        lines.append(f"controller      {c['evaluations']} evaluations, "
                     f"{c['saturated_evaluations']} with a joint clipped "
                     f"at its motor line ({c['saturated_joint_evaluations']} joint clippings)")
    return "\n".join(lines)
