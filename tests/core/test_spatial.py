"""coopsim.core.spatial against references that share none of its code: scipy.spatial.transform.Rotation,
MuJoCo's quaternion routines, NumPy's cross product and elementary rotation matrices written out here.

Conventions under test (module docstring, scenario `rpy`/`quat` keys): R maps body to world
coordinates; quaternions [w, x, y, z] (SciPy's are [x, y, z, w]), canonical w >= 0; roll-pitch-yaw
R = Rz(yaw) Ry(pitch) Rx(roll), i.e. SciPy's extrinsic "xyz" Euler angles."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from coopsim.core.spatial import (axis_angle_to_rot, cross, quat_to_rot, rot_log, rot_to_quat, rot_to_rpy, rots_to_quats,
                                   rpy_to_rot, skew)

RNG_SEED = 20240508
PI = np.pi

# Angles on and around the hard spots: 0, tiny, the Shepperd branch switch (trace 0 at 2π/3), and
# within 1e-3 … 1e-15 of π (float π itself is 1.2e-16 below the true π).
NEAR_PI = [PI - d for d in (1e-3, 1e-6, 1e-9, 1e-11, 1e-12, 1e-13, 1e-14, 1e-15)]
ANGLES = [0.0, 1e-300, 1e-16, 1e-12, 1e-8, 1e-4, 0.3, 1.0, 2 * PI / 3, 2.0, 3.0, *NEAR_PI, PI]


def _unit(rng, n=None):
    v = rng.normal(size=(3,) if n is None else (n, 3))
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _axes(rng, count=40):
    """Random unit axes plus the coordinate axes, their negatives and a few diagonals."""
    fixed = np.vstack([np.eye(3), -np.eye(3), np.array([[1, 1, 0], [1, -1, 1], [0, 1, -1]]) / np.array([[2**.5], [3**.5], [2**.5]])])
    return np.vstack([fixed, _unit(rng, count)])


def _Rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _Ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _Rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _wxyz(q_xyzw):
    return np.array([q_xyzw[3], q_xyzw[0], q_xyzw[1], q_xyzw[2]])


def _max(a) -> float:
    return float(np.max(np.abs(a)))


# -- skew, cross -----------------------------------------------------------------------------------

def test_skew_is_the_cross_product_matrix():
    rng = np.random.default_rng(RNG_SEED)
    worst = worst_asym = 0.0
    for _ in range(200):
        v, u = rng.normal(size=3) * 10.0, rng.normal(size=3)
        K = skew(v)
        worst = max(worst, _max(K @ u - np.cross(v, u)) / (np.linalg.norm(v) * np.linalg.norm(u)))
        worst_asym = max(worst_asym, _max(K + K.T))
    assert worst <= 1e-15, f"skew(v) @ u vs numpy cross: relative error {worst:.3g}"
    assert worst_asym == 0.0, f"skew(v) not antisymmetric: |K + Kᵀ| = {worst_asym:.3g}"
    assert np.array_equal(skew(np.array([1.0, 2.0, 3.0])), [[0, -3, 2], [3, 0, -1], [-2, 1, 0]]), "skew([1,2,3]) entries"


def test_cross_matches_numpy_with_broadcasting():
    rng = np.random.default_rng(RNG_SEED + 1)
    a, b = rng.normal(size=(5, 4, 3)), rng.normal(size=(5, 4, 3))
    cases = [(a, b), (a, b[0, 0]), (a[0, 0], b), (a[:, :1], b), (a[0, 0], b[0, 0])]
    for x, y in cases:
        got, ref = cross(x, y), np.cross(x, y)
        assert got.shape == ref.shape, f"cross shape {got.shape} vs numpy {ref.shape}"
        err = _max(got - ref) / max(1.0, _max(ref))
        assert err <= 1e-15, f"cross vs numpy cross for shapes {np.shape(x)}, {np.shape(y)}: error {err:.3g}"
    # lists are accepted too
    assert _max(cross([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]) - [0.0, 0.0, 1.0]) == 0.0, "cross(x̂, ŷ) != ẑ"


# -- axis-angle, roll-pitch-yaw, quaternions → R -----------------------------------------------------

def test_axis_angle_matches_scipy_rotvec_including_near_pi():
    rng = np.random.default_rng(RNG_SEED + 2)
    worst = 0.0
    for a in _axes(rng):
        for ang in ANGLES + [-x for x in ANGLES] + [PI + 1e-12, 2 * PI - 1e-9, 7.5]:
            ref = Rotation.from_rotvec(ang * a).as_matrix()
            worst = max(worst, _max(axis_angle_to_rot(a, ang) - ref))
    assert worst <= 2e-15, f"axis_angle_to_rot vs SciPy from_rotvec: max entry error {worst:.3g}"


def test_rpy_is_fixed_axis_x_then_y_then_z():
    """R = Rz(yaw) Ry(pitch) Rx(roll), equal to SciPy's extrinsic 'xyz' Euler angles and to the
    product of elementary rotations, including pitch = ±π/2 (gimbal lock) and angles near ±π."""
    rng = np.random.default_rng(RNG_SEED + 3)
    rpys = [rng.uniform(-PI, PI, 3) for _ in range(200)]
    rpys += [np.array([0.3, s * PI / 2, -1.1]) for s in (1, -1)] + [np.array([PI - 1e-12, -(PI - 1e-12), PI])]
    worst_scipy = worst_prod = 0.0
    for rpy in rpys:
        R = rpy_to_rot(rpy)
        worst_scipy = max(worst_scipy, _max(R - Rotation.from_euler("xyz", rpy).as_matrix()))
        worst_prod = max(worst_prod, _max(R - _Rz(rpy[2]) @ _Ry(rpy[1]) @ _Rx(rpy[0])))
    assert worst_scipy <= 2e-15, f"rpy_to_rot vs SciPy from_euler('xyz'): max entry error {worst_scipy:.3g}"
    assert worst_prod <= 2e-15, f"rpy_to_rot vs Rz Ry Rx: max entry error {worst_prod:.3g}"
    # the convention, by example: roll about x first, then yaw about the fixed z
    R = rpy_to_rot(np.array([PI / 2, 0.0, PI / 2]))
    assert _max(R @ [0.0, 1.0, 0.0] - [0.0, 0.0, 1.0]) <= 1e-15, "roll π/2 then yaw π/2 should take ŷ to ẑ"
    assert _max(R @ [1.0, 0.0, 0.0] - [0.0, 1.0, 0.0]) <= 1e-15, "roll π/2 then yaw π/2 should take x̂ to ŷ"


def test_rot_to_rpy_inverts_rpy_to_rot_at_every_pitch():
    """rpy_to_rot(rot_to_rpy(R)) = R to rounding for random rotations (SciPy's), at pitch ±π/2 exactly and
    within 1e-9 of it (where the naive roll atan2(R21, R22) of two tiny entries loses digits), and the
    angles themselves where they are unique (|pitch| < π/2)."""
    rng = np.random.default_rng(RNG_SEED + 4)
    mats = list(Rotation.random(200, random_state=RNG_SEED + 4).as_matrix())
    mats += [rpy_to_rot(np.array([0.7, s * (PI / 2 - d), -2.1])) for s in (1, -1) for d in (0.0, 1e-9, 1e-13)]
    worst = max(_max(rpy_to_rot(rot_to_rpy(R)) - R) for R in mats)
    assert worst <= 4e-15, f"rpy_to_rot(rot_to_rpy(R)) vs R: max entry error {worst:.3g}"
    rpys = [rng.uniform([-PI, -PI / 2 + 1e-3, -PI], [PI, PI / 2 - 1e-3, PI]) for _ in range(100)]
    worst_angles = max(_max(rot_to_rpy(rpy_to_rot(rpy)) - rpy) for rpy in rpys)
    assert worst_angles <= 1e-12, f"rot_to_rpy(rpy_to_rot(rpy)) vs rpy: max error {worst_angles:.3g} rad"


def test_quat_to_rot_is_wxyz_and_normalises():
    """[w, x, y, z] order (SciPy: [x, y, z, w]; MuJoCo: [w, x, y, z]); scaled and negated
    quaternions give the same R."""
    rng = np.random.default_rng(RNG_SEED + 4)
    worst_scipy = worst_mj = worst_scaled = 0.0
    res = np.zeros(9)
    for _ in range(200):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        R = quat_to_rot(q)
        worst_scipy = max(worst_scipy, _max(R - Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()))
        mujoco.mju_quat2Mat(res, q)
        worst_mj = max(worst_mj, _max(R - res.reshape(3, 3)))
        worst_scaled = max(worst_scaled, _max(quat_to_rot(-3.7 * q) - R))
    assert worst_scipy <= 2e-15, f"quat_to_rot vs SciPy from_quat (scalar last): max entry error {worst_scipy:.3g}"
    assert worst_mj <= 2e-15, f"quat_to_rot vs MuJoCo mju_quat2Mat: max entry error {worst_mj:.3g}"
    assert worst_scaled <= 2e-15, f"quat_to_rot(−3.7 q) vs quat_to_rot(q): max entry error {worst_scaled:.3g}"
    # the order, by example: [cos 45°, 0, 0, sin 45°] is +90° about z
    assert _max(quat_to_rot(np.array([2**-.5, 0, 0, 2**-.5])) - _Rz(PI / 2)) <= 1e-15, "[w,0,0,z] not a z rotation"


# -- R → quaternion, R → rotation vector -------------------------------------------------------------

def _rotations(rng):
    """(nominal angle, rotation vector φ, R): every angle of ANGLES about every test axis, and 300
    uniformly random rotations (all four Shepperd branches)."""
    out = [(ang, ang * a, Rotation.from_rotvec(ang * a).as_matrix()) for a in _axes(rng, 20) for ang in ANGLES]
    for r in Rotation.random(300, random_state=rng.integers(2**31)):
        out.append((np.linalg.norm(r.as_rotvec()), r.as_rotvec(), r.as_matrix()))
    return out


# Within this of π, φ and −φ are the same rotation to 2e-15 rad, below what R's rounding resolves.
SIGN_FREE = 1e-15


def test_rot_to_quat_matches_scipy_and_mujoco():
    rng = np.random.default_rng(RNG_SEED + 5)
    worst_scipy = worst_mj = worst_norm = 0.0
    min_w = np.inf
    mj = np.zeros(4)
    for ang, phi, R in _rotations(rng):
        q = rot_to_quat(R)
        ref = _wxyz(Rotation.from_matrix(R).as_quat())
        mujoco.mju_mat2Quat(mj, R.ravel())
        # q and −q are the same rotation: where w ≈ 0 (angle ≈ π) either sign is canonical
        worst_scipy = max(worst_scipy, min(_max(q - ref), _max(q + ref)))
        worst_mj = max(worst_mj, min(_max(q - mj), _max(q + mj)))
        worst_norm = max(worst_norm, abs(np.linalg.norm(q) - 1.0))
        min_w = min(min_w, q[0])
        # away from π the sign is fixed: w > 0
        if ang < PI - 1e-3:
            assert q[0] > 0, f"rot_to_quat w = {q[0]} <= 0 at angle {ang} rad"
    assert worst_scipy <= 2e-15, f"rot_to_quat vs SciPy as_quat: max component error {worst_scipy:.3g}"
    assert worst_mj <= 2e-15, f"rot_to_quat vs MuJoCo mju_mat2Quat: max component error {worst_mj:.3g}"
    assert worst_norm <= 4.5e-16, f"rot_to_quat |q| − 1 = {worst_norm:.3g}"
    assert min_w >= 0.0, f"rot_to_quat returned w = {min_w} < 0 (canonical w >= 0)"


def test_rots_to_quats_matches_mujoco_over_a_batch():
    """The batched conversion (every Shepperd branch in one call, an extra leading axis) against MuJoCo's
    mju_mat2Quat, and equal to rot_to_quat matrix by matrix."""
    rng = np.random.default_rng(RNG_SEED + 6)
    R = np.array([R for _, _, R in _rotations(rng)])
    q = rots_to_quats(R.reshape(-1, 2, 3, 3)).reshape(-1, 4)
    mj = np.zeros(4)
    worst_mj = worst_own = 0.0
    for qi, Ri in zip(q, R):
        mujoco.mju_mat2Quat(mj, Ri.ravel())
        worst_mj = max(worst_mj, min(_max(qi - mj), _max(qi + mj)))
        worst_own = max(worst_own, _max(qi - rot_to_quat(Ri)))
    assert worst_mj <= 2e-15, f"rots_to_quats vs MuJoCo mju_mat2Quat: max component error {worst_mj:.3g}"
    assert worst_own <= 4.5e-16, f"rots_to_quats vs rot_to_quat: max component error {worst_own:.3g}"
    assert np.all(q[:, 0] >= 0.0), "rots_to_quats returned w < 0 (canonical w >= 0)"


def test_rot_log_recovers_the_rotation_vector_at_every_angle_including_near_pi():
    """rot_log(R(φ)) = φ to 1e-12 rad absolute (and 1e-14 relative for small angles), at every angle
    in ANGLES (within 1e-15 of π included) about every test axis and at 300 random rotations; agrees
    with SciPy's as_rotvec likewise. Within SIGN_FREE of π either ±φ is right (they differ by a
    rotation of 2e-15 rad at most). Measured: 1.0e-15 rad worst (the former sin φ·a / sin φ form: 2.3e-5 rad at π − 1e-11,
    the wrong sign below π − 1e-12)."""
    rng = np.random.default_rng(RNG_SEED + 6)
    worst_abs = worst_rel = worst_scipy = 0.0
    where = None
    for ang, phi, R in _rotations(rng):
        got = rot_log(R)
        scipy_phi = Rotation.from_matrix(R).as_rotvec()
        if ang >= PI - SIGN_FREE:
            err, err_scipy = min(_max(got - phi), _max(got + phi)), min(_max(got - scipy_phi), _max(got + scipy_phi))
        else:
            err, err_scipy = _max(got - phi), _max(got - scipy_phi)
        if err > worst_abs:
            worst_abs, where = err, ang
        worst_scipy = max(worst_scipy, err_scipy)
        if 0 < ang < 1e-3:
            worst_rel = max(worst_rel, err / ang)
        assert np.linalg.norm(got) <= PI + 1e-15, f"|rot_log| = {np.linalg.norm(got)!r} > π"
    assert worst_abs <= 1e-12, f"rot_log vs the rotation vector: error {worst_abs:.3g} rad at angle π − {PI - where:.3g}"
    assert worst_scipy <= 1e-12, f"rot_log vs SciPy as_rotvec: error {worst_scipy:.3g} rad"
    assert worst_rel <= 1e-14, f"rot_log small-angle relative error {worst_rel:.3g}"


@pytest.mark.parametrize("excess", [1e-13, 1e-9, 0.5])
def test_rot_log_wraps_angles_beyond_pi(excess):
    """A rotation by π + ε about a is the rotation by π − ε about −a: rot_log gives the latter."""
    rng = np.random.default_rng(RNG_SEED + 7)
    worst = 0.0
    for a in _axes(rng, 10):
        got = rot_log(Rotation.from_rotvec((PI + excess) * a).as_matrix())
        worst = max(worst, _max(got + (PI - excess) * a))
    assert worst <= 1e-12, f"rot_log at π + {excess:g}: error {worst:.3g} rad vs −(π − {excess:g}) a"


def test_rot_log_inverts_axis_angle_and_orthonormal_drift_is_harmless():
    """exp(rot_log(R)) = R (Rodrigues' formula of this module, checked against SciPy above) for random
    R, and an R off orthonormal by 1e-10 (a product of many rotations) still gives its rotation
    vector to ~1e-10."""
    rng = np.random.default_rng(RNG_SEED + 8)
    worst = worst_drift = 0.0
    for r in Rotation.random(200, random_state=rng.integers(2**31)):
        R = r.as_matrix()
        phi = rot_log(R)
        ang = np.linalg.norm(phi)
        worst = max(worst, _max(axis_angle_to_rot(phi / ang, ang) - R))
        drift = R + 1e-10 * rng.normal(size=(3, 3))
        worst_drift = max(worst_drift, _max(rot_log(drift) - r.as_rotvec()))
    assert worst <= 5e-15, f"axis_angle_to_rot(rot_log(R)) vs R: max entry error {worst:.3g}"
    assert worst_drift <= 1e-9, f"rot_log of R + 1e-10 noise: error {worst_drift:.3g} rad"
    assert np.array_equal(rot_log(np.eye(3)), np.zeros(3)), "rot_log(I) != 0"


# -- the compiled twins (coopsim.compiled.spatial), through a small compiled wrapper ----------------

def _compiled_spatial():
    from numba import njit

    from coopsim.compiled import spatial as cs

    @njit(cache=True)
    def log_and_quat(Rs):
        phi, q = np.empty((Rs.shape[0], 3)), np.empty((Rs.shape[0], 4))
        for i in range(Rs.shape[0]):
            cs.rot_log(Rs[i], phi[i])
            cs.rot_to_quat(Rs[i], q[i])
        return phi, q

    return log_and_quat


def _compiled_cases(near_pi: bool):
    rng = np.random.default_rng(RNG_SEED + 9)
    cases = [c for c in _rotations(rng) if (c[0] >= PI - 1e-3) == near_pi]
    return cases, np.array([R for _, _, R in cases])


def _check_compiled(near_pi: bool):
    cases, Rs = _compiled_cases(near_pi)
    phis, quats = _compiled_spatial()(Rs)
    worst_log = worst_quat = 0.0
    for (ang, phi, R), got, q in zip(cases, phis, quats):
        ref_q = rot_to_quat(R)
        worst_quat = max(worst_quat, min(_max(q - ref_q), _max(q + ref_q)) if ang >= PI - SIGN_FREE else _max(q - ref_q))
        worst_log = max(worst_log, min(_max(got - phi), _max(got + phi)) if ang >= PI - SIGN_FREE else _max(got - phi))
    assert worst_quat <= 2e-15, f"compiled rot_to_quat vs coopsim.core.spatial: max component error {worst_quat:.3g}"
    assert worst_log <= 1e-12, f"compiled rot_log vs the rotation vector: error {worst_log:.3g} rad"


def test_compiled_rot_log_and_rot_to_quat_away_from_pi():
    """Angles up to π − 1e-3."""
    _check_compiled(near_pi=False)


def test_compiled_rot_log_near_pi():
    _check_compiled(near_pi=True)
