"""Scaling: µs per evaluation of synthetic scenes of r arms × n joints (planar 3R pairs and spatial
chains built in code), with power-law fits."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Callable

import numpy as np

from coopsim.apps.bench.costs import native_eval_us, peer_eval_us
from coopsim.apps.bench.measure import CHOLESKY_RANK_TOL, Ladders, power_fit
from coopsim.core.model import Model
from coopsim.io.scenario import model_from_dict


_SPATIAL_AXES = ([0, 0, 1], [0, 1, 0], [0, 1, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0], [0, 0, 1])
_SPATIAL_LENGTHS = (0.12, 0.45, 0.40, 0.10, 0.08, 0.06, 0.05)
_SPATIAL_ANGLES = (0.3, -0.9, 1.2, 0.4, -0.7, 0.5, 0.2)
_PLANAR_LENGTHS = (0.5, 0.4, 0.1)
_PLANAR_ANGLES = (1.0, -1.1, -0.7)


def synthetic_scene(r: int, n: int) -> dict:
    """Scenario data (the YAML dict) of r arms of n revolute joints around a box held in a closed chain.

    Bases on a 0.8 m circle facing the centre, holding a 0.3 × 0.3 × 0.08 m box whose grasps are derived
    from the initial configuration; zero torques, 1 s. n = 3: planar arms (parallel vertical axes, planar
    constraint rows: a 3-joint arm cannot hold a 6-D grasp, Λ𝐈⁻¹Λᵀ would be singular for r ≥ 3); n ≥ 4:
    spatial arms with non-parallel axes (yaw, pitch, pitch, roll, pitch, roll, yaw), spatial rows; n ≤ 7.

    Args:
        r: the number of arms.
        n: joints per arm: 3 (planar) or 4 to 7 (spatial).

    Returns:
        dict: the scenario (name 'synthetic_RxN', gravity, duration, arms, object).

    Raises:
        ValueError: n is neither 3 nor in 4..7.
    """
    if not (n == 3 or 4 <= n <= len(_SPATIAL_AXES)):
        raise ValueError(f"n must be 3 (planar) or 4..{len(_SPATIAL_AXES)} (spatial), got {n}")
    arms = [_synthetic_arm(m, r, n) for m in range(r)]
    return {"name": f"synthetic_{r}x{n}", "gravity": [0.0, 0.0, -9.81], "duration": 1.0, "arms": arms,
            "object": {"box": {"size": [0.3, 0.3, 0.08], "density": 1000}, "grasps": "derive"}}


def _synthetic_arm(m: int, r: int, n: int) -> dict:
    """Arm m of `synthetic_scene`: base at angle 2πm/r on the circle, yawed to face the centre."""
    phi = 2.0 * math.pi * m / r
    yaw = math.remainder(phi + math.pi, 2.0 * math.pi)
    base = {"position": [0.8 * math.cos(phi), 0.8 * math.sin(phi), 0.0], "rpy": [0.0, 0.0, yaw]}
    box = lambda L, w: {"length": L, "cross_section": [w, w], "density": 2700}
    if n == 3:
        links = [{"joint": {"axis": [0, 0, 1]}, "box": box(L, 0.04)} for L in _PLANAR_LENGTHS]
        angles = list(_PLANAR_ANGLES)
    else:
        links = [{"joint": {"axis": _SPATIAL_AXES[i]}, "box": box(_SPATIAL_LENGTHS[i], 0.05)} for i in range(n)]
        links[0]["joint"]["position"] = [0.0, 0.0, 0.3]
        angles = list(_SPATIAL_ANGLES[:n])
    angles = [a + 0.05 * m for a in angles]
    return {"name": f"arm{m}", "base": base, "links": links, "initial": {"angles": angles},
            "torque": {"constant": [0.0] * n}}


def synthetic_model(r: int, n: int) -> Model:
    """The frozen Model of `synthetic_scene(r, n)`.

    Args:
        r: the number of arms.
        n: joints per arm: 3 (planar) or 4 to 7 (spatial).

    Returns:
        Model: the frozen scenario model.
    """
    return model_from_dict(synthetic_scene(r, n), where=f"synthetic_{r}x{n}")


def scaling_point(r: int, n: int, count: int, peers=None, repeats: int = 3, seed: int = 0) -> dict:
    """µs per evaluation of synthetic_model(r, n) at `count` random states.

    The states are q0 + N(0, 0.1²) rad, rates N(0, 1) rad/s, torques N(0, 1) N·m (not on the manifold: the
    cost does not depend on it): native amortised and from Python (`native_eval_us`), and
    'native_cholesky_us', amortised with rank_tol CHOLESKY_RANK_TOL (a diagnostic: the dense path's pivoted
    Cholesky taken whenever its pivots are positive, where the default rank_tol's guaranteed-bound test may
    send it to the eigen-decomposition; for three arms or more the O(r) Schur path (`compiled.schur`) is
    taken either way where its own certificate holds); with peers also mj_forward and constraintDynamics
    from Python (at the first state).

    Args:
        r: the number of arms.
        n: joints per arm (`synthetic_scene`).
        count: the number of states S.
        peers: the peers module (`load_peers`); None: native only.
        repeats: timings at least.
        seed: seed of the random states.

    Returns:
        dict: 'r', 'n', 'n_total' (stacked joints), 'rows' (constraint rows K = rows per grasp × (r − 1)),
        'planar'; µs: 'native_amortised_us', 'native_python_us', 'native_cholesky_us', with peers
        'mujoco_forward_us' and 'pinocchio_us' (None without pin); 'bad_states'.
    """
    model = synthetic_model(r, n)
    rng = np.random.default_rng(seed)
    N = model.n_total
    Y = np.hstack([model.q0 + rng.normal(scale=0.1, size=(count, N)), rng.normal(size=(count, N))])
    TAU = rng.normal(size=(count, N))
    out = {"r": r, "n": n, "n_total": N, "rows": int(model.rows.shape[0] * (r - 1)),
           "planar": model.plane is not None} | native_eval_us(model, Y, TAU, repeats, calls=1000)
    forced = replace(model, integrator=replace(model.integrator, rank_tol=CHOLESKY_RANK_TOL))
    out["native_cholesky_us"] = native_eval_us(forced, Y, TAU, repeats, calls=1)["native_amortised_us"]
    if peers is not None:
        out |= peer_eval_us(model, Y[0, :N], Y[0, N:], TAU[0], peers, calls=1000, repeats=repeats)
    return out


def scaling_study(ladders: Ladders, peers=None, log: Callable[[str], None] = lambda s: None) -> dict:
    """Every (r, n) of the ladders' grid (`scaling_point`) and power-law fits (`scaling_fits`).

    The fits are of the amortised µs ('fits') and of the forced-Cholesky diagnostic ('fits_cholesky').

    Args:
        ladders: the Ladders (scaling_r, scaling_n, eval_states, repeats).
        peers: the peers module (`load_peers`); None: native only.
        log: progress callback, one line of text per point.

    Returns:
        dict: 'points' (`scaling_point` dicts, r outer, n inner), 'fits', 'fits_cholesky'.
    """
    points = []
    for r in ladders.scaling_r:
        for n in ladders.scaling_n:
            log(f"scaling: {r} arms x {n} joints")
            points.append(scaling_point(r, n, ladders.eval_states, peers, max(ladders.repeats, 2)))
    return {"points": points, "fits": scaling_fits(points),
            "fits_cholesky": scaling_fits(points, "native_cholesky_us")}


def scaling_fits(points: list[dict], key: str = "native_amortised_us") -> dict:
    """Power-law fits (`power_fit`) of points[key] per fixed r, per fixed n, and over every point.

    'in_total_joints' per fixed r (over n), 'in_arms' per fixed n (over r), and 'all' of every point in
    total joints; only groups of two or more distinct abscissae.

    Args:
        points: `scaling_point` dicts.
        key: the µs field fitted.

    Returns:
        dict: 'in_total_joints' {str(r): fit}, 'in_arms' {str(n): fit}, and 'all' (a fit; only with two
        distinct total joint counts).
    """
    def group(by: str, x: str) -> dict:
        out = {}
        for v in sorted({p[by] for p in points}):
            sel = [p for p in points if p[by] == v]
            if len({p[x] for p in sel}) >= 2:
                out[str(v)] = power_fit([p[x] for p in sel], [p[key] for p in sel])
        return out

    fits = {"in_total_joints": group("r", "n_total"), "in_arms": group("n", "r")}
    if len({p["n_total"] for p in points}) >= 2:
        fits["all"] = power_fit([p["n_total"] for p in points], [p[key] for p in points])
    return fits
