"""The first compile's split (coopsim.apps.warmup), checked on the cache the session's warm-up
(conftest) filled: every compile group is on disk, and each kernel the warm-up compiles from its
types alone is cached for that one signature only: a caller passing other types would compile the
kernel a second time on a first run."""

import pytest

from coopsim.compiled import api
from coopsim.apps import warmup
from coopsim.compiled.structs import PACKED_T, WORKSPACE_T


@pytest.mark.parametrize("group", ["base", "extras", "control"])
def test_the_warm_up_leaves_no_group_pending(group):
    assert not api.compile_pending(group)


@pytest.mark.parametrize("kernel", list(warmup._signatures()), ids=lambda k: k.__name__)
def test_a_kernel_compiled_by_signature_has_no_other_signature(kernel):
    cached = {key[0] for key in kernel._cache._cache_file._load_index()}
    assert cached == {(PACKED_T, WORKSPACE_T, *warmup._signatures()[kernel])}, kernel.__name__
