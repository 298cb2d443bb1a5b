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
    """τ clipped to the motor lines of eq. 36, τ_min(θ̇) ≤ τ ≤ τ_max(θ̇) (`coopsim.core.model.torque_limits`).

    Args:
        motors: the Motors (stall torque, no-load speed per joint).
        tau: (..., n) N·m (N on a prismatic joint), the commanded torques.
        qd: (..., n) rad/s (m/s on a prismatic joint), the joint rates the lines are evaluated at.

    Returns:
        np.ndarray: the clipped torques, shaped like tau, N·m (N).
    """
    lo, hi = torque_limits(motors, qd)
    return np.minimum(np.maximum(tau, lo), hi)


def pd_torque(kp: np.ndarray, kd: np.ndarray, q_ref, qd_ref, q, qd) -> np.ndarray:
    """Kp (θ_r − θ) + Kd (θ̇_r − θ̇) (n,) N·m with diagonal gains kp, kd (n,).

    Args:
        kp: (n,) N·m/rad (N/m on a prismatic joint), the proportional gains.
        kd: (n,) N·m·s/rad (N·s/m), the derivative gains.
        q_ref, qd_ref: (n,) rad, rad/s (m, m/s on a prismatic joint), the reference θ_r, θ̇_r.
        q, qd: (n,) rad, rad/s (m, m/s), the joint state θ, θ̇.

    Returns:
        np.ndarray: (n,) N·m (N), the PD torques.
    """
    return kp * (q_ref - q) + kd * (qd_ref - qd)


def object_acceleration(kp: np.ndarray, kd: np.ndarray, err: np.ndarray, rate_err: np.ndarray,
                        acc_ref: np.ndarray) -> np.ndarray:
    """a = a_r + Kd ė + Kp e (6,) [v̇; ω̇] with gains [linear, angular] kp (2,) 1/s², kd (2,) 1/s.

    Args:
        kp: (2,) 1/s², the [linear, angular] proportional gains.
        kd: (2,) 1/s, the [linear, angular] derivative gains.
        err: (6,) [m; rad], the object's pose error e (`pose_error`), world axes.
        rate_err: (6,) [m/s; rad/s], the twist error ė = [v_r − v_C; ω_r − ω], world axes.
        acc_ref: (6,) [m/s²; rad/s²], the reference acceleration a_r = [a_C; ω̇], world axes.

    Returns:
        np.ndarray: (6,) [a_C; ω̇] m/s², rad/s², the object acceleration commanded, world axes.
    """
    return acc_ref + np.repeat(kd, 3) * rate_err + np.repeat(kp, 3) * err


def pose_error(p_ref, R_ref, p, R) -> np.ndarray:
    """[p_r − p; log(R_r Rᵀ)] (6,) m and rad, world axes.

    Args:
        p_ref: (3,) m, the reference position p_r, world.
        R_ref: (3, 3) the reference orientation R_r, world axes.
        p: (3,) m, the position p, world.
        R: (3, 3) the orientation R, world axes.

    Returns:
        np.ndarray: (6,) [m; rad], the position error and the rotation vector taking R to R_r, world axes.
    """
    return np.concatenate([p_ref - p, rot_log(R_ref @ R.T)])


def joint_accelerations(rows: np.ndarray, J: np.ndarray, Jd_qd: np.ndarray, rho: np.ndarray, twist: np.ndarray,
                        acc: np.ndarray, n: list[int]) -> np.ndarray:
    """Stacked θ̈ of the arms that give the object the acceleration acc = [a_C; ω̇] at twist [v_C; ω].

    Each grasp point ρ_m from C accelerates as a_C + ω̇ × ρ + ω × (ω × ρ), and S J_m θ̈_m =
    S (a_EE,m − J̇_m θ̇_m) in the rows S (square arms: k = n_m).

    Args:
        rows: (k, 6) the row selector S of the modelled rows.
        J: (r, 6, nmax) each arm's end-effector Jacobian, world axes (its first n_m columns used).
        Jd_qd: (r, 6) each arm's J̇_m θ̇_m [m/s²; rad/s²], world axes.
        rho: (r, 3) m, the grasp points relative to the centre of mass C, world axes.
        twist: (6,) [v_C; ω] m/s, rad/s, the object's twist, world axes.
        acc: (6,) [a_C; ω̇] m/s², rad/s², the object acceleration wanted, world axes.
        n: joints per arm, n_m.

    Returns:
        np.ndarray: (Σ n_m,) rad/s² (m/s² on a prismatic joint), θ̈ stacked arm by arm.
    """
    out = []
    for m, nm in enumerate(n):
        a_ee = np.concatenate([rigid_acceleration(acc[:3], twist[3:], acc[3:], rho[m]), acc[3:]])
        out.append(np.linalg.solve(rows @ J[m][:, :nm], rows @ (a_ee - Jd_qd[m])))
    return np.concatenate(out)


