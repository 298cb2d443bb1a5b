"""The compiled object-motion trajectory (coopsim.compiled.object_motion, the default engine of
`object_motion_trajectory`) against the readable reference (engine='reference': redundant_motion's
SciPy DOP853 and one Newton solve per sample and arm), at every bundled scenario with an object motion
and on a short motion of every other scene it solves (the robot scenes' redundant arms included), and
the failures of both engines worded alike.

Tolerance. Newton stops at max |S e| ≤ TOL = 1e-13 (m, rad), so two solutions of one target that both meet
it differ by up to 2 TOL/σ_min(S J) in the constrained directions; the redundant arms' null-space part
comes from the same DOP853 steps in both engines (the compiled pass follows scipy's step control), so it
may differ by rounding carried through the steps: allowed 1e-12 rad per rad of |θ| (the integration's
rtol, which the steps are far inside). θ̇ = (S J)⁻¹ S v and θ̈ inherit that error times at most
(1 + max |θ̇|)/σ_min (resp. θ̈). Measured: ≤ 4.6e-13 rad, 1e-13 rad/s, 3e-13 rad/s² (the panda carry's
3 s of the ODE), 30× to 1000× inside. B-spline paths (`coopsim.inverse.spline_path`) likewise: the
compiled object state against scipy's BSpline and the NumPy left Jacobian, the passes on bent splines
of a planar square pair, a spatial 6R pair and the redundant Panda carry."""

import re
from dataclasses import replace

import numpy as np
import pytest

from coopsim.compiled import api
from coopsim.compiled.object_motion import SMALL_ANGLE
from coopsim.core.model import ObjectMotion, PathSpline, SampledTimeLaw
from coopsim.core.spatial import rpy_to_rot
from coopsim.dynamics.kinematics import arm_pose, ee_jacobian
from coopsim.io.robots import robots_folder
from coopsim.inverse import spline_path
from coopsim.inverse.free_path import end_poses
from coopsim.inverse.trajectory import TrajectoryError, object_motion_at, object_motion_trajectory
from inverse_cases import model, short_motion

TOL = 1e-13
CARRIES = ["paper_planar_2x3_carry", "control/control_paper_carry", "robots/panda_ceiling_carry"]
# scenes without an object motion, given `short_motion` (the spatial 6R pairs meet a singularity on it)
SHORT = ["paper_planar_2x3", "planar_3arm_vertical", "gantry_prismatic", "hard/planar_4arm_mixed",
         "robots/baxter_box", "robots/panda_pair_tray", "robots/pr2_box", "robots/tiago_dual_box",
         "robots/ur10_xarm7_plate", "robots/ur5_pair_box"]


def _robots(name):
    return [pytest.param(n, marks=pytest.mark.skipif(robots_folder() is None, reason="example-robot-data is not "
                                                     "installed")) if n.startswith("robots/") else n for n in name]


def _assert_engines_agree(m, motion, ode_tol: float = 0.0):
    got = object_motion_trajectory(m, motion)
    ref = object_motion_trajectory(m, motion, engine="reference")
    assert np.array_equal(got.t, ref.t)
    s_min = min(float(np.linalg.svd(m.rows @ ee_jacobian(arm_pose(arm, q[sl])), compute_uv=False)[-1])
                for q in ref.q for arm, sl in zip(m.arms, m.dof_slices))
    tol_q = 2 * TOL / s_min + (1e-12 + ode_tol) * (1 + np.max(np.abs(ref.q)))
    assert np.max(np.abs(got.q - ref.q)) <= tol_q
    for name in ("qd", "qdd"):
        a, b = getattr(got, name), getattr(ref, name)
        assert np.max(np.abs(a - b)) <= tol_q * (1 + np.max(np.abs(b))) / s_min, name


@pytest.mark.parametrize("name", _robots(CARRIES))
def test_compiled_pass_equals_the_reference_on_every_bundled_object_motion(name):
    m = model(name)
    _assert_engines_agree(m, m.inverse.object_motion)


@pytest.mark.parametrize("name", _robots(SHORT))
def test_compiled_pass_equals_the_reference_on_a_short_motion_of_each_scene(name):
    m = model(name)
    _assert_engines_agree(m, short_motion(m))


def test_compiled_pass_equals_the_reference_with_the_cubic_law_and_a_rest_pull():
    """The carry's first segment on the cubic law (1 s samples), and a redundant scene with a stronger pull."""
    m = model(CARRIES[0])
    mo = m.inverse.object_motion
    _assert_engines_agree(m, ObjectMotion(mo.times[:2], mo.positions[:2], mo.rotations[:2], "cubic", 0.25))
    four = model("hard/planar_4arm_mixed")
    _assert_engines_agree(four, replace(short_motion(four), rest_gain=5.0, time_law="cubic"))


