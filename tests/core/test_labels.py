"""Labels (`coopsim/core/labels.py`): the ROS name tokens of the arms."""

from __future__ import annotations

import re

from coopsim.core.labels import ros_arm_names


def test_ros_arm_names_are_valid_tokens_and_stay_apart():
    """A name keeps its letters and digits, other runs become one '_'; a name that would be empty, start
    with a digit, or meet another arm's token sends every arm to its default 'arm{m + 1}'."""
    assert ros_arm_names(["arm1", "arm2"]) == ["arm1", "arm2"]
    assert ros_arm_names(["left", "right arm (B)"]) == ["left", "right_arm_B"]
    for names in (["left", "2nd"], ["left", "-"], ["a b", "a-b"]):
        assert ros_arm_names(names) == ["arm1", "arm2"], names
    assert all(re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", t) for t in ros_arm_names(["x__y", "é z", "q"]))
