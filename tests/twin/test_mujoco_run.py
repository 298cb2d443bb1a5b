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


PENDULUM = """<mujoco><option gravity="0 0 0" integrator="RK4" timestep="0.001"/><worldbody><body>
<joint name="j" type="hinge" axis="0 0 1"/><inertial pos="0 0 0" mass="1" diaginertia="0.1 0.1 0.1"/>
</body></worldbody><actuator><motor joint="j" gear="1"/></actuator></mujoco>"""


def _bang(kinks: np.ndarray, cut: bool) -> tuple[float, float, float]:
    """A free hinge of inertia 0.1 kg·m² under τ = ±1 N·m, the sign flipped at each kink (t), stepped 1 ms
    for 0.05 s by `advance` (cut at the kinks, or not): (θ, θ̇, d.time) at the end."""
    import mujoco

    from coopsim.twin.mujoco_run import advance

    m = mujoco.MjModel.from_xml_string(PENDULUM)
    d = mujoco.MjData(m)
    mujoco.set_mjcb_control(lambda m, d: d.ctrl.__setitem__(0, (-1.0) ** np.searchsorted(kinks, d.time, "right")))
    try:
        for i in range(5):
            advance(m, d, 0.01 * i, 10, kinks if cut else np.zeros(0))
    finally:
        mujoco.set_mjcb_control(None)
    assert m.opt.timestep == 0.001
    return float(d.qpos[0]), float(d.qvel[0]), float(d.time)


def test_a_step_holding_a_jump_of_the_torque_is_cut_there():
    """τ = ±1 N·m flipped at 7.3 ms, 21.55 ms and 40.0004 ms (inside steps of 1 ms, one 0.4 µs from a step's
    start) and at 30 ms (on a step's end): θ is piecewise quadratic, which RK4 integrates exactly, so cut
    around the kinks the steps give the closed form but for the short steps over them (2ε = 2e-12 s, whose
    stages read both sides: θ̇ off by at most 2ε|Δθ̈| = 4e-11 rad/s each, so 2e-10 rad/s and 2e-11 rad
    allowed); not cut, each straddled step errs by up to h·|Δθ̈| in θ̇ (2e-2 rad/s here), measured above
    1e-3 rad/s; the run ends at 0.05 s either way."""
    kinks = np.array([0.0073, 0.02155, 0.030, 0.0400004])
    edges = np.concatenate([[0.0], kinks, [0.05]])
    acc = 10.0 * (-1.0) ** np.arange(len(edges) - 1)                     # τ / I, rad/s²
    w = np.concatenate([[0.0], np.cumsum(acc * np.diff(edges))])
    theta = float(np.sum(w[:-1] * np.diff(edges) + 0.5 * acc * np.diff(edges) ** 2))
    q, qd, t = _bang(kinks, cut=True)
    assert abs(q - theta) <= 2e-11 and abs(qd - w[-1]) <= 2e-10 and abs(t - 0.05) <= 1e-15
    q0, qd0, t0 = _bang(kinks, cut=False)
    assert abs(qd0 - w[-1]) > 1e-3 and abs(t0 - 0.05) <= 1e-15
