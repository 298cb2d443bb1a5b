"""The first compile's split (coopsim.apps.warmup), checked on the cache the session's warm-up
(conftest) filled: every compile group is on disk, and each kernel the warm-up compiles from its
types alone is cached for that one signature only: a caller passing other types would compile the
kernel a second time on a first run."""

import pytest

from coopsim.compiled import api, object_motion
from coopsim.apps import warmup
from coopsim.compiled.dense_lp import dense_lp, lp_reachability_pass
from coopsim.compiled.distributions import linear_pass
from coopsim.compiled.lp import lp_vertices
from coopsim.compiled.stress import section_loads
from coopsim.compiled.structs import PACKED_T, WORKSPACE_T
from coopsim.inverse.trajectory import object_motion_trajectory, shared_object_motion_trajectory
from inverse_cases import model, short_motion


@pytest.mark.parametrize("group", ["base", "extras", "control"])
def test_the_warm_up_leaves_no_group_pending(group):
    assert not api.compile_pending(group)


@pytest.mark.parametrize("kernel", list(warmup._signatures()), ids=lambda k: k.__name__)
def test_a_kernel_compiled_by_signature_has_no_other_signature(kernel):
    cached = {key[0] for key in kernel._cache._cache_file._load_index()}
    assert cached == {(PACKED_T, WORKSPACE_T, *warmup._signatures()[kernel])}, kernel.__name__


def test_object_motion_passes_use_the_warm_up_signature():
    """The compiled object-motion pass called as the commands call it (a square scene through the shared
    trajectories' copies, a scene with redundant arms) finds the one signature the warm-up cached."""
    for name in ("paper_planar_2x3_carry", "hard/planar_4arm_mixed"):
        m = model(name)
        motion = m.inverse.object_motion or short_motion(m)
        shared_object_motion_trajectory(m, motion)
        object_motion_trajectory(m, motion)
    assert len(object_motion.trajectory._cache._cache_file._load_index()) == 1


@pytest.mark.parametrize("entry", [linear_pass, lp_vertices, section_loads, dense_lp, lp_reachability_pass],
                         ids=lambda e: e.__name__)
def test_an_inverse_entry_has_one_signature(entry):
    """Every caller reaches the linear resolutions' pass, the LP vertices, the section loads, the small-LP
    solver and the LP bound's reachability pass through `api`, which passes writable contiguous arrays: the
    warm-up's compile is the only one."""
    assert len(entry._cache._cache_file._load_index()) == 1
