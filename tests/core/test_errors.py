"""coopsim.core.errors: the one-line reason every error message ends with."""

from coopsim.core.errors import CoopsimError, one_line


def test_one_line_joins_every_run_of_whitespace():
    assert one_line(ValueError("first line\n  second\tline ")) == "first line second line"


def test_one_line_of_an_empty_message_is_the_type_name():
    assert one_line(KeyError()) == "KeyError" and one_line(CoopsimError("")) == "CoopsimError"


def test_one_line_cuts_at_the_limit():
    text = one_line(RuntimeError("x" * 200), 120)
    assert len(text) == 120 and text.endswith("...") and one_line(RuntimeError("short"), 120) == "short"
