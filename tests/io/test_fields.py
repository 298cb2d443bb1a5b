"""coopsim.io.fields: the typed getters of a scenario section, each refusal one line naming the field."""

import numpy as np
import pytest

from coopsim.core.errors import ScenarioError
from coopsim.io.fields import MAX_MAGNITUDE, REQUIRED, Section, show_value


def _sec(**data) -> Section:
    return Section(data, "arms[0]", "s.yaml")


def _refused(call, message: str):
    with pytest.raises(ScenarioError) as exc:
        call()
    assert str(exc.value) == message and "\n" not in str(exc.value)


def test_a_section_must_be_a_mapping():
    _refused(lambda: Section([1, 2], "object", "s.yaml"), "s.yaml: object: expected a mapping, got list")


@pytest.mark.parametrize("value, reason", [
    (True, "expected a number, got True"),
    ("1.0", "expected a number, got '1.0'"),
    (float("nan"), "must be finite, got nan"),
    (float("inf"), "must be finite, got inf"),
    (10 ** 400, f"must be at most {MAX_MAGNITUDE:g} in magnitude, got " + "1" + "0" * 22 + "…"),
    (2e9, f"must be at most {MAX_MAGNITUDE:g} in magnitude, got 2e+09"),
    (-1.0, "must be positive, got -1.0"),
])
def test_number_refuses_what_is_not_a_positive_real(value, reason):
    _refused(lambda: _sec(mass=value).number("mass", positive=True), f"s.yaml: arms[0].mass: {reason}")


def test_number_defaults_and_requirement():
    assert _sec(mass=None).number("mass", default=2.0) == 2.0 and _sec().number("mass", default=None) is None
    _refused(lambda: _sec().number("mass"), "s.yaml: arms[0].mass: missing required field")
    assert REQUIRED is not None


def test_whole_numbers_and_their_bound():
    assert _sec(n=3).whole("n") == 3 and _sec(n=3.0).whole("n") == 3
    _refused(lambda: _sec(n=2.5).whole("n"), "s.yaml: arms[0].n: must be a whole number, got 2.5")
    _refused(lambda: _sec(n=20).whole("n", maximum=10), "s.yaml: arms[0].n: must be at most 10, got 20")


def test_string_choices():
    assert _sec(law="joint_pd").string("law", ("joint_pd", "computed_torque")) == "joint_pd"
    _refused(lambda: _sec(law="pid").string("law", ("joint_pd", "computed_torque")),
             "s.yaml: arms[0].law: must be one of joint_pd, computed_torque; got 'pid'")


def test_array_shape_finiteness_and_sign():
    assert np.array_equal(_sec(kp=[1, 2, 3]).array("kp", (3,)), [1.0, 2.0, 3.0])
    _refused(lambda: _sec(kp=[1, 2]).array("kp", (3,)), "s.yaml: arms[0].kp: expected shape 3, got [2]")
    _refused(lambda: _sec(kp=[[1, 2], [3]]).array("kp", (None, 2)),
             "s.yaml: arms[0].kp: expected shape n×2, got rows of different lengths")
    _refused(lambda: _sec(kp=[1, "x", 3]).array("kp", (3,)),
             "s.yaml: arms[0].kp: expected numbers, got 'x' in [1, 'x', 3]")
    _refused(lambda: _sec(kp=[1, float("nan")]).array("kp"), "s.yaml: arms[0].kp: must be finite")
    assert np.isinf(_sec(kp=[1, float("inf")]).array("kp", allow_inf=True)[1])
    _refused(lambda: _sec(kp=[1, -2]).array("kp", nonneg=True),
             "s.yaml: arms[0].kp: must be non-negative, got [1.0, -2.0]")


def test_angles_in_radians_or_degrees_never_both():
    assert np.allclose(_sec(q_deg=[90, 180]).angles("q", (2,)), [np.pi / 2, np.pi])
    assert np.allclose(_sec(q=[0.5, -1.0]).angles("q", (2,)), [0.5, -1.0])
    _refused(lambda: _sec(q=[1], q_deg=[1]).angles("q", (1,)),
             "s.yaml: arms[0].q: give either q (rad) or q_deg (deg), not both")
    _refused(lambda: _sec(q=[90.0]).angles("q", (1,)),
             "s.yaml: arms[0].q: 90 rad is more than a turn: degrees? use q_deg")


def test_nested_sections_items_and_unknown_fields():
    sec = Section({"links": [{"mass": 1.0}, {"mass": 2.0}], "joint": {"axis": [0, 0, 1]}, "colour": "red"}, "arms[1]",
                  "s.yaml")
    links = sec.items("links", min_len=1)
    assert [x.path for x in links] == ["arms[1].links[0]", "arms[1].links[1]"]
    assert sec.section("joint").path == "arms[1].joint" and sec.section("base", default=None) is None
    _refused(sec.done, "s.yaml: arms[1].colour: unknown field (known here: base, joint, links)")
    _refused(lambda: _sec(links={"a": 1}).items("links"),
             "s.yaml: arms[0].links: expected a list of at least 0 entries")


def test_show_value_cuts_long_values_without_building_them():
    assert show_value("short") == "'short'"
    text = show_value(list(range(10 ** 6)))
    assert len(text) <= 60 and text.endswith("…")
