"""Run diagnostics: what a forward run's own samples say about how far to trust it, as warnings.

A run can finish and still be wrong, or right but fragile; each check below turns one such case into a
`RunWarning` that names the time, the configuration and the reason (`coopsim simulate` and `coopsim run`
print them, `summary.json` and the run log's metadata record them):

- `rank_deficient`: Λ𝐈⁻¹Λᵀ lost rank while integrating (minimum-norm grasp wrenches; found by the
  integrator, `coopsim.forward.simulate`);
- `ill_conditioned`: its condition number above `integrator.condition_limit` at some sample (the chain
  is near a singular configuration: grasp and internal wrenches lose about log10(cond) digits, and a
  small torque can ask for a large internal force); `integrator.on_ill_conditioning: error` stops the
  run instead (`first_ill_conditioned`);
- `arm_singularity`: an arm's end-effector Jacobian in the scene's rows near rank loss (σ_min/σ_max of
  the Jacobian with its linear rows divided by the arm's reach below `integrator.singularity_limit`), or
  passing through one (det changes sign between two samples, square Jacobians);
- `initial_correction`: closing the loop at t = 0 moved a joint by more than
  `integrator.initial_correction_warning` rad;
- `joint_limit`: a joint outside its position range (`Model.joint_range`, from a robot file or a
  joint's `range`) at some sample (the dynamics do not enforce the limits);
- `step_too_large`: a fixed rk4 step whose local error, estimated by step doubling at up to
  `STEP_CHECK_SAMPLES` samples, exceeds the requested accuracy atol + rtol·|y|.

Also the per-sample quantities they rest on: each arm's manipulability √det(A Aᵀ), A = S J_m (the
product of A's singular values; S the scene's constraint rows, J_m the end-effector Jacobian at the EE
point, world axes) and the kinetic energy ½θ̇ᵀ𝐈θ̇ of arms and object. Pure functions of a model and
sampled arrays (the compiled per-sample terms, `coopsim.compiled.api.inverse_terms`); no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from coopsim.core.joints import COORDINATE, joint_units
from coopsim.core.labels import arm_label, joint_labels
from coopsim.core.model import Model, TorqueFunction, applied_torque

STEP_CHECK_SAMPLES = 64   # states at which a fixed rk4 step is checked by step doubling


def describe_state(t: float, q: np.ndarray) -> str:
    """'t=0.35 s, q=[0.1, …] rad': the time and configuration every failure and warning names.

    Args:
        t: s, the time.
        q: (n,) rad (m on a prismatic joint), the stacked joint coordinates.

    Returns:
        str: the one-line state text (6 significant digits).
    """
    return f"t={t:.6g} s, q=[{', '.join(f'{x:.6g}' for x in q)}] rad"


@dataclass(frozen=True)
class RunWarning:
    """One warning about a run: where it applies, why, and the numbers it names.

    Attributes:
        kind: the check that raised it (see the module docstring): 'rank_deficient', 'ill_conditioned',
            'arm_singularity', 'initial_correction', 'joint_limit', 'step_too_large', or a controller's
            ('distribution_fallback').
        t: s, the time it names.
        q: (n,) rad (m on a prismatic joint), the stacked joint coordinates there.
        reason: the one-line reason.
        values: the numbers it names, name → float, SI.
    """

    kind: str
    t: float
    q: tuple[float, ...]
    reason: str
    values: dict = field(default_factory=dict)

    def message(self) -> str:
        """'at t=…, q=[…] rad: reason' (one line).

        Returns:
            str: the warning's message.
        """
        return f"at {describe_state(self.t, self.q)}: {self.reason}"

    def as_dict(self) -> dict:
        """The warning as JSON-ready data (summary.json, the run log's metadata).

        Returns:
            dict: {"kind", "t_s" (s), "q_rad" (list of n floats), "reason", "values" (name → float)}.
        """
        return {"kind": self.kind, "t_s": self.t, "q_rad": list(self.q), "reason": self.reason,
                "values": dict(self.values)}


def run_warning(kind: str, t: float, q: np.ndarray, reason: str, **values) -> RunWarning:
    """A RunWarning with its time, configuration and values as plain floats.

    Args:
        kind: the check that raised it (module docstring).
        t: s, the time it names.
        q: (n,) rad (m on a prismatic joint), the stacked joint coordinates there.
        reason: the one-line reason.
        values: the numbers it names (SI), each converted with float().

    Returns:
        RunWarning: the warning (q as a tuple of floats).
    """
    return RunWarning(kind, float(t), tuple(float(x) for x in q), reason, {k: float(v) for k, v in values.items()})


# ------------------------------------------------------------------------------------------------
# per-sample quantities
# ------------------------------------------------------------------------------------------------

class ArmTerms(NamedTuple):
    """Per-sample arm terms of the diagnostics (S samples, n joints, r arms, nmax joints per arm at most).

    Attributes:
        J: (S, r, 6, nmax) the end-effector Jacobians J_m (columns 0:n_m of arm m), world axes, EE point.
        I_qd: (S, n) N·m·s (N·s on a prismatic joint), 𝐈_m θ̇_m per arm (no object), stacked arm by arm.
        R_o: (S, 3, 3) the object rotation, world ← object frame.
    """

    J: np.ndarray
    I_qd: np.ndarray
    R_o: np.ndarray


def arm_terms(model: Model, q: np.ndarray, qd: np.ndarray) -> ArmTerms:
    """`ArmTerms` at the states (q, qd).

    The compiled per-sample inverse-dynamics terms (`coopsim.compiled.api.inverse_terms`) at θ̈ = θ̇ and
    at θ̈ = 0, whose difference is 𝐈_m θ̇_m.

    Args:
        model: the Model.
        q: (S, n) rad (m on a prismatic joint), the stacked joint coordinates at S samples.
        qd: (S, n) rad/s (m/s), the joint rates.

    Returns:
        ArmTerms: J (S, r, 6, nmax), I_qd (S, n), R_o (S, 3, 3), world axes.
    """
    from coopsim.compiled import api

    with_rate = api.inverse_terms(model, q, qd, qd)
    without = api.inverse_terms(model, q, qd, np.zeros_like(qd))
    return ArmTerms(with_rate.J, with_rate.tau_arms - without.tau_arms, with_rate.R_o)


def _row_jacobians(model: Model, J: np.ndarray, m: int, scaled: bool = False) -> np.ndarray:
    """A = S J_m (S, k, n_m) of arm m; `scaled`: linear rows divided by the arm's reach (dimensionless)."""
    arm = model.arms[m]
    Jm = J[:, m, :, :arm.n]
    if scaled:
        reach = float(np.sum(np.linalg.norm(arm.joint_pos[1:], axis=1)) + np.linalg.norm(arm.ee_pos))
        Jm = Jm * np.r_[np.full(3, 1.0 / reach if reach > 0 else 1.0), np.ones(3)][:, None]
    return np.einsum("kc,scj->skj", model.rows, Jm)


def manipulability(model: Model, J: np.ndarray) -> np.ndarray:
    """Each arm's manipulability: the product of the singular values of A = S J_m (k × n_m).

    This is √det(A Aᵀ) for k ≤ n_m (Yoshikawa's measure in the scene's rows; units m^(linear rows)); zero
    at a singular configuration.

    Args:
        model: the Model (its constraint rows S (k, 6)).
        J: (S, r, 6, nmax) the end-effector Jacobians (`ArmTerms.J`), world axes, EE point.

    Returns:
        np.ndarray: (S, r) the manipulability of each arm at each sample.
    """
    return np.stack([np.prod(np.linalg.svd(_row_jacobians(model, J, m), compute_uv=False), axis=1)
                     for m in range(model.r)], axis=1)


def kinetic_energy(model: Model, qd: np.ndarray, terms: ArmTerms, twist: np.ndarray) -> np.ndarray:
    """Kinetic energy of arms and object: ½ Σ_m θ̇_mᵀ 𝐈_m θ̇_m + ½ (m_o |v_C|² + ωᵀ R_o I_o R_oᵀ ω).

    This equals ½ θ̇ᵀ 𝐈 θ̇ of the closed chain.

    Args:
        model: the Model (the object's mass kg and inertia I_o (3, 3) kg·m² about C, object axes).
        qd: (S, n) rad/s (m/s on a prismatic joint), the joint rates.
        terms: the `ArmTerms` at those states (I_qd, R_o).
        twist: (S, 6) [v_C (m/s); ω (rad/s)], the object's twist at C, world axes.

    Returns:
        np.ndarray: (S,) J, the kinetic energy at each sample.
    """
    obj = model.object
    v, w = twist[:, :3], twist[:, 3:]
    w_body = np.einsum("sji,sj->si", terms.R_o, w)
    return 0.5 * (np.sum(qd * terms.I_qd, axis=1) + obj.mass * np.sum(v * v, axis=1)
                  + np.einsum("si,ij,sj->s", w_body, obj.inertia, w_body))


# ------------------------------------------------------------------------------------------------
# checks
# ------------------------------------------------------------------------------------------------

def _internal_force(internal_wrench: np.ndarray) -> np.ndarray:
    """max over arms of |F_I| (S,) N."""
    return np.max(np.linalg.norm(internal_wrench[:, :, :3], axis=2), axis=1)


def first_ill_conditioned(model: Model, cond: np.ndarray) -> int | None:
    """Index of the first sample whose condition number exceeds integrator.condition_limit, or None.

    Args:
        model: the Model (its integrator.condition_limit).
        cond: (S,) the condition number of Λ𝐈⁻¹Λᵀ at each sample (nan counts as above the limit).

    Returns:
        int | None: the 0-based sample index, or None when every sample is within the limit.
    """
    above = np.flatnonzero(~(cond <= model.integrator.condition_limit))
    return int(above[0]) if len(above) else None


def ill_conditioning_reason(model: Model, cond: float, force: float) -> str:
    """The one-line reason of an ill-conditioned constraint matrix (warning or error).

    Args:
        model: the Model (its integrator.condition_limit).
        cond: the condition number of Λ𝐈⁻¹Λᵀ at the sample.
        force: N, the largest internal force |F_I| over the arms there.

    Returns:
        str: the reason, naming the condition number, the limit, the digits lost and the force.
    """
    lim = model.integrator.condition_limit
    digits = np.log10(cond) if np.isfinite(cond) else np.inf
    return (f"constraint matrix Λ𝐈⁻¹Λᵀ is ill-conditioned: condition number {cond:.3g} > "
            f"integrator.condition_limit = {lim:g} (the chain is near a singular configuration: grasp and internal "
            f"wrenches lose about {digits:.0f} digits); internal force there {force:.4g} N")


def conditioning(model: Model, t, q, cond, internal_wrench) -> list[RunWarning]:
    """An `ill_conditioned` warning at the sample of largest condition number, if above the limit.

    Args:
        model: the Model (its integrator.condition_limit).
        t: (S,) s, the sample times.
        q: (S, n) rad (m on a prismatic joint), the stacked joint coordinates.
        cond: (S,) the condition number of Λ𝐈⁻¹Λᵀ (nan counts as infinite).
        internal_wrench: (S, r, 6) [N; N·m], the internal wrenches at C, world axes.

    Returns:
        list[RunWarning]: one warning, or none when no sample is above the limit.
    """
    if first_ill_conditioned(model, cond) is None:
        return []
    i = int(np.argmax(np.where(np.isnan(cond), np.inf, cond)))
    force = _internal_force(internal_wrench)
    reason = ill_conditioning_reason(model, cond[i], force[i]) + f" (max over the run {np.max(force):.4g} N)"
    return [run_warning("ill_conditioned", t[i], q[i], reason, condition_number=cond[i], internal_force_N=force[i],
                        max_internal_force_N=np.max(force))]


def arm_singularities(model: Model, t, q, J) -> list[RunWarning]:
    """Per arm, at most one `arm_singularity` warning.

    Where the arm's end-effector Jacobian in the scene's rows passes through a singularity (square: det
    changes sign between two samples), else at its most singular sample if σ_min/σ_max (linear rows
    over the reach) is below integrator.singularity_limit.

    Args:
        model: the Model (its rows S, arms and integrator.singularity_limit).
        t: (S,) s, the sample times.
        q: (S, n) rad (m on a prismatic joint), the stacked joint coordinates.
        J: (S, r, 6, nmax) the end-effector Jacobians (`ArmTerms.J`), world axes, EE point.

    Returns:
        list[RunWarning]: the warnings, in arm order (values: arm 1-based, manipulability, sigma_ratio).
    """
    out = []
    lim = model.integrator.singularity_limit
    w = manipulability(model, J)
    for m, arm in enumerate(model.arms):
        A = _row_jacobians(model, J, m, scaled=True)
        sv = np.linalg.svd(A, compute_uv=False)
        ratio = sv[:, -1] / sv[:, 0]
        label = arm_label(arm.name, m)
        if A.shape[1] == A.shape[2] and len(t) > 1:
            flips = np.flatnonzero(np.sign(np.linalg.det(A[:-1])) * np.sign(np.linalg.det(A[1:])) < 0)
            if len(flips):
                i = int(flips[0]) + int(ratio[flips[0] + 1] < ratio[flips[0]])
                out.append(run_warning(
                    "arm_singularity", t[i], q[i],
                    f"{label} passes through a singular configuration between t={t[flips[0]]:.6g} s and "
                    f"t={t[flips[0] + 1]:.6g} s (det of its end-effector Jacobian in the scene's rows changes sign; "
                    f"manipulability {w[i, m]:.3g}, σ_min/σ_max {ratio[i]:.3g})",
                    arm=m + 1, manipulability=w[i, m], sigma_ratio=ratio[i]))
                continue
        i = int(np.argmin(ratio))
        if ratio[i] < lim:
            out.append(run_warning(
                "arm_singularity", t[i], q[i],
                f"{label} is near a singular configuration: σ_min/σ_max of its end-effector Jacobian in the scene's "
                f"rows {ratio[i]:.3g} < integrator.singularity_limit = {lim:g} (manipulability {w[i, m]:.3g})",
                arm=m + 1, manipulability=w[i, m], sigma_ratio=ratio[i]))
    return out


def initial_correction(model: Model, init) -> list[RunWarning]:
    """An `initial_correction` warning when closing the loop at t = 0 moved a joint too far.

    Too far: by more than integrator.initial_correction_warning. The configuration named is the
    scenario's, before the correction.

    Args:
        model: the Model (its q0 and integrator settings).
        init: the Projection of the initial state (`coopsim.core.results.Projection`: dq (n,) rad or m,
            residual_before m or rad).

    Returns:
        list[RunWarning]: one warning, or none when every |dq| is within the limit.
    """
    s = model.integrator
    j = int(np.argmax(np.abs(init.dq)))
    worst = float(abs(init.dq[j]))
    if worst <= s.initial_correction_warning:
        return []
    return [run_warning(
        "initial_correction", 0.0, model.q0,
        f"arms[].initial is off the loop closure by {init.residual_before:.3g} (m or rad): closing it moved "
        f"{joint_labels(model)[j]} by {init.dq[j]:.4g} {joint_units(model.joint_type[j])[COORDINATE]} "
        f"(> integrator.initial_correction_warning = "
        f"{s.initial_correction_warning:g} rad; integrator.max_initial_correction = {s.max_initial_correction:g} rad "
        f"stops the run)", max_correction_rad=worst, residual_before=init.residual_before)]


def joint_limit_violation(model: Model, q: np.ndarray) -> tuple[int, int] | None:
    """The first sample (then the first joint) of q outside `Model.joint_range`.

    Args:
        model: the Model (its joint_range (n, 2) rad or m, or None).
        q: (S, n) rad (m on a prismatic joint), the stacked joint coordinates.

    Returns:
        tuple[int, int] | None: (sample i, stacked joint j), 0-based; None when no joint leaves its range
        (also when the model has no ranges).
    """
    if model.joint_range is None:
        return None
    lo, hi = model.joint_range.T
    bad = np.argwhere((q < lo) | (q > hi))
    return None if len(bad) == 0 else (int(bad[0, 0]), int(bad[0, 1]))


def joint_limit_reason(model: Model, j: int, value: float) -> str:
    """'arm 1 (left) joint 4 at -3.1 rad is outside its range [-3.07, -0.07] rad'.

    Args:
        model: the Model (its joint_range and joint labels).
        j: the stacked joint index, 0-based.
        value: rad (m on a prismatic joint), the joint's coordinate.

    Returns:
        str: the one-line reason.
    """
    lo, hi = model.joint_range[j]
    return (f"{joint_labels(model)[j]} at {value:.6g} rad is outside its range "
            f"[{lo:.6g}, {hi:.6g}] rad")


def joint_limits(model: Model, t, q) -> list[RunWarning]:
    """A `joint_limit` warning at the first sample where a joint leaves its range.

    Args:
        model: the Model (its joint_range).
        t: (S,) s, the sample times.
        q: (S, n) rad (m on a prismatic joint), the stacked joint coordinates.

    Returns:
        list[RunWarning]: one warning (values: joint 1-based, angle_rad), or none.
    """
    hit = joint_limit_violation(model, q)
    if hit is None:
        return []
    i, j = hit
    return [run_warning("joint_limit", t[i], q[i], joint_limit_reason(model, j, q[i, j]) +
                        " (the dynamics do not enforce joint limits)", joint=j + 1, angle_rad=q[i, j])]


def _torques(model: Model, t: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """τ (S, n) at times t (S,) and states Y (S, 2n) (a controller in the loop reads the state)."""
    if isinstance(model.torques, TorqueFunction):
        n = model.n_total
        return np.array([applied_torque(model.torques, ti, y[:n], y[n:]) for ti, y in zip(t, Y)])
    from coopsim.compiled.api import compiled, tabulated_torques

    return tabulated_torques(compiled(model).P, t)


def rk4_local_error(model: Model, t: np.ndarray, Y: np.ndarray, h: float) -> np.ndarray:
    """Step-doubling estimate of one rk4 step's local error from each state: 16/15 |y_h − y_{h/2,h/2}|.

    The h/2 pair is 16 times more accurate at order 4. The closed chain is evaluated compiled, with the
    model's torques at each stage (a controller in the loop reads the state).

    Args:
        model: the Model.
        t: (S,) s, the times of the states.
        Y: (S, 2n) the states [θ; θ̇] (rad or m, rad/s or m/s).
        h: s, the step.

    Returns:
        np.ndarray: (S, 2n) the error estimate per component, in the units of Y.
    """
    from coopsim.compiled import api

    n = model.n_total

    def f(ts, Ys):
        return np.hstack([Ys[:, n:], api.evaluate_states(model, Ys, _torques(model, ts, Ys)).qdd])

    def step(ts, Ys, dt):
        k1 = f(ts, Ys)
        k2 = f(ts + dt / 2, Ys + dt / 2 * k1)
        k3 = f(ts + dt / 2, Ys + dt / 2 * k2)
        k4 = f(ts + dt, Ys + dt * k3)
        return Ys + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)

    return np.abs(step(t, Y, h) - step(t + h / 2, step(t, Y, h / 2), h / 2)) * (16 / 15)


def step_size(model: Model, t, q, qd) -> list[RunWarning]:
    """A `step_too_large` warning when a fixed rk4 step's local error exceeds atol + rtol·|y| somewhere.

    The error is `rk4_local_error` at up to STEP_CHECK_SAMPLES samples, evenly spread; the warning names
    the worst sample and a step that would meet the tolerance (the error scales as h⁵). Only for
    integrator.method rk4.

    Args:
        model: the Model (its integrator settings: method, step s, rtol, atol).
        t: (S,) s, the sample times.
        q: (S, n) rad (m on a prismatic joint), the stacked joint coordinates.
        qd: (S, n) rad/s (m/s), the joint rates.

    Returns:
        list[RunWarning]: one warning (values: error_ratio, local_error, suggested_step_s), or none.
    """
    s = model.integrator
    if s.method != "rk4" or len(t) < 2:
        return []
    idx = np.unique(np.linspace(0, len(t) - 2, min(STEP_CHECK_SAMPLES, len(t) - 1)).round().astype(int))
    Y = np.hstack([q[idx], qd[idx]])
    err = rk4_local_error(model, t[idx], Y, s.step)
    ratio = np.max(err / (s.atol + s.rtol * np.abs(Y)), axis=1)
    k = int(np.argmax(ratio))
    if not ratio[k] > 1:
        return []
    suggest = s.step * 0.9 * ratio[k] ** -0.2
    return [run_warning(
        "step_too_large", t[idx[k]], q[idx[k]],
        f"integrator.step = {s.step:g} s is too large for integrator.rtol = {s.rtol:g}, atol = {s.atol:g}: a "
        f"step-doubling estimate of one rk4 step's local error is {ratio[k]:.3g} times the tolerance here "
        f"(max {np.max(err[k]):.3g}); a step of about {suggest:.2g} s would meet it, or use dop853",
        error_ratio=ratio[k], local_error=np.max(err[k]), suggested_step_s=suggest)]


def collect(res, terms: ArmTerms) -> tuple[RunWarning, ...]:
    """Every warning of a native SimResult, its integration events first.

    Then the checks in the order of the module docstring; the `ill_conditioned` check is skipped when the
    run already has a `rank_deficient` event.

    Args:
        res: the `coopsim.forward.simulate.SimResult` (model, t, q, qd, cond, internal_wrench, initial,
            events).
        terms: its `ArmTerms`.

    Returns:
        tuple[RunWarning, ...]: the warnings.
    """
    m = res.model
    found = list(res.events)
    if not any(w.kind == "rank_deficient" for w in found):
        found += conditioning(m, res.t, res.q, res.cond, res.internal_wrench)
    found += arm_singularities(m, res.t, res.q, terms.J)
    found += initial_correction(m, res.initial)
    found += joint_limits(m, res.t, res.q)
    found += step_size(m, res.t, res.q, res.qd)
    return tuple(found)