def grasp_errors(grasp_pos: np.ndarray, grasp_rot: np.ndarray, p_C: np.ndarray, R_o: np.ndarray,
                 twist: np.ndarray, p_ee: np.ndarray, R_ee: np.ndarray, ee_twist: np.ndarray):
    """(e, ė) (r, 6) of every arm's end effector against where its grasp puts it on the object.

    e_m = [p_t − p_EE; log(R_t R_EEᵀ)] m, rad (world axes) with p_t = p_C + R_o g_m, R_t = R_o G_m;
    ė_m = [v_C + ω × R_o g_m; ω] − [v_EE; ω_EE].

    Args:
        grasp_pos: (r, 3) m, the grasp points g_m, object frame (relative to C).
        grasp_rot: (r, 3, 3) the grasp orientations G_m, object frame.
        p_C: (3,) m, the object's centre of mass, world.
        R_o: (3, 3) the object's orientation, world axes.
        twist: (6,) [v_C; ω] m/s, rad/s, the object's twist, world axes.
        p_ee: (r, 3) m, the end-effector positions p_EE, world.
        R_ee: (r, 3, 3) the end-effector orientations R_EE, world axes.
        ee_twist: (r, 6) [v_EE; ω_EE] m/s, rad/s, the end-effector twists J_m θ̇_m, world axes.

    Returns:
        tuple[np.ndarray, np.ndarray]: e (r, 6) [m; rad] and ė (r, 6) [m/s; rad/s], world axes.
    """
    rho = grasp_pos @ R_o.T
    e = np.concatenate([(p_C + rho) - p_ee, [rot_log(R_o @ G @ R.T) for G, R in zip(grasp_rot, R_ee)]], axis=1)
    target = np.concatenate([twist[:3] + cross(twist[3:], rho), np.broadcast_to(twist[3:], rho.shape)], axis=1)
    return e, target - ee_twist


def grasp_torques(rows: np.ndarray, J: np.ndarray, kp: np.ndarray, kd: np.ndarray, e: np.ndarray, ed: np.ndarray,
                  n: list[int]) -> np.ndarray:
    """Stacked τ (N,) = J_mᵀSᵀS (Kp e_m + Kd ė_m) per arm: joint-space feedback on the grasp errors.

    Args:
        rows: (k, 6) the row selector S of the modelled rows.
        J: (r, 6, nmax) each arm's end-effector Jacobian, world axes (its first n_m columns used).
        kp: (2,) [N/m, N·m/rad], the [linear, angular] proportional gains.
        kd: (2,) [N·s/m, N·m·s/rad], the [linear, angular] derivative gains.
        e: (r, 6) [m; rad], the grasp errors e_m (`grasp_errors`), world axes.
        ed: (r, 6) [m/s; rad/s], their rates ė_m, world axes.
        n: joints per arm, n_m.

    Returns:
        np.ndarray: (N,) N·m (N on a prismatic joint), N = Σ n_m, τ stacked arm by arm.
    """
    w = (np.repeat(kp, 3) * e + np.repeat(kd, 3) * ed) @ rows.T          # (r, k)
    return np.concatenate([(rows @ J[m][:, :nm]).T @ w[m] for m, nm in enumerate(n)])


def squeeze_wrenches(grasp_offset: np.ndarray, rows: np.ndarray, A: np.ndarray, force: float) -> np.ndarray:
    """Grasp wrenches f (rk,) in the rows S of a squeeze, with zero net object wrench.

    Each grasp pushes `force` N towards the centre of mass along its grasp line (the direction of its
    offset ρ_m; a grasp at C pushes nowhere), projected on the null space of A so that the net wrench is
    zero.

    Args:
        grasp_offset: (r, 3) m, ρ_m = p_grasp − p_C, the grasp points relative to C, world axes.
        rows: (k, 6) the row selector S of the modelled rows.
        A: (k, rk) the map from f to the net object wrench ([S W_m Sᵀ], full row rank).
        force: N, the squeeze force of each grasp (0: none).

    Returns:
        np.ndarray: (rk,) [N; N·m] the grasp wrenches in the rows S, arm after arm.
    """
    if force == 0.0:
        return np.zeros(A.shape[1])
    norm = np.linalg.norm(grasp_offset, axis=1, keepdims=True)
    u = grasp_offset / np.where(norm > 0, norm, 1.0)                         # a grasp at C: no line, no push
    F = np.concatenate([-force * u, np.zeros_like(u)], axis=1) @ rows.T      # (r, k)
    f = F.reshape(-1)
    return f - A.T @ np.linalg.solve(A @ A.T, A @ f)
