"""The control laws as pure functions of arrays (the Controller evaluates them at every state; the
compiled laws in `coopsim.compiled.control` are the same equations): joint PD, the object
acceleration of computed torque and the arms' joint accelerations that realise it, pose and grasp
errors, grasp feedback torques, squeeze wrenches, and eq. 36 saturation.
"""

from __future__ import annotations


import numpy as np

from coopsim.core.model import torque_limits
from coopsim.core.spatial import cross, rigid_acceleration, rot_log


def saturate(motors, tau: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """τ clipped to the motor lines of eq. 36, τ_min(θ̇) ≤ τ ≤ τ_max(θ̇) (`coopsim.core.model.torque_limits`)."""
    lo, hi = torque_limits(motors, qd)
    return np.minimum(np.maximum(tau, lo), hi)


def pd_torque(kp: np.ndarray, kd: np.ndarray, q_ref, qd_ref, q, qd) -> np.ndarray:
    """Kp (θ_r − θ) + Kd (θ̇_r − θ̇) (n,) N·m with diagonal gains kp, kd (n,)."""
    return kp * (q_ref - q) + kd * (qd_ref - qd)


def object_acceleration(kp: np.ndarray, kd: np.ndarray, err: np.ndarray, rate_err: np.ndarray,
                        acc_ref: np.ndarray) -> np.ndarray:
    """a = a_r + Kd ė + Kp e (6,) [v̇; ω̇] with gains [linear, angular] kp (2,) 1/s², kd (2,) 1/s."""
    return acc_ref + np.repeat(kd, 3) * rate_err + np.repeat(kp, 3) * err


def pose_error(p_ref, R_ref, p, R) -> np.ndarray:
    """[p_r − p; log(R_r Rᵀ)] (6,) m and rad, world axes."""
    return np.concatenate([p_ref - p, rot_log(R_ref @ R.T)])


def joint_accelerations(rows: np.ndarray, J: np.ndarray, Jd_qd: np.ndarray, rho: np.ndarray, twist: np.ndarray,
                        acc: np.ndarray, n: list[int]) -> np.ndarray:
    """Stacked θ̈ of the arms that give the object the acceleration acc = [a_C; ω̇] (6,) at twist
    [v_C; ω] (6,): each grasp point ρ_m (r, 3) from C accelerates as a_C + ω̇ × ρ + ω × (ω × ρ), and
    S J_m θ̈_m = S (a_EE,m − J̇_m θ̇_m) in the rows S (k, 6) (square arms; J (r, 6, nmax), Jd_qd (r, 6),
    n: joints per arm)."""
    out = []
    for m, nm in enumerate(n):
        a_ee = np.concatenate([rigid_acceleration(acc[:3], twist[3:], acc[3:], rho[m]), acc[3:]])
        out.append(np.linalg.solve(rows @ J[m][:, :nm], rows @ (a_ee - Jd_qd[m])))
    return np.concatenate(out)


def grasp_errors(grasp_pos: np.ndarray, grasp_rot: np.ndarray, p_C: np.ndarray, R_o: np.ndarray,
                 twist: np.ndarray, p_ee: np.ndarray, R_ee: np.ndarray, ee_twist: np.ndarray):
    """(e, ė) (r, 6) of every arm's end effector against where its grasp puts it on the object:
    e_m = [p_t − p_EE; log(R_t R_EEᵀ)] m, rad (world axes) with p_t = p_C + R_o g_m, R_t = R_o G_m (grasp
    g_m (r, 3), G_m (r, 3, 3) in the object frame; object pose p_C (3,), R_o (3, 3), twist [v_C; ω] (6,));
    ė_m = [v_C + ω × R_o g_m; ω] − [v_EE; ω_EE] (ee_twist (r, 6) = J_m θ̇_m). p_ee (r, 3), R_ee (r, 3, 3)."""
    rho = grasp_pos @ R_o.T
    e = np.concatenate([(p_C + rho) - p_ee, [rot_log(R_o @ G @ R.T) for G, R in zip(grasp_rot, R_ee)]], axis=1)
    target = np.concatenate([twist[:3] + cross(twist[3:], rho), np.broadcast_to(twist[3:], rho.shape)], axis=1)
    return e, target - ee_twist


def grasp_torques(rows: np.ndarray, J: np.ndarray, kp: np.ndarray, kd: np.ndarray, e: np.ndarray, ed: np.ndarray,
                  n: list[int]) -> np.ndarray:
    """Stacked τ (N,) = J_mᵀSᵀS (Kp e_m + Kd ė_m) per arm (J (r, 6, nmax), gains (2,) [linear, angular],
    e, ė (r, 6), n: joints per arm)."""
    w = (np.repeat(kp, 3) * e + np.repeat(kd, 3) * ed) @ rows.T          # (r, k)
    return np.concatenate([(rows @ J[m][:, :nm]).T @ w[m] for m, nm in enumerate(n)])


def squeeze_wrenches(grasp_offset: np.ndarray, rows: np.ndarray, A: np.ndarray, force: float) -> np.ndarray:
    """Grasp wrenches f (rk,) in the rows S of a squeeze: each grasp pushes `force` N towards the centre
    of mass along its grasp line (offset ρ_m = p_grasp − p_C (r, 3)), projected on the null space of
    A (k × rk, the net object wrench of f) so that the net wrench is zero."""
    if force == 0.0:
        return np.zeros(A.shape[1])
    norm = np.linalg.norm(grasp_offset, axis=1, keepdims=True)
    u = grasp_offset / np.where(norm > 0, norm, 1.0)                         # a grasp at C: no line, no push
    F = np.concatenate([-force * u, np.zeros_like(u)], axis=1) @ rows.T      # (r, k)
    f = F.reshape(-1)
    return f - A.T @ np.linalg.solve(A @ A.T, A @ f)
