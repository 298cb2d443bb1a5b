"""Fixed path, free timing: the time law s(t) along a joint path that carries a payload fastest, and the
heaviest payload a path carries within a duration (the dynamic load carrying capacity with the
timing free).

Along a joint path θ(s) (`coopsim.inverse.path.JointPath`) with a = s̈ and b = ṡ²,
θ̇ = θ′√b and θ̈ = θ′a + θ″b, so the inverse dynamics of every linear resolution (paper W⁺,
non-squeezing, minimum energy with fixed weights) is affine in (a, b) at each path point, and
affine in the carried mass μ for fixed (a, b) (`coopsim.inverse.capacity.mass_line`):

    τ = C₀ + a C_a + b C_b,   C_x = c_x + μ m_x                                  (`path_dynamics`)

— three evaluations of the inverse dynamics, at (a, b) = (0, 0), (1, 0), (0, 1). The LP bound keeps
the grasp wrenches f free at each point: τ = τ_arms(a, b) + Jᵀ f with A f = y(a, b, μ).

The motor lines of eq. 36, −τ_s − k θ̇ ≤ τ ≤ τ_s − k θ̇ (k = τ_s/ω_s), are linear in θ̇ = θ′√b, not in
b. They are linearised in b around the previous solution b̄ by the tangent √b ≈ (√b̄ + b/√b̄)/2 —
an over-estimate, conservative on the side where the term counts against the torque and exact at b̄ —
and solved again until b stops changing, then checked exactly (`check_time_law`).

Discretisation (TOPP-RA's first-order interpolation): the grid s_0 < … < s_M on each smooth piece of
the path, b linear and a = a_i constant on [s_i, s_{i+1}], b_{i+1} = b_i + 2Δ_i a_i, b = 0 at both ends
of every piece (the path may have a corner there). The constraints hold at both ends of every
interval with that interval's a, i.e. on both sides of every grid point: the torques of the sampled
time law are within the lines at every grid point exactly, not only approximately. Between the grid
points the law (b linear, a constant) can still exceed them, most where ṡ = √b rises from rest (√b is
concave). The check points (`PathDynamics.fine_points`: by default the interior points of the FINE×
finer grid) fix that lazily: at a check point at σ in interval i, b = (1 − σ)b_i + σb_{i+1} and a = a_i,
so its torques are affine in the interval's unknowns with the path dynamics evaluated there (the LP
bound: its own grasp wrenches, free); `retime` solves, checks the law exactly at every check point
(`fine_excess`), adds the rows of every check point of each interval holding one that exceeds by more
than REFINE_TOL (their velocity terms by the tangent at b̄ there), and solves again, until none does.

Two solvers of the same discrete problem: 'reachability' (TOPP-RA: a backward pass of controllable
sets and a greedy forward pass, compiled, cost linear in the grid points; for a linear resolution each
stage a two-variable LP solved exactly by its vertices, `reachability`; for the LP bound a small LP in
(a, b) and its points' grasp wrenches, solved by a dense dual simplex, `lp_reachability`), and `grid_lp`
(one sparse LP over the whole grid, maximising Σ b, HiGHS; its simplex grows faster than linearly);
`default_solver` picks reachability except for the LP bound's large stages; `certificate` gives the grid
LP's dual certificate at a law found either way. The time is
Σ 2Δ_i/(√b_i + √b_{i+1}). Where the feasible profiles have a pointwise largest one the two give it (the
paper carry: to 1e-9); with this discretisation they need not, and then the greedy forward pass can be
slower than the grid LP's law (both within the lines, as `check_time_law` shows). Neither minimises the
time itself, a convex function of b over the linearised constraints.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
import scipy.sparse as sp
from scipy.optimize import brentq, linprog

from coopsim.core.errors import CoopsimError
from coopsim.core.model import Model, Motors, ObjectMotion, SampledTimeLaw
from coopsim.inverse import capacity as cap
from coopsim.inverse.path import JointPath
from coopsim.inverse.problem import InverseProblem, inverse_problem
from coopsim.inverse.solve import resolution_for

LP_BOUND = "lp"                 # the method name of the best distribution (grasp wrenches free per point)
B_FLOOR = 1e-14                 # relative floor of b̄ in the tangent (b̄ = 0 at a piece's ends)
SHRINKS = 30                    # the most times b̄ is quartered when the rows linearised at it have no solution
MAX_LINEARISATIONS = 60         # the most linearisations of the motor lines per minimum-time solve
BIG = 1e12                      # the box |a|, b <= BIG·scale keeping a stage's LP bounded
FINE = 10                       # the check grid's intervals per grid interval (the rows added between grid points)
REFINE_TOL = 1e-9               # the excess over a line (relative to τ_s) at a check point that adds its interval's rows
MAX_REFINE = 8                  # the most rounds of rows added between grid points per minimum-time solve
NEAR = 1e-6                     # the first bracket width, relative, of a heaviest-load search from a mass carried (at_least)


class RetimeError(CoopsimError):
    """The retiming cannot be done as asked (no motion meets the bound, the motors cannot hold the load,
    the solver does not converge)."""


@dataclass(frozen=True, eq=False)
class PathDynamics:
    """The inverse dynamics along a joint path, affine in (a, b) and the carried mass μ (N points, n joints).

    Attributes:
        path: the JointPath (N points).
        method: a linear resolution's name, or 'lp' (the LP bound: grasp wrenches free).
        mode: 'scaled' (μ the object's mass) or 'payload' (μ a point payload's mass).
        tau: (2, 3, N, n) N·m (N), the torques' coefficients [mass⁰, mass¹][constant, a, b]: for a
            resolution τ = Σ_x (tau[0, x] + μ tau[1, x]) x (x = 1, a, b); for 'lp' τ_arms (tau[1] = 0).
        y: (2, 3, N, k) [N; N·m], the net object wrench's coefficients, likewise ('lp' only; else None).
        JT: (N, n, rk) Jᵀ ('lp' only; else None).
        A: (N, k, rk) the grasp-matrix rows A ('lp' only; else None).
        stall: (n,) N·m (N), τ_s (inf: no limit).
        slope: (n,) N·m·s/rad, k = τ_s/ω_s (0: flat line).
        active: (n,) bool, the actuated joints (the passive ones carry zero torque).
        nominal_mass: kg, μ of the nominal object (the object's mass for 'scaled', 0 for 'payload').
        fine_maker: () ↦ the PathDynamics at the check points between the grid points (`fine_points`),
            or None (no check points: the constraints hold at the grid points only).
    """

    path: JointPath
    method: str
    mode: str
    tau: np.ndarray
    y: np.ndarray | None
    JT: np.ndarray | None
    A: np.ndarray | None
    stall: np.ndarray
    slope: np.ndarray
    active: np.ndarray
    nominal_mass: float
    fine_maker: Callable | None = None
    _fine: dict = field(default_factory=dict, init=False, repr=False)

    def fine_points(self) -> "FinePoints | None":
        """The check points between the grid points with their intervals (computed once; None: none).

        Returns:
            FinePoints | None: the dynamics at the points carry this PathDynamics' motors.
        """
        if self.fine_maker is None:
            return None
        if "points" not in self._fine:
            fd = self.fine_maker()
            self._fine["points"] = None if fd is None else fine_points(self, fd)
        fp = self._fine["points"]
        return None if fp is None else replace(fp, dyn=replace(fp.dyn, stall=self.stall, slope=self.slope,
                                                               active=self.active))

    def torques(self, mass: float, a, b, f: np.ndarray | None = None) -> np.ndarray:
        """τ (N, n) at carried mass μ and (a, b) per point (for 'lp' the grasp wrenches f (N, rk) too).

        Args:
            mass: kg, μ.
            a: (N,) or float, 1/s², s̈.
            b: (N,) or float, 1/s², ṡ².
            f: (N, rk) [N; N·m], the grasp wrenches ('lp' only).

        Returns:
            np.ndarray: (N, n) N·m (N on a prismatic joint).
        """
        C = self.tau[0] + mass * self.tau[1]
        a, b = np.broadcast_to(a, C.shape[1:2])[:, None], np.broadcast_to(b, C.shape[1:2])[:, None]
        tau = C[0] + a * C[1] + b * C[2]
        return tau if f is None else tau + np.einsum("nij,nj->ni", self.JT, f)


def path_dynamics(model: Model, jp: JointPath, method: str, mode: str = "payload",
                  payload_position: np.ndarray | None = None, fine=FINE) -> PathDynamics:
    """The affine coefficients of the inverse dynamics along a joint path (`PathDynamics`).

    Three inverse problems, at (a, b) = (0, 0), (1, 0), (0, 1); for a resolution each gives τ(μ) = α + μβ
    (`coopsim.inverse.capacity.affine_torques`), the coefficients of a and b their differences from
    the first. The same at the check points between the grid points when first needed (`fine_points`).

    Args:
        model: the Model (its motors, weights, passive joints, object).
        jp: the JointPath.
        method: a name in `coopsim.inverse.resolutions.LINEAR_METHODS`, or 'lp'.
        mode: 'scaled' or 'payload'.
        payload_position: (3,) m, object frame, the point payload's position ('payload'); None: the
            scenario's.
        fine: the check points: an int F (the interior points of the F× finer grid, `JointPath.refined`;
            none without the joint path's recipe), a JointPath on the same path (its points that are not
            grid points), the PathDynamics of the same method and mode at such points, or None / 0 / 1
            (none).

    Returns:
        PathDynamics.

    Raises:
        RetimeError: 'payload' without a payload position.
    """
    pos = model.inverse.payload_position if payload_position is None else payload_position
    if mode == "payload" and pos is None:
        raise RetimeError("inverse.payload.position: the payload mode needs a payload position")
    probs = [inverse_problem(model, jp.states(a, b), pos if mode == "payload" else None)
             for a, b in ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0))]
    motors = model.motors
    y = JT = A = None
    if method == LP_BOUND:
        tau = np.stack([np.stack([p.tau_arms for p in probs]), np.zeros((3,) + probs[0].tau_arms.shape)])
        lines = [cap.mass_line(p, mode) for p in probs]
        y = np.stack([np.stack([y0 for y0, _ in lines]), np.stack([y1 for _, y1 in lines])])
        JT, A = probs[0].JT, probs[0].A
    else:
        res = resolution_for(model, method)
        ab = [cap.affine_torques(p, res, mode) for p in probs]
        tau = np.stack([np.stack([x for x, _ in ab]), np.stack([x for _, x in ab])])
    tau[:, 1:] -= tau[:, :1]
    if y is not None:
        y[:, 1:] -= y[:, :1]
    maker = None
    if isinstance(fine, (JointPath, PathDynamics)) or (fine is not None and fine > 1 and jp.recipe is not None):
        def maker():
            if isinstance(fine, PathDynamics):
                return fine
            fjp = fine if isinstance(fine, JointPath) else jp.refined(fine)
            return path_dynamics(model, fjp, method, mode, payload_position, None)
    return PathDynamics(jp, method, mode, tau, y, JT, A, motors.stall_torque.astype(float), motors.line_slope,
                        ~motors.passive.astype(bool), cap.nominal_mass(model, mode), maker)


@dataclass(frozen=True, eq=False)
class FinePoints:
    """Check points strictly inside the grid's intervals (P points): on interval k (`_stages`), a = a_k and
    b = (1 − σ) b_i + σ b_{i+1} exactly (b linear in s), so each point's torques are linear in its
    interval's unknowns with the path dynamics evaluated there.

    Attributes:
        dyn: the PathDynamics at the P points.
        stage: (P,) int, each point's interval (an index into `_stages` of the grid).
        sigma: (P,) its place in the interval, (s − s_i)/(s_{i+1} − s_i) ∈ (0, 1).
    """

    dyn: PathDynamics
    stage: np.ndarray
    sigma: np.ndarray

    def subset(self, idx: np.ndarray) -> "FinePoints":
        """The points idx only.

        Args:
            idx: (R,) int, indices of the points.

        Returns:
            FinePoints: R points (their dynamics without check points of their own).
        """
        d = self.dyn
        sub = d.path.subset(idx)
        pick = (lambda x, ax: None if x is None else np.take(x, idx, axis=ax))
        dyn = replace(d, path=sub, tau=d.tau[:, :, idx], y=pick(d.y, 2), JT=pick(d.JT, 0), A=pick(d.A, 0),
                      fine_maker=None)
        return FinePoints(dyn, self.stage[idx], self.sigma[idx])


def fine_points(dyn: PathDynamics, fine: PathDynamics) -> FinePoints | None:
    """The points of `fine` strictly inside an interval of dyn's grid (the others dropped), with their intervals.

    Args:
        dyn: the PathDynamics on the grid.
        fine: the PathDynamics at other points of the same path and pieces.

    Returns:
        FinePoints | None: None when no point lies inside an interval.
    """
    s, piece = dyn.path.s, dyn.path.points.piece
    st = _stages(s, piece)
    fs, fpc = fine.path.s, fine.path.points.piece
    k = np.full(len(fs), -1)
    for p in np.unique(fpc):
        own = np.flatnonzero(piece[st] == p)
        sel = np.flatnonzero(fpc == p)
        if own.size:
            k[sel] = own[np.clip(np.searchsorted(s[st[own]], fs[sel], side="right") - 1, 0, own.size - 1)]
    i = st[np.maximum(k, 0)]
    sigma = (fs - s[i]) / (s[i + 1] - s[i])
    keep = np.flatnonzero((k >= 0) & (sigma > 1e-9) & (sigma < 1 - 1e-9))
    if not keep.size:
        return None
    return FinePoints(fine, k, sigma).subset(keep)


@dataclass(frozen=True, eq=False)
class TimeLaw:
    """A time law on a path grid: b = ṡ² linear and a = s̈ constant on each interval (N grid points).

    Attributes:
        s: (N,) the grid, piece after piece, each piece's knots at both of its ends.
        piece: (N,) int, each point's piece.
        b: (N,) 1/s², ṡ² at the points (0 at each piece's ends).
        a: (N,) 1/s², s̈ on the interval starting at each point (0 at each piece's last point).
        t: (N,) s, the time at each point.
    """

    s: np.ndarray
    piece: np.ndarray
    b: np.ndarray
    a: np.ndarray
    t: np.ndarray

    @property
    def duration(self) -> float:
        """s, the time from rest to rest along the whole path."""
        return float(self.t[-1])

    def at(self, s: np.ndarray, piece: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(a, b) at points s (M,) on pieces `piece` (M,): the interval's a, b = b_i + 2a_i(s − s_i).

        Args:
            s: (M,) the path parameter.
            piece: (M,) int, each point's piece.

        Returns:
            tuple[np.ndarray, np.ndarray]: a (M,) and b (M,) 1/s² (an interval's left end: its own a).
        """
        i = np.empty(len(s), dtype=int)
        for k in np.unique(piece):
            idx = np.flatnonzero(self.piece == k)
            sel = piece == k
            i[sel] = idx[np.clip(np.searchsorted(self.s[idx], s[sel], side="right") - 1, 0, len(idx) - 2)]
        a = self.a[i]
        return a, np.maximum(self.b[i] + 2.0 * a * (s - self.s[i]), 0.0)

    def point_accel(self) -> np.ndarray:
        """s̈ (N,) 1/s² at the points: each interval's a at its start, at a piece's last point that of the
        interval ending there (so every point's torque is one the law drives).

        Returns:
            np.ndarray: (N,) 1/s².
        """
        a = self.a.copy()
        last = np.append(np.flatnonzero(np.diff(self.piece)), len(self.s) - 1)
        a[last] = self.a[last - 1]
        return a

    def samples(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t, s, ṡ) at the grid points, each knot once: the sampled time law of a scenario.

        Returns:
            tuple: t (K,) s, s (K,) and ṡ (K,) 1/s (s̈ constant between samples).
        """
        keep = np.concatenate([[True], np.diff(self.s) > 0])
        return self.t[keep].copy(), self.s[keep].copy(), np.sqrt(self.b[keep])


def retimed_motion(motion: ObjectMotion, law: TimeLaw, output_dt: float | None = None) -> ObjectMotion:
    """The object motion of a waypoint path (`coopsim.inverse.path.WaypointPath`) with a retimed law.

    The waypoints stay; their times become the law's times at the knots, and the time law is 'sampled'
    (`coopsim.core.model.SampledTimeLaw`, the grid points' t, s and ṡ), starting at the first
    waypoint's time. The redundant arms' null-space pull becomes one per unit path (rest_pull 'path') of
    rest_gain × the given motion's duration per unit s, as `coopsim.inverse.path.joint_path` was given it
    (rest_gain scaled by the old duration over the law's), so the motion's joint path is the retimed one
    whatever the law.

    Args:
        motion: the ObjectMotion whose waypoints make the path.
        law: the TimeLaw on a grid of that path.
        output_dt: s, the sample interval of the motion's trajectory; None: the motion's.

    Returns:
        ObjectMotion: time_law 'sampled', rest_pull 'path'.
    """
    t, s, rate = law.samples()
    t = t + motion.times[0]
    s[-1], rate[[0, -1]] = 1.0, 0.0
    starts = np.concatenate([[0], np.flatnonzero(np.diff(law.piece)) + 1])
    times = np.append(law.t[starts], law.t[-1]) + motion.times[0]
    gain = motion.path_gain / float(times[-1] - times[0])
    return replace(motion, times=times, time_law="sampled", samples=SampledTimeLaw(t, s, rate), rest_pull="path",
                   rest_gain=gain, output_dt=motion.output_dt if output_dt is None else output_dt)


def time_of(s: np.ndarray, piece: np.ndarray, b: np.ndarray) -> TimeLaw:
    """The TimeLaw of b at the grid: a_i = (b_{i+1} − b_i)/(2Δ_i), Δt_i = 2Δ_i/(√b_i + √b_{i+1}).

    Args:
        s: (N,) the grid (`coopsim.inverse.path.path_grid`).
        piece: (N,) int, each point's piece.
        b: (N,) 1/s², ṡ² (≥ 0).

    Returns:
        TimeLaw (t inf after an interval with b = 0 at both ends).
    """
    ds, same = np.diff(s), piece[1:] == piece[:-1]
    root = np.sqrt(np.maximum(b, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.where(same, (b[1:] - b[:-1]) / (2 * ds), 0.0)
        dt = np.where(same, 2 * ds / (root[1:] + root[:-1]), 0.0)
    return TimeLaw(s, piece, b, np.append(a, 0.0), np.concatenate([[0.0], np.cumsum(dt)]))


# ------------------------------------------------------------------------------------------------
# The constraint rows
# ------------------------------------------------------------------------------------------------

def _tangent(b_ref: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """(λ₀, λ₁) (N,) of the tangent √b ≈ λ₀ + λ₁ b at b̄; (0, 0) where b̄ <= B_FLOOR·scale (a rest point:
    the velocity term vanishes there)."""
    r = np.sqrt(np.maximum(b_ref, B_FLOOR * scale))
    small = b_ref <= B_FLOOR * scale
    return np.where(small, 0.0, 0.5 * r), np.where(small, 0.0, 0.5 / r)


def speed_bound(dyn: PathDynamics) -> np.ndarray:
    """The largest ṡ² (N,) 1/s² at each point keeping every joint within its no-load speed, |θ′|√b ≤ ω_s.

    The motor lines of eq. 36 hold for |θ̇| ≤ ω_s (a robot file's velocity limits are its ω_s); linear in b,
    so exact.

    Args:
        dyn: the PathDynamics.

    Returns:
        np.ndarray: (N,) 1/s² (inf: no joint moves, or no finite no-load speed).
    """
    with np.errstate(divide="ignore"):
        omega = np.where(dyn.slope > 0, dyn.stall / np.where(dyn.slope > 0, dyn.slope, 1.0), np.inf)
        lim = (omega[None, :] / np.abs(dyn.path.d1)) ** 2
    return np.min(np.where(dyn.active[None, :], lim, np.inf), axis=1)


def motor_rows(dyn: PathDynamics, mass: float, lam: tuple[np.ndarray, np.ndarray]):
    """Motor-line rows G a + H b ≤ E at each point (linearised velocity term), active finite-limit joints.

    Upper line τ + kθ′(λ₀ + λ₁ b) ≤ τ_s, lower line −τ − kθ′(λ₀ + λ₁ b) ≤ τ_s, with τ = C₀ + aC_a + bC_b
    ('lp': τ_arms; the Jᵀf part is added by the caller).

    Args:
        dyn: the PathDynamics (N points).
        mass: kg, μ.
        lam: (λ₀, λ₁) (N,) the tangent of √b at each point.

    Returns:
        tuple: G, H, E (N, 2n_a) (upper rows of the n_a joints, then lower), and the joints (n_a,) int.
    """
    j = np.flatnonzero(dyn.active & np.isfinite(dyn.stall))
    C = (dyn.tau[0] + mass * dyn.tau[1])[:, :, j]
    c = dyn.slope[j] * dyn.path.d1[:, j]
    lam0, lam1 = lam[0][:, None], lam[1][:, None]
    G, H, E = C[1], C[2] + c * lam1, dyn.stall[j] - C[0] - c * lam0
    E_lo = dyn.stall[j] + C[0] + c * lam0
    return np.concatenate([G, -G], 1), np.concatenate([H, -H], 1), np.concatenate([E, E_lo], 1), j


def _stages(s: np.ndarray, piece: np.ndarray) -> np.ndarray:
    """Indices i (K,) of the grid points that start an interval (i and i + 1 on one piece)."""
    return np.flatnonzero(piece[1:] == piece[:-1])


def _stage_rows(G, H, E, s, i):
    """Rows in (a_i, b_i) of every stage i: point i with (a_i, b_i), point i+1 with (a_i, b_i + 2Δa_i),
    b_i ≥ 0 and b_{i+1} ≥ 0. Returns G, H, E (K, m) and Δ (K,)."""
    d = (s[i + 1] - s[i])[:, None]
    K = len(i)
    Gs = np.concatenate([G[i], G[i + 1] + 2 * d * H[i + 1], np.zeros((K, 1)), -2 * d], 1)
    Hs = np.concatenate([H[i], H[i + 1], -np.ones((K, 1)), -np.ones((K, 1))], 1)
    Es = np.concatenate([E[i], E[i + 1], np.zeros((K, 2))], 1)
    return Gs, Hs, Es, d[:, 0]


# ------------------------------------------------------------------------------------------------
# TOPP-RA: reachability with exact two-variable LPs
# ------------------------------------------------------------------------------------------------

def _vertices(G, H, E, tol):
    """The vertices (a, b) of the polygons {G a + H b ≤ E} (K stages, m rows): (K, P) arrays, nan where
    a pair of rows does not meet at a feasible point."""
    m = G.shape[1]
    r1, r2 = np.triu_indices(m, 1)
    det = G[:, r1] * H[:, r2] - G[:, r2] * H[:, r1]
    with np.errstate(divide="ignore", invalid="ignore"):
        a = (E[:, r1] * H[:, r2] - E[:, r2] * H[:, r1]) / det
        b = (G[:, r1] * E[:, r2] - G[:, r2] * E[:, r1]) / det
    ok = np.abs(det) > 1e-300
    with np.errstate(invalid="ignore"):
        lhs = G[:, None, :] * a[:, :, None] + H[:, None, :] * b[:, :, None]
        ok &= np.all(lhs <= E[:, None, :] + tol[:, None, None], axis=2)
    return np.where(ok, a, np.nan), np.where(ok, b, np.nan)


def _segment_b(G, H, E, d, h, tol):
    """(min, max) b of the polygon {G a + H b ≤ E} on the line b + 2d a = h (nan: they do not meet)."""
    g = G - 2 * d * H
    r = E - H * h
    with np.errstate(divide="ignore", invalid="ignore"):
        q = r / g
    a_hi = np.min(np.where(g > 0, q, np.inf))
    a_lo = np.max(np.where(g < 0, q, -np.inf))
    if a_lo > a_hi + tol or np.any((g == 0) & (r < -tol)):
        return np.nan, np.nan
    a_lo, a_hi = min(a_lo, a_hi), max(a_lo, a_hi)
    return h - 2 * d * a_hi, h - 2 * d * a_lo


def _boxed(G, H, E, scale_a, scale_b):
    """The rows with the box |a| ≤ BIG·scale_a, b ≤ BIG·scale_b appended (bounded polygons)."""
    K = G.shape[0]
    one, zero = np.ones((K, 1)), np.zeros((K, 1))
    return (np.concatenate([G, one, -one, zero], 1), np.concatenate([H, zero, zero, one], 1),
            np.concatenate([E, BIG * scale_a * one, BIG * scale_a * one, BIG * scale_b * one], 1))


def reachability(dyn: PathDynamics, mass: float, lam, extra=None) -> np.ndarray | None:
    """ṡ² (N,) of the time-optimal law for the linearised rows, by TOPP-RA; None when none exists — the
    compiled pass (`coopsim.compiled.reachability.reachability_pass`; `reachability_reference` the NumPy
    one, same rows, same words).

    Backward: K_M = {0} and K_i = the range of b over the stage polygon cut by b + 2Δa ∈ K_{i+1} (its
    vertices inside the strip and the polygon's chords on the strip's two lines). Forward from b_0 = 0:
    the largest a of the polygon at b_i that stays in K_{i+1}. A check point of `extra` at σ on stage i
    adds its rows to that stage's polygon: b = b_i + 2σΔ a there (`_extra_rows`). Each stage costs
    O(m³) for its m rows, so the pass is linear in the grid points.

    Args:
        dyn: the PathDynamics of a linear resolution.
        mass: kg, μ.
        lam: (λ₀, λ₁) (N,) the tangent of √b.
        extra: (FinePoints, (λ₀, λ₁) (P,)) the check points' rows, or None.

    Returns:
        np.ndarray | None: b (N,) 1/s², or None (a stage without a controllable state).
    """
    from coopsim.compiled import api

    s, piece = dyn.path.s, dyn.path.points.piece
    st, Gs, Hs, Es, d, tol = _stage_polygons(dyn, mass, lam)
    K, m = Gs.shape
    who = np.repeat(np.arange(K), m)
    flat = [Gs.ravel(), Hs.ravel(), Es.ravel()]
    if extra is not None:
        k, rows = _extra_rows(extra, mass, d)
        order = np.argsort(np.concatenate([who, k]), kind="stable")
        flat = [np.concatenate([x, y])[order] for x, y in zip(flat, rows)]
        who = np.concatenate([who, k])[order]
    off = np.concatenate([[0], np.cumsum(np.bincount(who, minlength=K))])
    N = len(s)
    end_at = (piece[st + 1] != piece[np.minimum(st + 2, N - 1)]) | (st + 1 == N - 1)
    start_at = (st == 0) | (piece[np.maximum(st - 1, 0)] != piece[st])
    b = api.reachability_pass(*flat, off, d, tol, st, end_at, start_at, N)
    if b is None:
        return None
    for p in np.unique(piece):
        b[np.flatnonzero(piece == p)[[0, -1]]] = 0.0
    return b


def _stage_polygons(dyn: PathDynamics, mass: float, lam):
    """Every stage's rows in (a_i, b_i) (`_stage_rows` with each point's speed bound and the box `_boxed`):
    st (K,), G, H, E (K, m), Δ (K,) and the stages' feasibility tolerances (K,)."""
    s = dyn.path.s
    G, H, E, _ = motor_rows(dyn, mass, lam)
    st = _stages(s, dyn.path.points.piece)
    scale = np.maximum(np.max(np.abs(np.concatenate([E[st], E[st + 1]], 1)), axis=1), 1e-300)
    cap_b = BIG / max(float(np.min(np.diff(s)[st])), 1e-300) ** 2
    top = np.minimum(speed_bound(dyn), cap_b)
    G, H, E = (np.concatenate([x, y[:, None]], 1) for x, y in ((G, np.zeros(len(s))), (H, np.ones(len(s))),
                                                                 (E, top)))
    Gs, Hs, Es, d = _stage_rows(G, H, E, s, st)
    Gs, Hs, Es = _boxed(Gs, Hs, Es, 1.0 / max(np.min(d), 1e-300), 1.0 / max(np.min(d), 1e-300) ** 2)
    return st, Gs, Hs, Es, d, 1e-12 * scale


def _extra_rows(extra, mass: float, d: np.ndarray):
    """The check points' rows in their stage's (a_i, b_i): G_p a + H_p (b_i + 2σΔ a) ≤ E_p and the speed bound
    b_i + 2σΔ a ≤ b_max(p) (where finite): the stage of each row (R,) and G, H, E (R,)."""
    fp, flam = extra
    Gf, Hf, Ef, _ = motor_rows(fp.dyn, mass, flam)
    top = speed_bound(fp.dyn)
    w = (2 * d[fp.stage] * fp.sigma)[:, None]
    Gf, Hf, Ef = (np.concatenate([x, y[:, None]], 1) for x, y in ((Gf + w * Hf, w[:, 0]), (Hf, np.ones(len(top))),
                                                                   (Ef, top)))
    k = np.repeat(fp.stage, Gf.shape[1])
    keep = np.isfinite(Ef.ravel())
    return k[keep], (Gf.ravel()[keep], Hf.ravel()[keep], Ef.ravel()[keep])


def reachability_reference(dyn: PathDynamics, mass: float, lam, extra=None) -> np.ndarray | None:
    """`reachability` in NumPy: each stage's polygon's vertices vectorised (`_vertices`), the passes in Python.

    Args:
        dyn: the PathDynamics of a linear resolution.
        mass: kg, μ.
        lam: (λ₀, λ₁) (N,) the tangent of √b.
        extra: (FinePoints, (λ₀, λ₁) (P,)) the check points' rows, or None.

    Returns:
        np.ndarray | None: b (N,) 1/s², or None (a stage without a controllable state).
    """
    s, piece = dyn.path.s, dyn.path.points.piece
    st, Gs, Hs, Es, d, tol = _stage_polygons(dyn, mass, lam)
    va, vb = _vertices(Gs, Hs, Es, tol)
    Gs, Hs, Es, va, vb = list(Gs), list(Hs), list(Es), list(va), list(vb)
    if extra is not None:
        for k, rows in _extra_stage_rows(extra, mass, d, (Gs, Hs, Es), tol).items():
            Gs[k], Hs[k], Es[k], va[k], vb[k] = rows
    b = np.zeros(len(s))
    lo, hi = np.zeros(len(s)), np.zeros(len(s))
    for k in range(len(st) - 1, -1, -1):
        i = st[k]
        if piece[i + 1] != piece[min(i + 2, len(s) - 1)] or i + 1 == len(s) - 1:
            lo[i + 1] = hi[i + 1] = 0.0
        inside = vb[k] + 2 * d[k] * va[k]
        sel = (inside >= lo[i + 1] - tol[k]) & (inside <= hi[i + 1] + tol[k])
        cand = [vb[k][sel], *_segment_b(Gs[k], Hs[k], Es[k], d[k], lo[i + 1], tol[k]),
                *_segment_b(Gs[k], Hs[k], Es[k], d[k], hi[i + 1], tol[k])]
        cand = np.concatenate([np.atleast_1d(c) for c in cand])
        cand = cand[np.isfinite(cand)]
        if not len(cand):
            return None
        lo[i], hi[i] = max(np.min(cand), 0.0), np.max(cand)
        if i == 0 or piece[i - 1] != piece[i]:
            if lo[i] > tol[k]:
                return None
            lo[i] = hi[i] = 0.0
    for k, i in enumerate(st):
        g, r = Gs[k], Es[k] - Hs[k] * b[i]
        with np.errstate(divide="ignore", invalid="ignore"):
            a_max = np.min(np.where(g > 0, r / g, np.inf))
        a = min(a_max, (hi[i + 1] - b[i]) / (2 * d[k]))
        a = max(a, (lo[i + 1] - b[i]) / (2 * d[k]))
        b[i + 1] = max(b[i] + 2 * d[k] * a, 0.0)
    for k in np.unique(piece):
        b[np.flatnonzero(piece == k)[[0, -1]]] = 0.0
    return b


def _extra_stage_rows(extra, mass: float, d: np.ndarray, base, tol: np.ndarray) -> dict:
    """{stage k: (G, H, E, vertices a, vertices b)} of the stages with check points: the stage's rows
    (`base`: lists of (m,) arrays) and its points' (`_extra_rows`), padded with 0 ≤ 1 to a common length."""
    k, flat = _extra_rows(extra, mass, d)
    stages = np.unique(k)
    rows = [[np.concatenate([base[x][j], flat[x][k == j]]) for x in range(3)] for j in stages]
    m = max(len(r[0]) for r in rows)
    G, H, E = (np.stack([np.pad(r[x], (0, m - len(r[x])), constant_values=float(x == 2)) for r in rows])
               for x in range(3))
    va, vb = _vertices(G, H, E, tol[stages])
    return {int(j): (G[n], H[n], E[n], va[n], vb[n]) for n, j in enumerate(stages)}


# ------------------------------------------------------------------------------------------------
# One LP over the grid (any resolution, and the LP bound)
# ------------------------------------------------------------------------------------------------

def grid_lp(dyn: PathDynamics, mass: float, lam, extra=None) -> tuple[np.ndarray | None, dict]:
    """ṡ² (N,) maximising Σ b over the grid for the linearised rows, one sparse LP (HiGHS); None: infeasible.

    Unknowns b (N,) (a_i = (b_{i+1} − b_i)/(2Δ_i)), for 'lp' also the grasp wrenches f at both ends
    of every interval and at every check point of `extra` (A f = y(a, b, μ), passive torques 0). The
    rows hold at both ends of every interval and at the check points (b = (1 − σ)b_i + σb_{i+1} there,
    their speed bounds too). The maximal ṡ² profile is the pointwise largest feasible one, so it
    maximises Σ b.

    Args:
        dyn: the PathDynamics.
        mass: kg, μ.
        lam: (λ₀, λ₁) (N,) the tangent of √b.
        extra: (FinePoints, (λ₀, λ₁) (P,) its tangent of √b) the check points' rows, or None.

    Returns:
        tuple: b (N,) 1/s² or None, and the LP's statistics (status, message, iterations, the grasp
        wrenches f (K, 2, rk) and f_fine (P, rk) for 'lp').
    """
    s, piece = dyn.path.s, dyn.path.points.piece
    N = len(s)
    G, H, E, j = motor_rows(dyn, mass, lam)
    st = _stages(s, piece)
    K, d = len(st), s[st + 1] - s[st]
    ks = np.arange(K)
    blocks = [(ks, np.zeros(K), dyn, st, G[st], H[st], E[st], "start"),
              (ks, np.ones(K), dyn, st + 1, G[st + 1], H[st + 1], E[st + 1], "end")]
    if extra is not None:
        fp, flam = extra
        Gf, Hf, Ef, _ = motor_rows(fp.dyn, mass, flam)
        blocks.append((fp.stage, fp.sigma, fp.dyn, np.arange(len(fp.stage)), Gf, Hf, Ef, "inside"))
    lp = dyn.method == LP_BOUND
    rk = dyn.JT.shape[2] if lp else 0
    sizes = [len(b[0]) for b in blocks]
    offs = N + rk * np.concatenate([[0], np.cumsum(sizes)])
    nv = int(offs[-1])
    rows, rhs, eqs, meta = [], [], [], []
    for (k, sig, src, pt, g, h, e, side), off in zip(blocks, offs):
        P, m = g.shape
        i = st[k]
        ga = g / (2 * d[k])[:, None]                                  # a = (b_{i+1} − b_i)/(2Δ), b = (1−σ)b_i + σb_{i+1}
        r_idx = np.arange(P * m)
        M = (sp.coo_matrix(((-ga + h * (1 - sig)[:, None]).ravel(), (r_idx, np.repeat(i, m))), shape=(P * m, nv))
             + sp.coo_matrix(((ga + h * sig[:, None]).ravel(), (r_idx, np.repeat(i + 1, m))), shape=(P * m, nv)))
        if lp:
            JT = src.JT[pt][:, j, :]                                    # (P, n_a, rk)
            blk = np.concatenate([JT, -JT], axis=1)                     # upper, lower rows
            cols = off + np.arange(P)[:, None] * rk + np.arange(rk)[None, :]
            rr = np.repeat(r_idx.reshape(P, m, 1), rk, axis=2)
            cc = np.repeat(cols[:, None, :], m, axis=1)
            M = M + sp.coo_matrix((blk.ravel(), (rr.ravel(), cc.ravel())), shape=(P * m, nv))
            eqs.append(_lp_equalities(src, mass, pt, i, k, sig, d, nv, off, rk))
        rows.append(M.tocsr())
        rhs.append(e.ravel())
        meta.append((np.repeat(src.path.s[pt], m), np.repeat(np.where(side == "inside", -1, pt), m),
                     np.tile(np.arange(m), P), np.full(P * m, side)))
    if extra is not None:                                               # the check points' speed bounds
        top = speed_bound(fp.dyn)
        on = np.flatnonzero(np.isfinite(top))
        i = st[fp.stage[on]]
        r_idx = np.arange(len(on))
        rows.append((sp.coo_matrix((1 - fp.sigma[on], (r_idx, i)), shape=(len(on), nv))
                     + sp.coo_matrix((fp.sigma[on], (r_idx, i + 1)), shape=(len(on), nv))).tocsr())
        rhs.append(top[on])
        meta.append((fp.dyn.path.s[on], np.full(len(on), -1), np.full(len(on), -1), np.full(len(on), "inside")))
    A_ub = sp.vstack(rows).tocsr()
    b_ub = np.concatenate(rhs)
    keep = np.isfinite(b_ub)
    A_eq = b_eq = None
    if lp:
        A_eq = sp.vstack([m for m, _ in eqs]).tocsr()
        b_eq = np.concatenate([r for _, r in eqs])
    bounds = np.zeros((nv, 2))
    bounds[:, 1] = np.inf
    bounds[N:, 0] = -np.inf
    bounds[:N, 1] = speed_bound(dyn)
    for p in np.unique(piece):
        bounds[np.flatnonzero(piece == p)[[0, -1]], 1] = 0.0
    c = np.zeros(nv)
    c[:N] = -1.0
    r = linprog(c, A_ub=A_ub[keep], b_ub=b_ub[keep], A_eq=A_eq, b_eq=b_eq, bounds=bounds, method="highs")
    stats = {"status": int(r.status), "message": str(r.message), "iterations": int(getattr(r, "nit", 0))}
    if r.status != 0:
        return None, stats
    if lp:
        stats["f"] = r.x[N:offs[2]].reshape(2, K, rk).transpose(1, 0, 2)
        stats["f_fine"] = r.x[offs[2]:].reshape(-1, rk)
    where = tuple(np.concatenate([m[x] for m in meta])[keep] for x in range(4))
    stats["certificate"] = _certificate(r, b_ub[keep], b_eq, bounds, where, j)
    return np.maximum(r.x[:N], 0.0), stats


def _certificate(r, b_ub, b_eq, bounds, where, joints) -> dict:
    """The grid LP's dual certificate: the dual objective (equal to the primal's at an optimum, its duals of
    the right sign), their gap, how many motor-line rows bind (nonzero dual) and the one of largest dual
    (its s, grid point (or None inside an interval), stacked joint, side of the interval and line).
    `where`: per row its point's s, grid point (−1 inside an interval), column (−1: a speed bound), side."""
    y_ub = r.ineqlin.marginals
    dual = float(b_ub @ y_ub + (0.0 if b_eq is None else b_eq @ r.eqlin.marginals)
                 + np.where(np.isfinite(bounds[:, 1]), bounds[:, 1], 0.0) @ r.upper.marginals
                 + np.where(np.isfinite(bounds[:, 0]), bounds[:, 0], 0.0) @ r.lower.marginals)
    big = np.abs(y_ub) > 1e-9 * max(float(np.max(np.abs(y_ub), initial=0.0)), 1e-300)
    out = {"primal": float(r.fun), "dual": dual, "gap": abs(float(r.fun) - dual), "sign_ok": bool(np.all(y_ub <= 0)),
           "binding_rows": int(big.sum())}
    if np.any(big):
        k = int(np.argmax(np.abs(y_ub)))
        s, point, col, side = (w[k] for w in where)
        n_a = len(joints)
        out["largest"] = {"s": float(s), "point": None if point < 0 else int(point),
                          "joint": None if col < 0 else int(joints[col % n_a]), "interval_side": str(side),
                          "line": "speed" if col < 0 else ("tau_max" if col < n_a else "tau_min"),
                          "dual": float(y_ub[k])}
    return out


def _lp_equalities(src, mass, pt, i, k, sig, d, nv, off, rk):
    """A f − y_a a − y_b b = y₀ at the points pt (P,) of `src` (on intervals k, at σ), and Jᵀf = −τ_arms on
    the passive joints (τ_arms' a, b parts moved to the b columns i, i + 1); f at columns off + p·rk."""
    Y = src.y[0] + mass * src.y[1]                                      # (3, N, k)
    P = len(pt)
    cols_f = off + np.arange(P)[:, None] * rk + np.arange(rk)[None, :]
    blocks = []
    for Mat, y3 in ((src.A[pt], Y[:, pt]), (src.JT[pt][:, ~src.active, :], -src.tau[0][:, pt][:, :, ~src.active])):
        n_r = Mat.shape[1]
        if n_r == 0:
            continue
        rr = np.arange(P * n_r).reshape(P, n_r)
        f_part = sp.coo_matrix((Mat.ravel(), (np.repeat(rr[:, :, None], rk, 2).ravel(),
                                              np.repeat(cols_f[:, None, :], n_r, 1).ravel())), shape=(P * n_r, nv))
        ya, yb = y3[1], y3[2]                                           # (P, n_r)
        ca = ya / (2 * d[k])[:, None]                                   # −y_a a − y_b ((1−σ)b_i + σb_{i+1})
        b_part = (sp.coo_matrix(((ca - yb * (1 - sig)[:, None]).ravel(), (rr.ravel(), np.repeat(i, n_r))),
                                shape=(P * n_r, nv))
                  + sp.coo_matrix(((-ca - yb * sig[:, None]).ravel(), (rr.ravel(), np.repeat(i + 1, n_r))),
                                  shape=(P * n_r, nv)))
        blocks.append((f_part + b_part, y3[0].ravel()))
    return sp.vstack([m for m, _ in blocks]), np.concatenate([r for _, r in blocks])


# ------------------------------------------------------------------------------------------------
# The LP bound by reachability: each stage a polyhedron in (a, b, z)
# ------------------------------------------------------------------------------------------------

NULL_TOL = 1e-10                # singular values below this times a point's largest count as zero (null spaces)
LP_STAGE_MAX = 40               # the most unknowns of an LP-bound stage LP for the reachability pass (`default_solver`)
LP_BOX = 1e2                    # a stage LP's first box: this times b̄'s peak (/Δ for a), the wrenches' size (z)


def grasp_null_space(dyn: PathDynamics) -> tuple[np.ndarray, np.ndarray] | None:
    """The grasp wrenches meeting the LP bound's equalities at each point: f = A⁺ ȳ + N z, ȳ = [y; −τ_arms,passive]
    the right-hand sides of [A; J_passiveᵀ] f (the object wrench and the passive torques), N the null space of
    that matrix less the directions that move no active motor (Jᵀ_active N z = 0: they change no row).

    Args:
        dyn: the PathDynamics of 'lp' (N points).

    Returns:
        tuple | None: A⁺ (N, rk, q) and N (N, rk, nz) (orthonormal columns); None when either rank differs
        between the points.
    """
    Aeq = np.concatenate([dyn.A, dyn.JT[:, ~dyn.active, :]], 1)               # (N, q, rk)
    U, S, Vt = np.linalg.svd(Aeq)
    rank = np.sum(S > NULL_TOL * S[:, :1], axis=1)
    if np.any(rank != rank[0]):
        return None
    r = int(rank[0])
    plus = np.einsum("nji,nj,nkj->nik", Vt[:, :r, :], 1.0 / S[:, :r], U[:, :, :r])
    null = np.swapaxes(Vt[:, r:, :], 1, 2)                                     # (N, rk, nz0)
    j = dyn.active & np.isfinite(dyn.stall)
    W = dyn.JT[:, j, :] @ null
    if null.shape[2] == 0 or W.shape[1] == 0:
        return plus, null[:, :, :0]
    _, S2, V2t = np.linalg.svd(W)
    rank2 = np.sum(S2 > NULL_TOL * np.maximum(S2[:, :1], 1e-300), axis=1)
    if np.any(rank2 != rank2[0]):
        return None
    return plus, null @ np.swapaxes(V2t[:, :int(rank2[0]), :], 1, 2)


def _lp_point_rows(dyn: PathDynamics, mass: float, lam, ns):
    """Each point's rows g a + h b + W z ≤ e of the LP bound (the motor lines with f = F(a, b) + N z, then the
    speed bound): g, h, e (N, m), W (N, m, nz), F (3, N, rk) (f's constant, a and b parts) and N; None when
    the equalities cannot be met for every (a, b) (`grasp_null_space`)."""
    plus, null = ns
    pas = ~dyn.active
    Y = dyn.y[0] + mass * dyn.y[1]                                              # (3, N, k)
    T = dyn.tau[0] + mass * dyn.tau[1]                                          # (3, N, n)
    rhs = np.concatenate([Y, -T[:, :, pas]], 2)                                 # (3, N, q)
    F = np.einsum("niq,xnq->xni", plus, rhs)
    Aeq = np.concatenate([dyn.A, dyn.JT[:, pas, :]], 1)
    miss = np.max(np.abs(np.einsum("nqi,xni->xnq", Aeq, F) - rhs), initial=0.0)
    if not miss <= 1e-9 * max(float(np.max(np.abs(rhs), initial=0.0)), 1e-300):
        return None
    eff = replace(dyn, tau=np.stack([T + np.einsum("nji,xni->xnj", dyn.JT, F), np.zeros_like(T)]), fine_maker=None)
    G, H, E, j = motor_rows(eff, 0.0, lam)
    Wj = dyn.JT[:, j, :] @ null
    N, nz = len(G), null.shape[2]
    g = np.concatenate([G, np.zeros((N, 1))], 1)
    h = np.concatenate([H, np.ones((N, 1))], 1)
    e = np.concatenate([E, speed_bound(dyn)[:, None]], 1)
    W = np.concatenate([Wj, -Wj, np.zeros((N, 1, nz))], 1)
    return g, h, e, W, F, null


def lp_reachability(dyn: PathDynamics, mass: float, lam, extra=None) -> tuple[np.ndarray | None, dict]:
    """ṡ² (N,) of the LP bound's time-optimal law for the linearised rows by TOPP-RA's passes, each stage the
    polyhedron of its interval's unknowns (a, b) and the grasp wrenches of its points, free
    (`coopsim.compiled.dense_lp.lp_reachability_pass`); the same discrete problem as `grid_lp`.

    The equalities A f = y(a, b, μ) and Jᵀ_passive f = −τ_arms,passive are met exactly by f = F(a, b) + N z
    (`grasp_null_space`), so a stage has 2 + nz·(2 + its check points) unknowns and only the rows: the
    motor lines and speed bound at its two grid points (at the end b + 2Δa) and at each of its check points
    of `extra` (b + 2σΔa), b ≥ 0 at both ends. Backward: K_i = [min b, max b] over the polyhedron cut by
    b + 2Δa ∈ K_{i+1} (two small LPs, compiled dual simplex); forward from b_0 = 0: the largest a at b_i
    that stays in K_{i+1} (one small LP), its z giving the grasp wrenches. Where the equalities' rank differs
    between the points or they cannot be met for every (a, b), or a small LP is not solved (its step limit),
    the problem is left to `grid_lp` (stats['fallback'] says why).

    Args:
        dyn: the PathDynamics of 'lp'.
        mass: kg, μ.
        lam: (λ₀, λ₁) (N,) the tangent of √b.
        extra: (FinePoints, (λ₀, λ₁) (P,)) the check points' rows, or None.

    Returns:
        tuple: b (N,) 1/s² or None (a stage without a controllable state), and the statistics: the grasp
        wrenches f (K, 2, rk) at both ends of every interval (as `grid_lp`'s), the stage LPs solved, their
        simplex steps, cold starts and box growths.
    """
    from coopsim.compiled import api

    s, piece = dyn.path.s, dyn.path.points.piece
    N = len(s)
    st = _stages(s, piece)
    K, d = len(st), s[st + 1] - s[st]
    if "null" not in dyn._fine:
        dyn._fine["null"] = grasp_null_space(dyn)
    ns = dyn._fine["null"]
    rows = None if ns is None else _lp_point_rows(dyn, mass, lam, ns)
    more = None
    if rows is not None and extra is not None:
        fp, flam = extra
        fns = grasp_null_space(fp.dyn)
        more = None if fns is None or fns[1].shape[2] != ns[1].shape[2] else _lp_point_rows(fp.dyn, mass, flam, fns)
        if more is None:
            rows = None
    if rows is None:
        b, stats = grid_lp(dyn, mass, lam, extra)
        return b, stats | {"fallback": "the grasp equalities' rank differs between the points, or they miss some "
                                       "(a, b): grid LP"}
    g, h, e, W, F, null = rows
    m, nz = g.shape[1], W.shape[2]
    dd = d[:, None]
    i0, i1 = st, st + 1
    zero, one = np.zeros((K, 1)), np.ones((K, 1))
    Gs = np.concatenate([g[i0], g[i1] + 2 * dd * h[i1], zero, -2 * dd], 1)
    Hs = np.concatenate([h[i0], h[i1], -one, -one], 1)
    Es = np.concatenate([e[i0], e[i1], zero, zero], 1)
    Ws = np.concatenate([W[i0], W[i1], np.zeros((K, 2, nz))], 1)
    slot = np.broadcast_to(np.concatenate([np.zeros(m, int), np.ones(m, int), [-1, -1]]), Gs.shape)
    who = np.repeat(np.arange(K), Gs.shape[1])
    flat = [Gs.ravel(), Hs.ravel(), Es.ravel(), slot.ravel(), Ws.reshape(-1, nz)]
    nslot = np.full(K, 2)
    if more is not None:
        gf, hf, ef, Wf, _, _ = more
        k = fp.stage
        order = np.argsort(k, kind="stable")
        local = np.empty(len(k), int)
        local[order] = np.arange(len(k)) - np.searchsorted(k[order], k[order], side="left")
        w = (2 * d[k] * fp.sigma)[:, None]
        xs = [gf + w * hf, hf, ef, np.broadcast_to((2 + local)[:, None], gf.shape), Wf]
        flat = [np.concatenate([x, y.reshape(-1, nz) if n == 4 else y.ravel()])
                for n, (x, y) in enumerate(zip(flat, xs))]
        who = np.concatenate([who, np.repeat(k, m)])
        nslot += np.bincount(k, minlength=K)
    order = np.argsort(who, kind="stable")
    flat = [x[order] for x in flat]
    off = np.concatenate([[0], np.cumsum(np.bincount(who, minlength=K))])
    end_at = (piece[st + 1] != piece[np.minimum(st + 2, N - 1)]) | (st + 1 == N - 1)
    start_at = (st == 0) | (piece[np.maximum(st - 1, 0)] != piece[st])
    motor = np.concatenate([e[i0, :-1], e[i1, :-1]], 1)
    tol = 1e-12 * np.maximum(np.max(np.abs(motor), axis=1, initial=0.0), 1e-300)
    dmin = max(float(np.min(d)), 1e-300)
    lam1 = lam[1][lam[1] > 0]
    sb = float(np.max((0.5 / lam1) ** 2)) if lam1.size else 1.0              # b̄'s peak (the tangent's point)
    fs = float(np.max(np.abs(F[0]) + sb * np.abs(F[2]) + sb / dmin * np.abs(F[1]), initial=0.0))
    first = np.array([LP_BOX * sb / dmin, LP_BOX * sb, LP_BOX * max(fs, 1.0)])
    top = np.array([BIG / dmin, BIG / dmin ** 2, BIG * max(fs, 1.0)])
    caps = np.broadcast_to(np.minimum(first, top), (K, 3))
    status, b, a, z, count = api.lp_reachability_pass(*flat, off, nslot, d, tol, caps, top, st, end_at, start_at, N)
    counts = dict(zip(("stage_lps", "simplex_steps", "cold_starts", "box_growths"), (int(x) for x in count)))
    if status == 1:
        return None, counts
    if status != 0:
        b, stats = grid_lp(dyn, mass, lam, extra)
        return b, stats | {"fallback": f"compiled stage LP {api.LP_STATUS[status]}: grid LP"}
    for p in np.unique(piece):
        b[np.flatnonzero(piece == p)[[0, -1]]] = 0.0
    f = np.empty((K, 2, null.shape[1]))
    for side, pt in ((0, i0), (1, i1)):
        f[:, side] = F[0, pt] + a[:, None] * F[1, pt] + b[pt, None] * F[2, pt] + np.einsum("kiz,kz->ki", null[pt],
                                                                                            z[:, side])
    return b, counts | {"f": f}


# ------------------------------------------------------------------------------------------------
# Solving: the linearisation loop, the minimum time, the maximum payload
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Retiming:
    """The time-optimal law of one carried mass along a path.

    Attributes:
        mass: kg, μ.
        law: the TimeLaw (None: no motion carries μ).
        feasible: a motion exists.
        converged: the linearisation converged (max |Δb| ≤ tol·max b).
        iterations: the linearisations solved (all rounds).
        solver: 'reachability' or 'grid_lp'.
        f: (K, 2, rk) [N; N·m] the LP bound's grasp wrenches at both ends of every interval, or None.
        stats: the last solve's statistics (grid_lp's; the LP bound's reachability pass: its counts) or {}.
        refine: the rows between the grid points (`retime`), or None (no check points): rounds (solves
            after the first), rows (int (R,), the check points whose rows the law meets, indices into
            `PathDynamics.fine_points`), intervals (how many intervals carry them), max_excess (the
            largest excess over a line or a no-load speed at any check point, relative), s (its point),
            within (max_excess ≤ REFINE_TOL).
    """

    mass: float
    law: TimeLaw | None
    feasible: bool
    converged: bool
    iterations: int
    solver: str
    f: np.ndarray | None = None
    stats: dict | None = None
    refine: dict | None = None

    @property
    def duration(self) -> float:
        """s, the minimum time (inf when infeasible)."""
        return self.law.duration if self.feasible else np.inf


def retime(dyn: PathDynamics, mass: float, solver: str | None = None, tol: float = 1e-7, max_iter: int | None = None,
           start: np.ndarray | None = None, refine: bool = True, rows: np.ndarray | None = None) -> Retiming:
    """The minimum-time law of carried mass μ along the path, the motor lines exact (see the module), at the
    grid points and (`refine`) at the check points between them.

    The rows are linearised at b̄ (first without the velocity term, or at `start`; where the rows
    linearised there have no solution, at b̄/4, up to SHRINKS times), solved, and
    linearised again at the solution until max |b − b̄| ≤ tol·max b; `check_time_law` then measures
    the exact lines. With check points (`PathDynamics.fine_points`) and `refine`, the law is then
    checked exactly at every check point (`fine_excess`); every check point of an interval holding one
    that exceeds by more than REFINE_TOL adds its rows to that interval (b linear, a constant: the
    point's torques are linear in the interval's unknowns, its velocity term by the tangent at b̄ there)
    and the law is solved again from the last, up to MAX_REFINE rounds.

    Args:
        dyn: the PathDynamics.
        mass: kg, μ.
        solver: 'reachability' or 'grid_lp'; None: `default_solver`.
        tol: the relative change of b that ends the loop (the tangent's error at the solution is of its
            square: 1e-7 leaves ~1e-15 of the velocity term).
        max_iter: the most linearisations per round; None: MAX_LINEARISATIONS.
        start: (N,) 1/s², b̄ to linearise at first; None: the law without velocity terms.
        refine: add the rows of the check points where the law exceeds (no effect without check points).
        rows: int (R,), check points whose rows are there from the first solve (a previous law's
            `refine['rows']`); None: none.

    Returns:
        Retiming (infeasible when no motion carries μ).
    """
    solver = solver or default_solver(dyn)
    fp = dyn.fine_points() if refine else None
    rows = np.zeros(0, dtype=int) if rows is None or fp is None else np.unique(np.asarray(rows, dtype=int))
    its = 0
    for rounds in range(MAX_REFINE + 1):
        r = _min_time(dyn, mass, solver, tol, max_iter, start, None if fp is None or not rows.size else fp.subset(rows))
        its += r.iterations
        if fp is None or not r.feasible:
            return replace(r, iterations=its)
        ex = fine_excess(fp, r)
        bad = np.isin(fp.stage, np.unique(fp.stage[ex > REFINE_TOL]))
        add = np.setdiff1d(np.flatnonzero(bad), rows)
        if not add.size or rounds == MAX_REFINE or not r.converged:
            break
        rows, start = np.union1d(rows, add), r.law.b
    w = int(np.argmax(ex))
    info = {"rounds": rounds, "rows": rows, "intervals": int(np.unique(fp.stage[rows]).size),
            "max_excess": float(ex[w]), "s": float(fp.dyn.path.s[w]), "within": bool(ex[w] <= REFINE_TOL)}
    return replace(r, iterations=its, refine=info)


def default_solver(dyn: PathDynamics) -> str:
    """'reachability' for a linear resolution (compiled, linear in the grid points); for the LP bound
    'reachability' (`lp_reachability`) where its largest stage LP has at most LP_STAGE_MAX unknowns —
    2 + nz·(2 + the check points of one interval), nz the grasp wrenches' free coordinates a point
    (`grasp_null_space`): the dense simplex's steps cost O(n³) in them, so on larger stages (the spatial
    pairs: nz = 6, 68 unknowns) the sparse grid LP is the faster — else 'grid_lp'.

    Args:
        dyn: the PathDynamics.

    Returns:
        str: the solver's name.
    """
    if dyn.method != LP_BOUND:
        return "reachability"
    if "null" not in dyn._fine:
        dyn._fine["null"] = grasp_null_space(dyn)
    if dyn._fine["null"] is None:
        return "grid_lp"
    fp = dyn.fine_points()
    inside = 0 if fp is None else int(np.max(np.bincount(fp.stage), initial=0))
    return "reachability" if 2 + dyn._fine["null"][1].shape[2] * (2 + inside) <= LP_STAGE_MAX else "grid_lp"


def certificate(dyn: PathDynamics, r: Retiming) -> dict:
    """The grid LP's dual certificate (`grid_lp`) of the rows linearised at a law (its check points' rows
    too), with how far the grid LP's ṡ² lies from the law's (law_gap, relative to its peak: ~0 when the law
    is the LP's optimum, whichever solver found it).

    Args:
        dyn: the PathDynamics.
        r: a feasible Retiming.

    Returns:
        dict: `grid_lp`'s certificate (primal, dual, gap, sign_ok, binding_rows, largest) and law_gap;
        {} when the grid LP has no optimum there.
    """
    b = r.law.b
    scale = max(float(np.max(b)), 1e-300)
    extra = None
    fp = dyn.fine_points() if r.refine is not None and r.refine["rows"].size else None
    if fp is not None:
        sub = fp.subset(r.refine["rows"])
        k = _stages(r.law.s, r.law.piece)[sub.stage]
        extra = (sub, _tangent((1 - sub.sigma) * b[k] + sub.sigma * b[k + 1], scale))
    new, stats = grid_lp(dyn, r.mass, _tangent(b, scale), extra)
    if new is None:
        return {}
    return stats["certificate"] | {"law_gap": float(np.max(np.abs(new - b)) / scale)}


def _min_time(dyn: PathDynamics, mass: float, solver: str, tol: float, max_iter: int | None,
              start: np.ndarray | None, extra: FinePoints | None) -> Retiming:
    """The linearisation loop of `retime` with the rows of the check points `extra` (None: none)."""
    max_iter = MAX_LINEARISATIONS if max_iter is None else max_iter
    s, piece = dyn.path.s, dyn.path.points.piece
    N = len(s)
    st = _stages(s, piece)

    def solve(b_ref, scale):
        lam = (np.zeros(N), np.zeros(N)) if b_ref is None else _tangent(b_ref, scale)
        more = None
        if extra is not None:
            k, sig = st[extra.stage], extra.sigma
            fb = None if b_ref is None else (1 - sig) * b_ref[k] + sig * b_ref[k + 1]
            more = (extra, (np.zeros(len(sig)), np.zeros(len(sig))) if fb is None else _tangent(fb, scale))
        if solver == "grid_lp":
            return grid_lp(dyn, mass, lam, more)
        if dyn.method == LP_BOUND:
            return lp_reachability(dyn, mass, lam, more)
        return reachability(dyn, mass, lam, more), {}

    if start is None:
        b, stats = solve(None, 1.0)
        if b is None and not np.any(dyn.slope):
            return Retiming(mass, None, False, True, 1, solver, stats=stats)
        b = np.zeros(N) if b is None else b
    else:
        b, stats = start, {}
    scale = max(float(np.max(b)), 1e-300)
    shrunk = 0
    for it in range(1, max_iter + 1):
        new, stats = solve(b, scale)
        if new is None and shrunk < SHRINKS and np.any(b > 0):
            b, shrunk = b / 4.0, shrunk + 1        # a tangent far above the feasible ṡ² overestimates θ̇ at rest
            continue
        if new is None:
            return Retiming(mass, None, False, True, it, solver, stats=stats)
        change = float(np.max(np.abs(new - b)))
        b, scale = new, max(float(np.max(new)), 1e-300)
        if change <= tol * scale:
            return Retiming(mass, time_of(s, piece, b), True, True, it, solver, stats.pop("f", None), stats)
    return Retiming(mass, time_of(s, piece, b), True, False, max_iter, solver, stats.pop("f", None),
                    stats | {"relative_change": change / scale})


def fine_excess(fp: FinePoints, r: Retiming) -> np.ndarray:
    """The excess of a law at the check points (P,): the largest over the joints of the excess over eq. 36
    (relative to τ_s; the LP bound: with the best grasp wrenches at each point, `best_excess`) and of
    |θ̇|/ω_s − 1 (≤ 0: within).

    Args:
        fp: the FinePoints.
        r: the feasible Retiming on their grid.

    Returns:
        np.ndarray: (P,).
    """
    law = r.law
    i = _stages(law.s, law.piece)[fp.stage]
    a = law.a[i]
    b = np.maximum((1 - fp.sigma) * law.b[i] + fp.sigma * law.b[i + 1], 0.0)
    if fp.dyn.method == LP_BOUND:
        ex = best_excess(fp.dyn, r.mass, a, b)[0]
    else:
        ex = np.max(line_excess(fp.dyn, r.mass, a, b)[0], axis=1, initial=-np.inf)
    return np.maximum(ex, _speed_ratio(fp.dyn, b) - 1.0)


def static_capacity(dyn: PathDynamics) -> float:
    """kg, the largest μ the motors hold at rest at every path point (the limit of an ever slower motion).

    Args:
        dyn: the PathDynamics.

    Returns:
        float: kg (−inf: not even μ = 0 is held; inf: unbounded).
    """
    jp = dyn.path
    if dyn.method != LP_BOUND:
        j = dyn.active
        lo = np.broadcast_to(-dyn.stall, jp.q.shape)
        up, dn = cap.mass_limits(dyn.tau[0, 0][:, j], dyn.tau[1, 0][:, j], lo[:, j], -lo[:, j])
        mass, lower, ok = cap.mass_interval(up, dn)
        return mass if ok else -np.inf
    r = retime_static_lp(dyn)
    return r


def retime_static_lp(dyn: PathDynamics) -> float:
    """kg, the LP bound's static capacity: `coopsim.inverse.capacity.lp_capacity` of the path at rest.

    Args:
        dyn: the PathDynamics of 'lp'.

    Returns:
        float: kg (−inf: infeasible).
    """
    jp = dyn.path
    n = jp.q.shape[1]
    prob = _static_problem(dyn)
    motors = Motors(dyn.stall, np.full(n, np.inf), np.ones(n), ~dyn.active)
    c = cap.lp_capacity(prob, motors, ~dyn.active, "payload")
    return c.mass if c.feasible else -np.inf


def _static_problem(dyn: PathDynamics):
    """A stand-in InverseProblem at rest along the path with y₀ = the nominal wrench, y_payload = per kg."""
    jp, N = dyn.path, len(dyn.path.s)
    z = np.zeros_like(jp.q)
    k = dyn.y.shape[3]
    r = dyn.A.shape[2] // k
    return InverseProblem(jp.s, jp.q, z, z, dyn.tau[0, 0], dyn.JT, dyn.A, dyn.y[0, 0], dyn.y[1, 0], dyn.y[1, 0],
                          np.zeros((N, r, 6, 6)), np.zeros((N, 3)), np.zeros((N, 3, 3)), np.zeros((N, 6)),
                          np.zeros((N, 6)), np.zeros((N, r, 3)), np.zeros((k, 6)), None, np.zeros(3), 1.0,
                          np.eye(3), np.zeros(3), np.zeros((r, 3)))


def max_payload(dyn: PathDynamics, duration: float, solver: str | None = None, rtol: float = 1e-10,
                field: str = "--duration", names: list[str] | None = None, refine: bool = True,
                at_least: float | None = None, only_above: bool = False):
    """The heaviest carried mass whose minimum time is within `duration`, and its Retiming.

    The minimum time grows with μ; the bracket [nominal mass, μ_hi] is grown (×4 from twice the nominal
    mass or 1 kg, never past the static capacity) until T(μ_hi) > duration, then Brent's method on
    T(μ) − duration (an infeasible μ counts as infinitely slow). The heaviest μ found feasible is kept.
    With `refine` every solve starts with the rows of every check point any earlier solve added
    (`retime`), so that later solves rarely need a second round. With `at_least` (a mass known to be
    carried within the duration, e.g. the refined law's heaviest when the grid's rows alone are asked) the
    bracket starts there instead, its width grown from NEAR × μ by ×16: a few solves where the answer
    lies close above it. With `only_above` a path that does not carry `at_least` within the duration (nor,
    then, any heavier load: the minimum time grows with the mass) gives None after that one solve, where
    the search would start from the nominal load: whether a path beats another's payload.

    Args:
        dyn: the PathDynamics.
        duration: s, T_max.
        solver: as `retime`.
        rtol: the relative tolerance on μ.
        field: the input that set the duration, for the message when even the nominal load is too slow.
        names: (n,) the joints' labels, for the message when the motors cannot hold the nominal load.
        refine: as `retime` (the rows between the grid points).
        at_least: kg, a mass carried within the duration (the search starts from it; one not carried
            there is ignored), or None.
        only_above: return None where `at_least` is not carried within the duration (or the motors cannot
            hold the nominal load at rest).

    Returns:
        tuple | None: (mass kg, Retiming at it, the minimum-time solves made); None only with `only_above`.

    Raises:
        RetimeError: the motors cannot hold the nominal load at rest, or no motion carries it within
            the duration.
    """
    lo = dyn.nominal_mass
    top = static_capacity(dyn)
    if not top > lo:
        if only_above:
            return None
        raise RetimeError(hold_failure(dyn, names))
    count = [0]
    first = None
    if at_least is not None and (lo < at_least < top or only_above):
        count[0] += 1
        first = retime(dyn, float(at_least), solver, refine=refine)
        if not first.feasible or first.duration > duration:
            first = None
    if first is None and only_above:
        return None
    near = first is not None
    if first is None:
        count[0] += 1
        first = retime(dyn, lo, solver, refine=refine)
    if not first.feasible or first.duration > duration:
        raise RetimeError(f"{field}: no motion carries the bare object along the path within {duration:g} s "
                          f"(its minimum time is {first.duration:.6g} s)")
    best = {"r": first, "rows": None if first.refine is None else first.refine["rows"]}

    def excess(mu):
        count[0] += 1
        r = retime(dyn, mu, solver, start=best["r"].law.b, refine=refine, rows=best["rows"])
        if r.refine is not None:
            best["rows"] = np.union1d(best["rows"], r.refine["rows"])
        if r.feasible and r.duration <= duration and mu >= best["r"].mass:
            best["r"] = r
        return (r.duration if r.feasible else np.inf) - duration

    cap_top = top * (1 - 1e-12) if np.isfinite(top) else np.inf
    base = first.mass
    hi = min(base * (1 + NEAR) if near else max(2 * lo, 1.0), cap_top)
    while excess(hi) <= 0:
        if hi >= cap_top:
            return best["r"].mass, best["r"], count[0]
        hi = min(base + 16 * (hi - base) if near else 4 * hi, cap_top)
    brentq(lambda mu: min(excess(mu), 1e300), best["r"].mass, hi, xtol=rtol * hi, rtol=4 * np.finfo(float).eps)
    return best["r"].mass, best["r"], count[0]


def hold_failure(dyn: PathDynamics, names: list[str] | None = None) -> str:
    """The one-line reason the motors cannot hold the nominal load at rest, naming the motor and where.

    Args:
        dyn: the PathDynamics.
        names: (n,) the joints' labels; None: stacked indices.

    Returns:
        str: 'motors.stall_torque: arm 1 joint 2 cannot hold the bare object at rest at s=0.3 (…)'.
    """
    head = "motors.stall_torque: the motors cannot hold the bare object at rest along the path"
    if dyn.method == LP_BOUND:
        return head + " with any distribution of the grasp wrenches"
    tau = (dyn.tau[0, 0] + dyn.nominal_mass * dyn.tau[1, 0])
    ratio = np.where(dyn.active, np.abs(tau) / dyn.stall, 0.0)
    i, j = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
    who = names[j] if names is not None else f"joint {j}"
    return (f"motors.stall_torque: {who} cannot hold the bare object at rest at s={dyn.path.s[i]:.4g} "
            f"({dyn.method}: {abs(tau[i, j]):.4g} of its stall torque {dyn.stall[j]:.4g})")


# ------------------------------------------------------------------------------------------------
# The exact check of eq. 36
# ------------------------------------------------------------------------------------------------

def line_excess(dyn: PathDynamics, mass: float, a: np.ndarray, b: np.ndarray, f: np.ndarray | None = None):
    """max(τ − τ_max(θ̇), τ_min(θ̇) − τ)/τ_s (N, n_a) at the points with (a, b), θ̇ = θ′√b exactly (eq. 36).

    Args:
        dyn: the PathDynamics (N points).
        mass: kg, μ.
        a: (N,) 1/s², s̈.
        b: (N,) 1/s², ṡ².
        f: (N, rk) the grasp wrenches ('lp').

    Returns:
        tuple: the excess relative to τ_s (N, n_a) (≤ 0: within), and the joints (n_a,) int.
    """
    j = np.flatnonzero(dyn.active & np.isfinite(dyn.stall))
    tau = dyn.torques(mass, a, b, f)[:, j]
    qd = dyn.path.d1[:, j] * np.sqrt(np.maximum(b, 0.0))[:, None]
    drop = dyn.slope[j] * qd
    hi, lo = dyn.stall[j] - drop, -dyn.stall[j] - drop
    return np.maximum(tau - hi, lo - tau) / dyn.stall[j], j


def best_excess(dyn: PathDynamics, mass: float, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The LP bound's excess at points with (a, b): per point the least max relative excess over any
    grasp wrenches f with A f = y(a, b, μ) (passive torques 0), one small LP per point.

    Args:
        dyn: the PathDynamics of 'lp' (N points).
        mass: kg, μ.
        a: (N,) 1/s², s̈.
        b: (N,) 1/s², ṡ².

    Returns:
        tuple: (N,) the least excess relative to τ_s (≤ 0: some distribution keeps every line), and (N, rk)
        the grasp wrenches reaching it.

    Raises:
        RetimeError: HiGHS fails on a point.
    """
    rk = dyn.JT.shape[2]
    ta = dyn.torques(mass, a, b)
    drop = dyn.slope * dyn.path.d1 * np.sqrt(np.maximum(b, 0.0))[:, None]
    lo, hi = -dyn.stall - drop, dyn.stall - drop
    Y = dyn.y[0] + mass * dyn.y[1]
    y = Y[0] + a[:, None] * Y[1] + b[:, None] * Y[2]
    lp = cap.least_excess(ta, dyn.JT, dyn.A, y, lo, hi, dyn.stall, ~dyn.active)
    if np.any(lp.status != 0):
        i = int(np.flatnonzero(lp.status != 0)[0])
        raise RetimeError(f"lp: HiGHS failed at s={dyn.path.s[i]:.6g}: {lp.messages[i]}")
    return lp.x[:, -1], lp.x[:, :rk]


def check_time_law(dyn: PathDynamics, r: Retiming) -> dict:
    """The time law against eq. 36 exactly at every grid point, on both sides (each interval's a).

    Args:
        dyn: the PathDynamics the law was solved on.
        r: the Retiming (feasible).

    Returns:
        dict: max_excess (relative to τ_s; ≤ 0 within), the worst point's index, s and joint, and
        max_speed_excess (`speed_excess`).
    """
    law = r.law
    st = _stages(law.s, law.piece)
    worst = -np.inf, None, None
    for side, pt in ((0, st), (1, st + 1)):
        a = np.zeros(len(law.s))
        a[pt] = law.a[st]
        f = None
        if r.f is not None:
            f = np.zeros((len(law.s), r.f.shape[2]))
            f[pt] = r.f[:, side]
        ex, j = line_excess(dyn, r.mass, a, law.b, f)
        ex = ex[pt]
        if ex.size and ex.max() > worst[0]:
            i, jj = np.unravel_index(int(np.argmax(ex)), ex.shape)
            worst = float(ex[i, jj]), int(pt[i]), int(j[jj])
    return {"max_excess": worst[0], "index": worst[1], "s": None if worst[1] is None else float(law.s[worst[1]]),
            "joint": worst[2], "max_speed_excess": speed_excess(dyn, law.b)}


def speed_excess(dyn: PathDynamics, b: np.ndarray) -> float:
    """max |θ̇|/ω_s − 1 over the points and the joints with a finite no-load speed (≤ 0: within; −1: none).

    Args:
        dyn: the PathDynamics (N points).
        b: (N,) 1/s², ṡ².

    Returns:
        float: the largest relative excess of a joint's speed over its no-load speed.
    """
    return float(np.max(_speed_ratio(dyn, b), initial=0.0)) - 1.0


def _speed_ratio(dyn: PathDynamics, b: np.ndarray) -> np.ndarray:
    """max over the joints with a finite no-load speed of |θ̇|/ω_s (N,) (0: none)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        omega = np.where(dyn.slope > 0, dyn.stall / np.where(dyn.slope > 0, dyn.slope, 1.0), np.inf)
        ratio = np.abs(dyn.path.d1) * np.sqrt(np.maximum(b, 0.0))[:, None] / omega
    return np.max(np.where(dyn.active & np.isfinite(omega), ratio, 0.0), axis=1, initial=0.0)


def point_wrenches(r: Retiming) -> np.ndarray | None:
    """The LP bound's grasp wrenches (N, rk) at the grid points, as `TimeLaw.point_accel` takes s̈: each
    interval's start wrenches at its start, at a piece's last point those of the interval ending there.

    Args:
        r: the Retiming (its f; None: not the LP bound).

    Returns:
        np.ndarray | None: (N, rk) [N; N·m], or None.
    """
    if r.f is None:
        return None
    law = r.law
    st = _stages(law.s, law.piece)
    f = np.zeros((len(law.s), r.f.shape[2]))
    f[st] = r.f[:, 0]
    ends = np.flatnonzero(~np.isin(st + 1, st))                   # intervals ending a piece
    f[st[ends] + 1] = r.f[ends, 1]
    return f


def saturating(dyn: PathDynamics, r: Retiming, tol: float = 1e-7) -> dict:
    """The motor closest to its line at each grid point (`TimeLaw.point_accel`), and the critical point of
    the law.

    Args:
        dyn: the PathDynamics.
        r: the feasible Retiming.
        tol: relative excess above −tol counts as on the line.

    Returns:
        dict: joint (N,) int (the stacked joint nearest its line per point), excess (N,) relative to τ_s,
        on_line (N,) bool, and critical: the point of largest excess (index, s, joint).
    """
    law = r.law
    ex, j = line_excess(dyn, r.mass, law.point_accel(), law.b, point_wrenches(r))
    k = np.argmax(ex, axis=1)
    e = ex[np.arange(len(ex)), k]
    i = int(np.argmax(e))
    return {"joint": j[k], "excess": e, "on_line": e >= -tol,
            "critical": {"index": i, "s": float(law.s[i]), "joint": int(j[k[i]])}}
