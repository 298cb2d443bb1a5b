"""The cost of one dynamics evaluation: µs from Python and amortised in a compiled loop (native), and
the peers' from Python, at states of the reference trajectory."""

from __future__ import annotations

import numpy as np

from coopsim.apps.bench.measure import EVAL_BUDGET_S, Ladders, RunRow, best_time, have_pinocchio
from coopsim.compiled import api
from coopsim.core.model import Model


def trajectory_states(ref, count: int) -> tuple[np.ndarray, np.ndarray]:
    """The reference's samples repeated cyclically as `count` states and torques.

    Args:
        ref: the reference run (`SimResult`): q, qd, tau on its output grid.
        count: the number of states S.

    Returns:
        tuple[np.ndarray, np.ndarray]: Y (S, 2n) = [θ; θ̇] rad, rad/s (m, m/s on a prismatic joint) and TAU
        (S, n) N·m (N).
    """
    idx = np.arange(count) % len(ref.t)
    return np.hstack([ref.q, ref.qd])[idx], ref.tau[idx]


def native_eval_us(model: Model, Y: np.ndarray, TAU: np.ndarray, repeats: int = 3, calls: int = 2000) -> dict:
    """µs per native closed-chain evaluation, amortised over the states and from Python.

    'native_amortised_us': api.evaluate_states over the S states, one thread; 'native_python_us':
    api.forward, one call from Python at Y[0], timed in loops of `calls`. Each is the minimum over at least
    `repeats` timings, more (up to 10) while under EVAL_BUDGET_S.

    Args:
        model: the Model.
        Y: (S, 2n) the states [θ; θ̇], rad, rad/s (m, m/s on a prismatic joint).
        TAU: (S, n) N·m (N), the joint torques.
        repeats: timings at least.
        calls: api.forward calls per timing.

    Returns:
        dict: 'native_amortised_us' µs, 'native_python_us' µs, 'bad_states': evaluations with a non-zero
        status.
    """
    n = model.n_total
    kw = dict(repeats=repeats, budget_s=EVAL_BUDGET_S, max_repeats=10)
    out, wall = best_time(lambda: api.evaluate_states(model, Y, TAU, n_threads=1), **kw)
    q, qd, tau = Y[0, :n].copy(), Y[0, n:].copy(), TAU[0].copy()
    api.forward(model, q, qd, tau)
    _, loop = best_time(lambda: [api.forward(model, q, qd, tau) for _ in range(calls)], **kw)
    return {"native_amortised_us": 1e6 * wall / len(Y), "native_python_us": 1e6 * loop / calls,
            "bad_states": int(np.count_nonzero(out.status))}


def peer_eval_us(model: Model, q: np.ndarray, qd: np.ndarray, tau: np.ndarray, peers, calls: int = 2000,
                 repeats: int = 3) -> dict:
    """µs per call from Python of MuJoCo's mj_forward and, with pin, of pinocchio.constraintDynamics.

    The MuJoCo twin is built at the scenario's step, RK4.

    Args:
        model: the Model.
        q: (n,) rad (m on a prismatic joint), the joint coordinates.
        qd: (n,) rad/s (m/s), the joint rates.
        tau: (n,) N·m (N), the joint torques.
        peers: the peers module (`load_peers`).
        calls: calls per timing loop.
        repeats: timing loops (the minimum is kept).

    Returns:
        dict: 'mujoco_forward_us' µs and 'pinocchio_us' µs (None without pin).
    """
    twin = peers.mujoco_twin(model, "RK4")
    out = {"mujoco_forward_us": peers.mujoco_forward_us(twin, q, qd, tau, calls, repeats), "pinocchio_us": None}
    if have_pinocchio():
        system = peers.pinocchio_system(model)
        out["pinocchio_us"] = peers.pinocchio_eval_us(system, q, qd, tau, calls, repeats)
    return out


def eval_costs(model: Model, ref, rows: list[RunRow], peers, ladders: Ladders) -> dict:
    """Per-model µs per evaluation: native, MuJoCo and Pinocchio, from Python and in their integrators.

    Native: amortised and from Python (`native_eval_us` at ladders.eval_states states of the reference),
    and in the time loop of the tightest DOP853 run (loop_s / rhs evaluations). MuJoCo: mj_forward from
    Python; amortised: rollout wall / (steps · 4) of the RK4 run with the most steps. Pinocchio: from
    Python; in its scipy integrator: wall / nfev of its tightest run. The from-Python peers are timed at
    the reference's middle sample.

    Args:
        model: the Model.
        ref: the reference run (`SimResult`).
        rows: the scenario's runs (native, MuJoCo, Pinocchio).
        peers: the peers module (`load_peers`).
        ladders: the Ladders (eval_states, repeats).

    Returns:
        dict: µs: 'native_amortised_us', 'native_python_us', 'mujoco_forward_us', 'pinocchio_us' (None
        without pin), and where such runs exist 'native_loop_us_per_rhs', 'mujoco_amortised_us',
        'pinocchio_in_integrator_us'; 'native_amortised_over_pinocchio' (with pin); 'bad_states',
        'n_joints', 'eval_states'.
    """
    Y, TAU = trajectory_states(ref, ladders.eval_states)
    n = model.n_total
    k = len(ref.t) // 2
    out = native_eval_us(model, Y, TAU, repeats=max(ladders.repeats, 2))
    out |= peer_eval_us(model, ref.q[k], ref.qd[k], ref.tau[k], peers, repeats=max(ladders.repeats, 2))
    dop = [r for r in rows if r.family == "native" and r.method == "dop853" and r.loop_s]
    if dop:
        tight = min(dop, key=lambda r: r.param)
        out["native_loop_us_per_rhs"] = 1e6 * tight.loop_s / tight.evals
    rk4 = [r for r in rows if r.family == "mujoco" and r.method == "RK4" and np.isfinite(r.wall_s)]
    if rk4:
        longest = max(rk4, key=lambda r: r.evals)
        out["mujoco_amortised_us"] = 1e6 * longest.wall_s / longest.evals
    pin = [r for r in rows if r.family == "pinocchio"]
    if pin:
        tight = min(pin, key=lambda r: r.param)
        out["pinocchio_in_integrator_us"] = 1e6 * tight.wall_s / tight.evals
    if out["pinocchio_us"]:
        out["native_amortised_over_pinocchio"] = out["native_amortised_us"] / out["pinocchio_us"]
    out["n_joints"], out["eval_states"] = n, len(Y)
    return out