UNCONVERGED = re.compile(r"max \|error\| (\S+) after")   # a Newton that did not converge: its last residual


def _same_error(m, motion, match):
    """Both engines raise one TrajectoryError text, matching `match`.

    The texts are equal but for the last residual of a Newton that did not converge: after its 50 steps
    it wanders, and where it ends depends on each engine's rounding (0.0256 against 0.0556 on one CPU,
    equal on another), so there each residual need only exceed Newton's tolerance by far (> 1e-6).
    """
    texts = []
    for engine in ("compiled", "reference"):
        with pytest.raises(TrajectoryError, match=match) as err:
            object_motion_trajectory(m, motion, engine=engine)
        texts.append(str(err.value))
    residuals = [[float(r) for r in UNCONVERGED.findall(t)] for t in texts]
    assert all(r > 1e-6 for rs in residuals for r in rs), texts
    masked = [UNCONVERGED.sub("max |error| … after", t) for t in texts]
    assert masked[0] == masked[1], texts


def _motion(positions, yaws_deg, dt=0.05):
    return ObjectMotion(np.arange(len(positions), dtype=float), np.array(positions, float),
                        np.array([rpy_to_rot([0, 0, np.deg2rad(y)]) for y in yaws_deg]), "quintic", dt)


START = [0.75, 0.9316786, 0.0]     # the paper carry's first waypoint


def test_an_unreachable_waypoint_is_reported_alike():
    m = model(CARRIES[0])
    _same_error(m, _motion([START, [1.4, 1.0, 0.0]], [0, 0]), r"^inverse\.object_motion: the path leaves the "
                r"workspace of arm 'arm1' at t=.* s \(object at \[.*\] m\): its grasp is .* reach 1\.25 m$")
    near = model("hard/near_singular_chain")
    _same_error(near, short_motion(near), r"arm 'arm1' at t=0\.05 s .*: its grasp is .* m from the first joint, "
                                          r"reach 1\.25 m$")


def test_a_singular_jacobian_a_crossed_singularity_and_a_grasp_off_the_plane_are_reported_alike():
    """A start on arm 1's stretched-out branch (θ₂ = 0: S J singular at Newton's first step); the path of
    tests/inverse/test_trajectory.py that ends arm 1 fully stretched (det S J changes sign); one that leaves
    the plane."""
    m = model(CARRIES[0])
    mo = m.inverse.object_motion
    stretched = m.q0.copy()
    stretched[1] = 0.0
    short = ObjectMotion(mo.times[:2], mo.positions[:2], mo.rotations[:2], mo.time_law, 0.5, stretched)
    _same_error(m, short, r"^inverse\.object_motion: arm 'arm1' meets a singularity at t=0 s \(object at .*\): "
                          r"singular Jacobian \(σ_min/σ_max = .*\)$")
    wrist = 1.2 * np.array([np.cos(np.pi / 3), np.sin(np.pi / 3), 0.0])
    _same_error(m, _motion([START, wrist + [0.25, 0, 0]], [0, 0]),
                r"arm 'arm1' crosses a singularity between t=0\.95 s and t=1 s")
    _same_error(m, _motion([START, [0.75, 0.9, 0.05]], [0, 0]), r"arm1' leaves the plane of motion by")


@pytest.mark.parametrize("name,joint", [(CARRIES[0], 4), ("hard/planar_4arm_mixed", 4)])
def test_a_joint_limit_passed_is_reported_alike(name, joint):
    """A range around a joint's start narrower than its travel: square (paper carry, arm 2 joint 2) and
    redundant (planar_4arm_mixed's second arm, 4R in 3 rows)."""
    m = model(name)
    mo = m.inverse.object_motion or short_motion(m)
    mo = replace(mo, times=mo.times[:2], positions=mo.positions[:2], rotations=mo.rotations[:2])
    travel = object_motion_trajectory(m, mo).q[:, joint]
    rng = np.tile([-np.inf, np.inf], (m.n_total, 1))
    rng[joint] = [travel.min() - 1e-3, (travel.min() + travel.max()) / 2] if travel[0] < travel[-1] else \
        [(travel.min() + travel.max()) / 2, travel.max() + 1e-3]
    _same_error(replace(m, joint_range=rng), mo, r"^inverse\.object_motion: at t=.* s arm .* joint .* is outside "
                                                 r"its range")


