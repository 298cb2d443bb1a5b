"""The LP bound's grasp wrenches along a replayed motion (`coopsim optimize --method lp --replay`).

The LP bound fixes the grasp wrenches only where its rows are: at both ends of every grid interval
(`coopsim.inverse.retime.Retiming.f`, each interval's own s̈). Along the replayed motion they are

    f(t) = f_LP(t) + Ā⁺ (ȳ(t) − Ā f_LP(t)),   Ā = [A; Jᵀ_passive],  ȳ = [y; −τ_arms,passive]

with f_LP linear in t on each law interval between its two ends' wrenches (at a grid point the interval
starting there, as the sampled time law takes s̈), read at the replay's samples and joined linearly between
them (`LPWrenches.resampled`: a grid point's jump spread over the sample interval holding it, as the
trajectory's Hermite interpolant spreads the jump of s̈; a jump inside an integrator step would cost the
MuJoCo twin's soft welds an error of its size). The correction is the least-norm one onto Ā f = ȳ, so the
object wrench equation and the passive joints' zero torque hold exactly at every sample whatever f_LP, and
the motion is the one optimised; at the LP's own points f_LP meets them already and f is its distribution.

Between the points the interpolant can leave a motor line although some distribution keeps it: wherever
it leaves one by more than REFINE_TOL (relative to τ_s, the retiming's own tolerance at its check points),
f is the nearest wrenches to it (least ½|f − f_LP|²) meeting the equalities and every line widened by
REFINE_TOL τ_s (one small QP, `coopsim.inverse.qp.solve_qps`; continuous in the sample's state, unlike a
vertex of the least-excess LP, whose jumps the twin's welds would feel). Where even the widened lines
admit none, the least excess e* any distribution reaches (`coopsim.inverse.capacity.least_excess`, the
LP bound's own definition: f free per point) widens them to e* + REFINE_TOL. So every sample is within
REFINE_TOL of its lines, or of the least excess of any distribution there. The QPs are solved at the
replay's samples only; at the integrators' stage times between them the samples' wrenches are joined
linearly and projected alike (`sample_wrenches`), so the motion is exact there too. Without the LP's wrenches (a
free path under the scenario's law) f_LP = 0: the least-norm wrenches A⁺ȳ, corrected alike.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from coopsim.core.model import Motors, torque_limits
from coopsim.inverse.capacity import least_excess
from coopsim.inverse.problem import InverseError, InverseProblem, torques_of
from coopsim.inverse.qp import solve_qps
from coopsim.inverse.retime import REFINE_TOL, Retiming, _stages

PINV_RCOND = 1e-10        # singular values of Ā below this times its largest count as zero (its pseudo-inverse)


@dataclass(frozen=True, eq=False)
class LPWrenches:
    """The LP bound's grasp wrenches at both ends of each grid interval of its time law (K intervals).

    Attributes:
        t0: (K,) s, each interval's start, from the law's start.
        t1: (K,) s, its end.
        f: (K, 2, rk) [N; N·m], the wrenches at its start and at its end (its own s̈), rows S, world axes.
    """

    t0: np.ndarray
    t1: np.ndarray
    f: np.ndarray

    def at(self, t: np.ndarray) -> np.ndarray:
        """f_LP (M, rk) at times t (M,): linear on the interval holding t (the one starting at a grid point
        there; clamped to the law's span).

        Args:
            t: (M,) s, from the law's start.

        Returns:
            np.ndarray: (M, rk) [N; N·m].
        """
        t = np.asarray(t, dtype=float)
        k = np.clip(np.searchsorted(self.t0, t, side="right") - 1, 0, len(self.t0) - 1)
        span = self.t1[k] - self.t0[k]
        sig = np.clip((t - self.t0[k]) / np.where(span > 0, span, 1.0), 0.0, 1.0)[:, None]
        return (1.0 - sig) * self.f[k, 0] + sig * self.f[k, 1]

    def resampled(self, t: np.ndarray) -> "LPWrenches":
        """The wrenches at times t (M,) (`at`) joined linearly between them: continuous, a jump at a grid point
        (each side its own s̈) spread over the interval of t holding it, as the trajectory's Hermite
        interpolant between its samples spreads the jump of s̈.

        Args:
            t: (M,) s, increasing, from the law's start (the replay's samples).

        Returns:
            LPWrenches: M − 1 intervals.
        """
        t = np.asarray(t, dtype=float)
        f = self.at(t)
        return LPWrenches(t[:-1], t[1:], np.stack([f[:-1], f[1:]], 1))


def lp_wrenches(r: Retiming) -> LPWrenches:
    """The LP bound's wrenches of a retiming on its law's intervals.

    Args:
        r: a feasible Retiming of the LP bound (its f).

    Returns:
        LPWrenches.

    Raises:
        InverseError: the retiming has no wrenches (not the LP bound's, or infeasible).
    """
    if r.f is None or r.law is None:
        raise InverseError("lp replay: the retiming carries no LP-bound grasp wrenches")
    law = r.law
    st = _stages(law.s, law.piece)
    return LPWrenches(law.t[st], law.t[st + 1], np.asarray(r.f, dtype=float))


class LPDistribution(NamedTuple):
    """The LP bound's grasp wrenches at a problem's samples (N samples).

    Attributes:
        f: (N, rk) [N; N·m], the wrenches applied (rows S, world axes).
        interpolant_excess: (N,) the interpolant's largest excess over a motor line, relative to τ_s (≤ 0:
            within).
        excess: (N,) that of f.
        corrected: (N,) bool, the samples whose nearest wrenches within the lines replaced the interpolant.
        least: (N,) the least excess any distribution reaches, relative to τ_s, at the samples where even
            the lines widened by REFINE_TOL admit none (nan elsewhere).
    """

    f: np.ndarray
    interpolant_excess: np.ndarray
    excess: np.ndarray
    corrected: np.ndarray
    least: np.ndarray


def lp_distribution(prob: InverseProblem, wrenches: LPWrenches | None, motors: Motors,
                    passive: np.ndarray, correct: bool = True) -> LPDistribution:
    """The LP bound's grasp wrenches at the samples of `prob` (see the module).

    Args:
        prob: the InverseProblem (N samples; its t from the law's start; its object the carried load).
        wrenches: the LPWrenches of the law, or None (the interpolant f_LP = 0: the least-norm wrenches A⁺ȳ).
        motors: the Motors (the lines of eq. 36).
        passive: (n,) bool, the passive joints.
        correct: False: the least-norm projection only, no sample corrected (between the replay's samples,
            `sample_wrenches`).

    Returns:
        LPDistribution.

    Raises:
        InverseError: a sample's least-excess LP is not solved, or neither QP is.
    """
    passive = np.asarray(passive, dtype=bool)
    lo, hi = torque_limits(motors, prob.qd)
    Aeq = np.concatenate([prob.A, prob.JT[:, passive, :]], 1)
    ybar = np.concatenate([prob.y, -prob.tau_arms[:, passive]], 1)
    f0 = np.zeros(prob.JT.shape[::2]) if wrenches is None else wrenches.at(prob.t)
    f = f0 + np.einsum("niq,nq->ni", np.linalg.pinv(Aeq, rcond=PINV_RCOND), ybar - np.einsum("nqi,ni->nq", Aeq, f0))
    interp = _excess(torques_of(prob, f), lo, hi, motors.stall_torque, passive)
    bad = np.flatnonzero(interp > REFINE_TOL) if correct else np.zeros(0, int)
    least = np.full(len(f), np.nan)
    if bad.size:
        rows = (prob.tau_arms[bad], prob.JT[bad], Aeq[bad], ybar[bad], lo[bad], hi[bad], motors.stall_torque, passive)
        qp = _nearest(f[bad], *rows, np.full(bad.size, REFINE_TOL))
        if not np.all(qp.ok):
            out = np.flatnonzero(~qp.ok)
            lp = least_excess(prob.tau_arms[bad[out]], prob.JT[bad[out]], prob.A[bad[out]], prob.y[bad[out]],
                              lo[bad[out]], hi[bad[out]], motors.stall_torque, passive)
            if np.any(lp.status != 0):
                i = int(np.flatnonzero(lp.status != 0)[0])
                raise InverseError(f"lp replay: the least-excess LP failed at t = {prob.t[bad[out[i]]]:.6g} s: "
                                   f"{lp.messages[i]}")
            least[bad[out]] = lp.x[:, -1]
            again = _nearest(f[bad[out]], *(r[out] if k < 6 else r for k, r in enumerate(rows)),
                             np.maximum(lp.x[:, -1], 0.0) + REFINE_TOL)
            qp.x[out] = np.where(again.ok[:, None], again.x, lp.x[:, :-1])
        f[bad] = qp.x
    ex = _excess(torques_of(prob, f), lo, hi, motors.stall_torque, passive)
    corrected = np.zeros(len(f), bool)
    corrected[bad] = True
    return LPDistribution(f, interp, ex, corrected, least)


def sample_wrenches(prob: InverseProblem, wrenches: LPWrenches | None, motors: Motors,
                    passive: np.ndarray) -> LPWrenches:
    """The replay's wrenches at its samples (`lp_distribution`, corrected) joined linearly between them.

    Read at an integrator's stage times with `lp_distribution(..., correct=False)`: the motion exact there
    too (the least-norm projection), the lines kept at the samples, one QP a sample and none a stage time.

    Args:
        prob: the InverseProblem at the replay's samples (N, increasing t from the law's start).
        wrenches: the LPWrenches of the law (`LPWrenches.resampled` at those samples), or None.
        motors: the Motors.
        passive: (n,) bool, the passive joints.

    Returns:
        LPWrenches: N − 1 intervals.
    """
    f = lp_distribution(prob, wrenches, motors, passive).f
    return LPWrenches(prob.t[:-1], prob.t[1:], np.stack([f[:-1], f[1:]], 1))


def _nearest(f0, tau_arms, JT, Aeq, ybar, lo, hi, stall, passive, widen):
    """The wrenches nearest f0 (M, rk) (least ½|f − f0|², N and N·m alike) with Ā f = ȳ and every active line
    with a finite τ_s widened by widen (M,) × τ_s: the `solve_qps` batch."""
    j = ~passive & np.isfinite(stall)
    C = JT[:, j, :]
    w = widen[:, None] * stall[j]
    M, rk = f0.shape
    return solve_qps(np.broadcast_to(np.eye(rk), (M, rk, rk)), f0, Aeq, ybar, C,
                     lo[:, j] - tau_arms[:, j] - w, hi[:, j] - tau_arms[:, j] + w)


def _excess(tau: np.ndarray, lo: np.ndarray, hi: np.ndarray, stall: np.ndarray, passive: np.ndarray) -> np.ndarray:
    """max over the active joints with a finite τ_s of max(τ − τ_max, τ_min − τ)/τ_s (N,) (−inf: none)."""
    j = ~passive & np.isfinite(stall)
    return np.max((np.maximum(tau - hi, lo - tau) / np.where(j, stall, 1.0))[:, j], axis=1, initial=-np.inf)
