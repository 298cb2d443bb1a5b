"""coopsim.io.yaml_rules: YAML read defensively (one document, no key twice, bounded depth and expanded
size), every refusal one line through the caller's `fail`."""

import pytest

from coopsim.core.errors import ScenarioError
from coopsim.io.yaml_rules import MAX_DEPTH, MAX_NODES, load_yaml, parse_yaml_text


class Refused(Exception):
    pass


def _fail(reason):
    raise Refused(reason)


def _reason(text: str) -> str:
    with pytest.raises(Refused) as exc:
        parse_yaml_text(text, _fail)
    assert "\n" not in str(exc.value)
    return str(exc.value)


def test_plain_documents_parse_as_safe_yaml():
    assert parse_yaml_text("a: 1\nb: [1, 2.5, x]\n", _fail) == {"a": 1, "b": [1, 2.5, "x"]}
    assert parse_yaml_text("", _fail) is None


def test_a_key_twice_is_refused_with_both_lines():
    assert _reason("arms:\n  - name: a\n    mass: 1\n    mass: 2\n") == \
        "arms[0].mass: duplicate key (lines 3 and 4: the second would silently replace the first)"


def test_the_same_key_under_two_parents_is_fine_and_merges_are_not_duplicates():
    assert parse_yaml_text("a: {x: 1}\nb: {x: 2}\n", _fail) == {"a": {"x": 1}, "b": {"x": 2}}
    data = parse_yaml_text("base: &b {x: 1, y: 2}\nc:\n  <<: *b\n  y: 3\n", _fail)
    assert data["c"] == {"x": 1, "y": 3}


def test_depth_is_bounded_before_anything_is_built():
    deep = "a: " + "[" * (MAX_DEPTH + 1) + "]" * (MAX_DEPTH + 1) + "\n"
    assert f"nested more than {MAX_DEPTH} levels deep" in _reason(deep)


def test_an_alias_bomb_is_refused_by_its_expanded_size():
    lines = ["l0: &l0 [x, x, x, x, x, x, x, x, x, x]"]
    lines += [f"l{i}: &l{i} [" + ", ".join([f"*l{i - 1}"] * 10) + "]" for i in range(1, 8)]
    reason = _reason("\n".join(lines) + "\n")
    assert f"to more than {MAX_NODES:,} values" in reason


def test_malformed_yaml_names_line_and_column():
    assert _reason("a: [1, 2\nb: 3\n").startswith("malformed YAML at line ")


def test_load_yaml_names_the_file(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text("duration: 1\nduration: 2\n")
    with pytest.raises(ScenarioError, match=r"s\.yaml: duration: duplicate key \(lines 1 and 2"):
        load_yaml(path)
    path.write_bytes(b"name: caf\xe9\n")
    with pytest.raises(ScenarioError, match=r"s\.yaml: "):
        load_yaml(path)


def test_a_path_that_cannot_be_read_is_one_line(tmp_path):
    """A missing file, or a folder given as the file, is the same one-line ScenarioError as any other
    refusal (the commands check for a file first; library callers of load_yaml get the same)."""
    for path, why in ((tmp_path / "missing.yaml", "No such file or directory"), (tmp_path, "Is a directory")):
        with pytest.raises(ScenarioError) as exc:
            load_yaml(path)
        assert str(exc.value) == f"{path}: cannot be read ({why})"
