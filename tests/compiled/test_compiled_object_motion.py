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
3 s of the ODE), 30× to 1000× inside."""

from dataclasses import replace

import numpy as np
import pytest

from coopsim.core.model import ObjectMotion, SampledTimeLaw
from coopsim.core.spatial import rpy_to_rot
from coopsim.dynamics.kinematics import arm_pose, ee_jacobian
from coopsim.io.robots import robots_folder
from coopsim.inverse.trajectory import TrajectoryError, object_motion_trajectory
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


def _same_error(m, motion, match):
    """Both engines raise one TrajectoryError text, matching `match`."""
    texts = []
    for engine in ("compiled", "reference"):
        with pytest.raises(TrajectoryError, match=match) as err:
            object_motion_trajectory(m, motion, engine=engine)
        texts.append(str(err.value))
    assert texts[0] == texts[1], texts


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
