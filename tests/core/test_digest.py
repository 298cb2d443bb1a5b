"""coopsim.core.digest: a model's content digest, for sharing results between models of equal content."""

from dataclasses import replace

import numpy as np

from coopsim.core.digest import content_digest
from coopsim.core.model import TorqueFunction


def test_equal_content_equal_digest_and_any_change_tells(paper):
    again = replace(paper, arms=tuple(replace(a) for a in paper.arms))       # new objects, same content
    assert content_digest(again) == content_digest(paper)
    arm = paper.arms[0]
    longer = replace(paper, arms=(replace(arm, joint_pos=arm.joint_pos + 1e-15),) + paper.arms[1:])
    assert content_digest(longer) != content_digest(paper)
    assert content_digest(replace(paper, gravity=np.array([0.0, 0.0, -9.8]))) != content_digest(paper)


def test_skipped_fields_do_not_count(paper):
    moved = replace(paper, inverse=replace(paper.inverse, payload_position=np.array([0.1, 0.0, 0.0])))
    skip = frozenset({"inverse.payload_position"})
    assert content_digest(moved) != content_digest(paper)
    assert content_digest(moved, skip) == content_digest(paper, skip)


def test_arrays_count_by_dtype_and_shape_and_a_callable_has_no_digest(paper):
    assert content_digest(np.zeros(4)) != content_digest(np.zeros((2, 2)))
    assert content_digest(np.zeros(2)) != content_digest(np.zeros(2, dtype=np.float32))
    assert content_digest((1, 2.0)) != content_digest((1.0, 2))
    live = replace(paper, torques=TorqueFunction(lambda t, q, qd: q))
    assert content_digest(live) is None and content_digest(live, frozenset({"torques"})) is not None
