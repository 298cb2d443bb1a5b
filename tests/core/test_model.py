"""coopsim.core.model: the LoopController protocol test the forward pipeline makes on every run."""

from dataclasses import replace

import numpy as np
import pytest

from coopsim.control.controller import Controller
from coopsim.core.model import ControlSettings, LoopController, TorqueTable, is_loop_controller, torque_at


class _Complete:
    compiled_reason = None

    def __init__(self):
        self.model = None

    def __call__(self, t, q, qd):
        return q

    def loop_record(self):
        return ()

    def loop_counts(self):
        return ()

    def loop_torques(self, t, q, qd):
        return q

    def run_warnings(self):
        return []


class _NoModel(_Complete):
    def __init__(self):
        pass


class _NoRecord:
    model, compiled_reason = None, None

    def __call__(self, t, q, qd):
        return q


@pytest.fixture(scope="module")
def controller(paper):
    n = paper.n_total
    return Controller(replace(paper, control=ControlSettings("joint_pd", np.ones(n), np.ones(n))))


def test_is_loop_controller_answers_as_the_protocol_check(controller):
    for fn in (controller, _Complete(), _NoModel(), _NoRecord(), lambda t, q, qd: q, None, 3.0):
        assert is_loop_controller(fn) == isinstance(fn, LoopController), fn
    assert is_loop_controller(controller) and is_loop_controller(_Complete())
    assert not is_loop_controller(_NoModel()) and not is_loop_controller(_NoRecord())


def test_a_torque_table_is_read_as_np_interp_reads_each_column():
    """All joints of a table at once (one binary search) give np.interp's value of each column to the bit,
    on and between knots, before and after them."""
    rng = np.random.default_rng(3)
    times = np.unique(rng.uniform(0.0, 2.0, 40))
    values = rng.normal(0.0, 5.0, (len(times), 3))
    for t in [*rng.uniform(-0.5, 2.5, 200), *times]:
        ref = np.array([np.interp(t, times, col) for col in values.T])
        assert np.array_equal(torque_at((TorqueTable(times, values),), t), ref)
