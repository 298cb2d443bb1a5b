"""The twin's torque lookup (coopsim/twin/mujoco_run.py): one stacked table for arms sharing their times gives
`torque_at`'s values bit for bit (the same arithmetic), so the twin's runs do not change with it."""

import numpy as np

from coopsim.core.model import TorqueTable, torque_at
from coopsim.twin.mujoco_run import shared_table


def _tables(times, n=(3, 2), seed=0):
    rng = np.random.default_rng(seed)
    return tuple(TorqueTable(np.asarray(times, dtype=float), rng.normal(0, 1, (len(times), k))) for k in n)


def test_the_stacked_table_is_torque_at_bit_for_bit():
    times = np.cumsum(np.random.default_rng(1).uniform(1e-3, 0.1, 40))
    tables = _tables(times)
    at = shared_table(tables)
    inside = np.random.default_rng(2).uniform(times[0], times[-1], 500)
    for t in np.concatenate([inside, times, [times[0] - 1.0, times[-1] + 1.0]]):
        assert np.array_equal(at(float(t)), torque_at(tables, float(t)))
    assert np.all(np.isnan(at(float("nan")))) and np.all(np.isnan(torque_at(tables, float("nan"))))
    row = at(float(times[3]))
    row[:] = 0.0                                            # a copy: the table itself is left alone
    assert np.array_equal(at(float(times[3])), torque_at(tables, float(times[3])))


def test_tables_with_other_times_or_one_row_keep_the_general_lookup():
    a, b = _tables([0.0, 1.0, 2.0], n=(2,)), _tables([0.0, 1.5, 2.0], n=(2,), seed=1)
    assert shared_table(a + b) is None
    assert shared_table(_tables([0.0])) is None
