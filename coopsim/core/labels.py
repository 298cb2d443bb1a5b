"""Joint, arm and column labels: the one place they are made, for text, JSON, logs and plots.

Arms and joints are counted from 1 everywhere a person reads them: the third joint of the second arm is
`arm 2 joint 3`. An arm the scenario names (not its default name `arm2`) keeps that name beside its
number: `arm 1 (left) joint 3`. Stacked joint indices (0-based, arm after arm) stay what they are in
the arrays; only the labels count from 1.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping, Sequence


def arm_label(name: str, m: int) -> str:
    """The label of one arm, counted from 1: 'arm 2' for the default name 'arm2', else 'arm 2 (name)'.

    Args:
        name: the arm's name in the scenario.
        m: arm index, 0-based.

    Returns:
        str: 'arm {m + 1}', followed by ' (name)' when the name is not the default 'arm{m + 1}'.
    """
    return f"arm {m + 1}" if name == f"arm{m + 1}" else f"arm {m + 1} ({name})"


def arm_joint_labels(names: Sequence[str], dofs: Sequence[int]) -> list[str]:
    """Labels of the stacked joints of several arms: 'arm 2 joint 3', …

    Args:
        names: (r,) the arms' names, in stacking order.
        dofs: (r,) the number of joints of each arm.

    Returns:
        list[str]: (sum(dofs),) one label per stacked joint, arm after arm, joints counted from 1.
    """
    return [f"{arm_label(name, m)} joint {j + 1}" for m, (name, n) in enumerate(zip(names, dofs)) for j in range(n)]


def joint_labels(model) -> list[str]:
    """Labels of a model's stacked joints (`arm_joint_labels` of its arms).

    Args:
        model: the Model (its arms' names and joint counts are read).

    Returns:
        list[str]: (n_total,) one label per stacked joint.
    """
    return arm_joint_labels([a.name for a in model.arms], [a.n for a in model.arms])


def plain_joint_labels(n: int) -> list[str]:
    """'joint 1', …, 'joint n': labels when nothing says which arm a joint belongs to.

    Args:
        n: the number of joints.

    Returns:
        list[str]: (n,) the labels.
    """
    return [f"joint {j + 1}" for j in range(n)]


def metadata_arms(metadata: Mapping) -> tuple[list[str], list[int]] | None:
    """The arm names and joints per arm of a log's "model" metadata record, or None.

    The record is read as `coopsim.io.log.run_metadata` writes it (JSON strings under "arms" and "dofs").

    Args:
        metadata: the log's metadata (record name → record).

    Returns:
        tuple[list[str], list[int]] | None: (arm names, joints per arm), or None when the record is
            missing or unreadable.
    """
    rec = metadata.get("model", {})
    try:
        names, dofs = json.loads(rec["arms"]), json.loads(rec["dofs"])
        return [str(a) for a in names], [int(d) for d in dofs]
    except (KeyError, TypeError, ValueError):
        return None


def metadata_joint_types(metadata: Mapping, n: int) -> list[str]:
    """'revolute' or 'prismatic' per joint, from a log's "model" metadata record.

    Every joint is revolute when the record is missing, unreadable or describes another number of joints
    (a log written before joint types were recorded holds revolute joints only).

    Args:
        metadata: the log's metadata (record name → record).
        n: the number of stacked joints the log holds.

    Returns:
        list[str]: (n,) 'revolute' or 'prismatic' per joint.
    """
    try:
        types = [str(x) for x in json.loads(metadata.get("model", {})["joint_types"])]
    except (KeyError, TypeError, ValueError):
        types = []
    return types if len(types) == n and set(types) <= {"revolute", "prismatic"} else ["revolute"] * n


def metadata_joint_labels(metadata: Mapping, n: int) -> list[str]:
    """Labels of the joints of a log, from its "model" metadata record (`metadata_arms`).

    Args:
        metadata: the log's metadata (record name → record).
        n: the number of stacked joints the log holds.

    Returns:
        list[str]: (n,) the labels; `plain_joint_labels` when the record is missing, unreadable or
            describes another number of joints.
    """
    arms = metadata_arms(metadata)
    labels = [] if arms is None else arm_joint_labels(*arms)
    return labels if len(labels) == n else plain_joint_labels(n)


def field_name(column: str) -> str:
    """A column's name as a JSON field that Foxglove's message paths can address.

    Each run of characters other than letters, digits and '_' becomes one '_', and leading or trailing
    '_' are dropped (`capacity.payload.min_energy.mass_kg` → `capacity_payload_min_energy_mass_kg`).

    Args:
        column: the column name.

    Returns:
        str: the field name ('_' when nothing else is left).
    """
    return re.sub(r"[^A-Za-z0-9_]+", "_", column).strip("_") or "_"


def ros_arm_names(names: Sequence[str]) -> list[str]:
    """Each arm's name as a ROS name token, for topics and frames (`/native/left/joint_states`).

    A name becomes its letters and digits, each other run of characters one '_' (none at either end).
    When that leaves a name empty or starting with a digit, or two arms with one token, every arm takes its
    default name 'arm{m + 1}' instead (a token must not start with a digit, and topics must stay apart).

    Args:
        names: (r,) the arms' names in the scenario, in stacking order.

    Returns:
        list[str]: (r,) the tokens, each matching [A-Za-z][A-Za-z0-9_]*.
    """
    tokens = [re.sub(r"[^A-Za-z0-9]+", "_", name).strip("_") for name in names]
    if any(not t or t[0].isdigit() for t in tokens) or len(set(tokens)) < len(tokens):
        return [f"arm{m + 1}" for m in range(len(names))]
    return tokens