@pytest.mark.skipif(robots_folder() is None, reason="example-robot-data is not installed")
def test_a_redundant_arm_out_of_reach_is_reported_alike():
    """The panda carry's tray moved 2 m along x: the least-norm IK's reach check on a redundant arm, at the
    first sample. (A tray path that leaves the reach later first stops the redundancy resolution's ODE:
    its rates grow without bound as A = S J loses rank, in both engines.)"""
    m = model(CARRIES[2])
    mo = m.inverse.object_motion
    far = mo.positions[:2] + [2.0, 0.0, 0.0]
    _same_error(m, replace(mo, times=mo.times[:2], positions=far, rotations=mo.rotations[:2]),
                r"^inverse\.object_motion: the path leaves the workspace of arm .* its grasp is .* m from the first "
                r"joint, reach .* m$")


def _trapezoid_law(times: np.ndarray) -> SampledTimeLaw:
    """A sampled time law (`coopsim optimize`'s kind) through waypoints at `times`: on each segment σ̇ rises
    from 0 over its first quarter, holds, and falls to 0 over its last quarter, covering 1/(w − 1)."""
    w1 = len(times) - 1
    t, rate = [times[0]], [0.0]
    for a, b in zip(times[:-1], times[1:]):
        top = 4.0 / (3.0 * w1 * (b - a))
        t += [a + 0.25 * (b - a), a + 0.75 * (b - a), b]
        rate += [top, top, 0.0]
    t, rate = np.array(t), np.array(rate)
    s = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t))])
    return SampledTimeLaw(t, s, rate)


@pytest.mark.parametrize("name", _robots([CARRIES[0], "robots/panda_ceiling_carry"]))
def test_compiled_pass_equals_the_reference_on_a_sampled_time_law(name):
    """The carries along a sampled law (constant σ̈ between samples, the retimed scenarios' kind): a
    square pair and a redundant pair (its null-space ODE integrated through the samples' kinks in σ̈,
    where a last-bit difference of the right-hand side can flip DOP853's step acceptance: the engines may
    then take different steps, so they agree to the ODE's tolerance, ten times its rtol of 1e-12; measured
    8e-12 rad on the Panda carry)."""
    m = model(name)
    mo = m.inverse.object_motion
    law = _trapezoid_law(mo.times)
    assert law.s[-1] == pytest.approx(1.0, abs=1e-12)
    _assert_engines_agree(m, replace(mo, time_law="sampled", samples=law), ode_tol=1e-11)


@pytest.mark.skipif(robots_folder() is None, reason="example-robot-data is not installed")
def test_compiled_pass_equals_the_reference_with_a_pull_per_unit_path():
    """rest_pull 'path' (the gain rest_gain·T·σ̇ and its rate σ̈ in θ̈) on the redundant Panda carry along a
    sampled law, at 0.25 s samples (tolerance as the sampled law's above)."""
    m = model("robots/panda_ceiling_carry")
    mo = m.inverse.object_motion
    mo = replace(mo, rest_pull="path", time_law="sampled", samples=_trapezoid_law(mo.times), output_dt=0.25)
    _assert_engines_agree(m, mo, ode_tol=1e-11)


def bent_spline(motion: ObjectMotion, S: np.ndarray, control_points: int, offset: float, dt: float) -> ObjectMotion:
    """The straight B-spline between a motion's first and last poses (`spline_path.straight_control_points`)
    with its control points moved by `offset` × a seeded normal draw in the rows S (m and rad: in the plane
    of a planar scene), sampled every dt."""
    ends = end_poses(motion, dt)
    line = spline_path.straight_control_points(ends, control_points)
    d = offset * np.random.default_rng(1).normal(0.0, 1.0, (control_points, S.shape[0])) @ S
    return replace(ends, path=PathSpline(line.kind, line.positions + d[:, :3], line.rotation_vectors + d[:, 3:]))


