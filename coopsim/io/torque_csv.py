"""Joint torques as the CSV files a scenario's `torque: {csv: FILE}` reads back (one file per arm: a
header row, then time s and one column per joint N·m; floats written in their shortest exact form, so
a file read back gives the same numbers to the last bit). Written atomically (`coopsim.io.atomic`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from coopsim.io.atomic import write_text_atomic
from coopsim.core.model import Model


def torque_csv_text(t: np.ndarray, tau: np.ndarray, names: list[str]) -> str:
    """The CSV text of torques tau (N, n) N·m at times t (N,) s under the column names (n,).

    Args:
        t: (N,) s, the sample times (first column, "time_s").
        tau: (N, n) N·m (N on a prismatic joint), one column per joint.
        names: (n,) the joints' column names.

    Returns:
        str: a header row, then one row per sample, floats in their shortest exact form, newline-ended.
    """
    rows = [",".join(["time_s"] + names)]
    rows += [",".join(repr(float(x)) for x in (ti, *row)) for ti, row in zip(t, tau)]
    return "\n".join(rows) + "\n"


def write_torque_csvs(prefix: str | Path, model: Model, t: np.ndarray, tau: np.ndarray) -> list[Path]:
    """One CSV per arm, PREFIX_ARMNAME.csv, of the stacked torques tau (N, n_total) at times t (N,) s.

    t is the run's time (0 at the first sample); each file is written atomically.

    Args:
        prefix: the files' path without the suffix "_ARMNAME.csv".
        model: the Model (its arms' names and joint slices).
        t: (N,) s, the sample times.
        tau: (N, n_total) N·m (N on a prismatic joint), the joints stacked arm by arm.

    Returns:
        list[Path]: the files written, one per arm in the model's order.
    """
    prefix = Path(prefix)
    paths = []
    for arm, sl in zip(model.arms, model.dof_slices):
        path = prefix.with_name(f"{prefix.name}_{arm.name}.csv")
        write_text_atomic(path, torque_csv_text(t, tau[:, sl], [f"tau{i + 1}_Nm" for i in range(arm.n)]))
        paths.append(path)
    return paths
