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
    """'arm 2' for arm index m = 1 named 'arm2' (the scenario's default name), else 'arm 2 (name)'."""
    return f"arm {m + 1}" if name == f"arm{m + 1}" else f"arm {m + 1} ({name})"


def arm_joint_labels(names: Sequence[str], dofs: Sequence[int]) -> list[str]:
    """Labels of the stacked joints of arms `names` with `dofs` joints each: 'arm 2 joint 3', …"""
    return [f"{arm_label(name, m)} joint {j + 1}" for m, (name, n) in enumerate(zip(names, dofs)) for j in range(n)]


def joint_labels(model) -> list[str]:
    """Labels (n,) of a model's stacked joints (`arm_joint_labels` of its arms)."""
    return arm_joint_labels([a.name for a in model.arms], [a.n for a in model.arms])


def plain_joint_labels(n: int) -> list[str]:
    """'joint 1', …, 'joint n': labels when nothing says which arm a joint belongs to."""
    return [f"joint {j + 1}" for j in range(n)]


def metadata_arms(metadata: Mapping) -> tuple[list[str], list[int]] | None:
    """(arm names, joints per arm) of a log's "model" metadata record (as `coopsim.io.log.run_metadata`
    writes it), or None when it is missing or unreadable."""
    rec = metadata.get("model", {})
    try:
        names, dofs = json.loads(rec["arms"]), json.loads(rec["dofs"])
        return [str(a) for a in names], [int(d) for d in dofs]
    except (KeyError, TypeError, ValueError):
        return None


def metadata_joint_types(metadata: Mapping, n: int) -> list[str]:
    """'revolute' or 'prismatic' per joint (n,) from a log's "model" metadata record; every joint
    revolute when the record is missing, unreadable or describes another number of joints (a log
    written before joint types were recorded holds revolute joints only)."""
    try:
        types = [str(x) for x in json.loads(metadata.get("model", {})["joint_types"])]
    except (KeyError, TypeError, ValueError):
        types = []
    return types if len(types) == n and set(types) <= {"revolute", "prismatic"} else ["revolute"] * n


def metadata_joint_labels(metadata: Mapping, n: int) -> list[str]:
    """Labels (n,) of the joints of a log from its "model" metadata record (`metadata_arms`);
    `plain_joint_labels` when the record is missing, unreadable or describes another number of joints."""
    arms = metadata_arms(metadata)
    labels = [] if arms is None else arm_joint_labels(*arms)
    return labels if len(labels) == n else plain_joint_labels(n)


def field_name(column: str) -> str:
    """A column's name as a JSON field that Foxglove's message paths can address: characters other than
    letters, digits and '_' become '_' (`capacity.payload.min_energy.mass_kg` → `capacity_payload_min_energy_mass_kg`)."""
    return re.sub(r"[^A-Za-z0-9_]+", "_", column).strip("_") or "_"