@pytest.mark.parametrize("big", [True, False])
@pytest.mark.parametrize("K", [1, 2, 5])
def test_object_state_kernel_equals_the_spline_path(K, big):
    """The compiled object state (`object_motion.object_states`, de Boor's basis derivatives and the left
    Jacobian) on a spatial B-spline motion of degree 2, 3, 3 (rotation vectors up to about 1.5 rad, or below
    SMALL_ANGLE: its Taylor branch) under the linear law s = (t − t₀)/T against `BSplinePath.at` (scipy's
    BSpline, NumPy's J_l) times the law's rates: both sum d + 1 ≤ 4 basis values × coefficients and build R by
    Rodrigues' formula, so they differ by rounding of the order of 1e-16 of each quantity's scale (the
    derivative bases grow as n·d per order): allowed 1e-13 × (1 + its max), measured ≤ 6e-16 of it."""
    assert SMALL_ANGLE == spline_path.SMALL_ANGLE
    rng = np.random.default_rng(3)
    amp = 0.5 if big else 0.015
    R0, R1 = rpy_to_rot(rng.uniform(-amp, amp, 3)), rpy_to_rot(rng.uniform(-amp, amp, 3))
    path = PathSpline("bspline", rng.uniform(-0.3, 0.3, (K, 3)), rng.uniform(-2 * amp, 2 * amp, (K, 3)))
    motion = ObjectMotion(np.array([1.0, 4.0]), np.array([[0.1, 0.2, 0.3], [0.5, -0.1, 0.2]]), np.stack([R0, R1]),
                          "linear", 0.1, path=path)
    s = np.linspace(0.0, 1.0, 21)
    pc, R, tw, ac = api.object_states(model(CARRIES[0]), motion, 1.0 + 3.0 * s, spline_path.spline_arrays(motion))
    ref = spline_path.BSplinePath(motion).at(s, motion.positions[0])
    for got, want in [(pc, ref.p), (R, ref.R), (3.0 * tw[:, :3], ref.dp), (3.0 * tw[:, 3:], ref.dw),
                      (9.0 * ac[:, :3], ref.ddp), (9.0 * ac[:, 3:], ref.ddw)]:
        assert np.max(np.abs(got - want)) <= 1e-13 * (1 + np.max(np.abs(want)))


@pytest.mark.parametrize("law", ["quintic", "linear", "sampled"])
def test_object_states_equal_object_motion_at(law):
    """`api.object_states` against the reference `object_motion_at` at 27 times (the ends and the clamped
    outside included) on a B-spline motion of the paper carry and on its waypoint motion: the same
    formulas, to 1e-13 × (1 + each quantity's max)."""
    m = model(CARRIES[0])
    mo = m.inverse.object_motion
    for motion in (bent_spline(mo, m.rows, 4, 0.02, 0.25), mo):
        if law == "sampled":
            motion = replace(motion, time_law=law, samples=_trapezoid_law(motion.times))
        else:
            motion = replace(motion, time_law=law)
        t = np.concatenate([[-1.0], np.linspace(motion.times[0], motion.times[-1], 25), [motion.times[-1] + 1.0]])
        spline = None if motion.path is None else spline_path.spline_arrays(motion)
        got = api.object_states(m, motion, t, spline)
        want = [np.array(v) for v in zip(*(object_motion_at(motion, x, motion.positions[0]) for x in t))]
        for a, b in zip(got, want):
            assert np.max(np.abs(a - b)) <= 1e-13 * (1 + np.max(np.abs(b)))


def _first_segment(motion: ObjectMotion) -> ObjectMotion:
    return replace(motion, times=motion.times[:2], positions=motion.positions[:2], rotations=motion.rotations[:2])


# scene → its bent spline: the paper carry's end poses (K = 4, 2 cm and 0.02 rad bends, 0.25 s samples), the UR5
# pair's short motion (K = 3, 2 mm, 50 ms), the Panda carry's first segment (K = 2, 5 mm, 0.1 s samples)
SPLINES = {CARRIES[0]: lambda m: bent_spline(m.inverse.object_motion, m.rows, 4, 0.02, 0.25),
           "robots/ur5_pair_box": lambda m: bent_spline(short_motion(m), m.rows, 3, 0.002, 0.05),
           CARRIES[2]: lambda m: bent_spline(_first_segment(m.inverse.object_motion), m.rows, 2, 0.005, 0.1)}


@pytest.mark.parametrize("name", _robots(list(SPLINES)))
def test_compiled_pass_equals_the_reference_on_a_bspline_path(name):
    """The compiled pass follows a bent B-spline (a planar square pair, a spatial 6R pair, the redundant
    Panda pair) as the reference does, to the tolerances above (measured ≤ 1.3e-15 rad, 1.2e-15 rad/s,
    3.3e-15 rad/s²)."""
    m = model(name)
    _assert_engines_agree(m, SPLINES[name](m))


def test_a_spline_out_of_reach_is_reported_alike():
    """A B-spline of the paper carry bent 0.6 m out of the arms' reach: arm 1's Newton stops on its way out
    (t = 2.25 s), with the same text from both engines."""
    m = model(CARRIES[0])
    motion = bent_spline(m.inverse.object_motion, m.rows, 4, 0.0, 0.25)
    far = replace(motion.path, positions=motion.path.positions + [0.0, 0.6, 0.0])
    _same_error(m, replace(motion, path=far), r"^inverse\.object_motion: the path leaves the workspace of arm 'arm1' "
                r"at t=2\.25 s \(object at \[.*\] m\): no joint angles reach its grasp \(Newton did not converge")
