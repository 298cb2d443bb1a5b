"""Minimum-energy load capacity for one weight vector, compiled: the objective that
`coopsim.inverse.capacity.optimise_weights` evaluates hundreds of times (paper eqs. 33–36).

From the weight-independent setup of the minimum-energy problem (`coopsim.inverse.distributions.MinEnergySetup`: the
torques u of a particular solution and D = Jᵀ Z over the null space of the constraints, for the net
object wrenches of zero payload and of one unit of payload), per sample i

    H = Dᵀ Q D,  g = Dᵀ Q u,  H z = −g (Cholesky),  τ = u + D z        (two right-hand sides),

then τ(μ) = a + μ b with a = τ₀, b = τ₁ − τ₀, and the mass interval of lo ≤ τ(μ) ≤ hi over the active
joints — `coopsim.inverse.distributions.mass_limits` and `coopsim.inverse.capacity.mass_interval`, sample by sample. Where C lost rank or H
is not certified well-conditioned — λ_min/λ_max ≥ 1/(trace(H)·trace(H⁻¹)) > rank_tol, the forward
model's rank rule with a bound within a factor d² of the eigenvalues (`coopsim.inverse.distributions._spd_solve`
decides by eigenvalues where its bound is not enough) — the result is marked uncertain and the caller
takes the NumPy path, which handles rank loss.
"""

import numpy as np

from coopsim.compiled.linalg import cholesky, cholesky_solve, trace_of_inverse
from coopsim.compiled.toolchain.jit import entry


@entry
def min_energy_mass_interval(D, u, Q, lo, hi, act, regular, rank_tol):
    """The payload-mass interval of the minimum-energy torques for the energy weights Q, over all samples.

    Per sample the two minimum-energy torque vectors τ₀, τ₁ (for the carried mass μ = 0 and μ = 1 kg;
    module docstring) give τ(μ) = τ₀ + μ (τ₁ − τ₀), and each active joint's limits lo ≤ τ(μ) ≤ hi an
    interval of μ: mass is the smallest upper limit, lower the largest lower limit. It stops at the first
    sample that needs the rank-deficient path (C not of full row rank, H not positive definite or not
    certified well-conditioned), and returns certain False.

    Args:
        D: (n, d, N) D = Jᵀ Z per sample (n joints, d null-space directions, N samples; samples last):
            joint torques per unit null-space coordinate (`MinEnergySetup.D`).
        u: (n, 2, N) N·m, the torques of the particular solutions for the two net wrenches y₀ and
            y₀ + y₁ (μ = 0 and 1 kg) (`MinEnergySetup.u`).
        Q: (n,) energy weights, the diagonal of Q (0 on passive joints).
        lo, hi: (N, n) N·m, lower and upper torque limits per sample.
        act: (n,) bool, the joints whose limits count.
        regular: (N,) bool, C of full row rank at the sample.
        rank_tol: the forward model's rank tolerance (λ_min/λ_max), applied to H's certified bound.

    Returns:
        tuple[float, float, bool]: (mass kg, lower kg, certain): mass the smallest upper limit (+inf:
        none), lower max(0, the largest lower limit); certain False when some sample needs the
        rank-deficient path (mass and lower are then meaningless).
    """
    n, d, N = D.shape
    H = np.empty((d, d))
    z = np.empty((d, 2))
    x = np.empty(d)
    mass, lower = np.inf, 0.0
    for i in range(N):
        if not regular[i]:
            return mass, lower, False
        trace = 0.0
        for a in range(d):
            for b in range(a + 1):
                acc = 0.0
                for j in range(n):
                    acc += Q[j] * D[j, a, i] * D[j, b, i]
                H[a, b] = acc
            trace += H[a, a]
            for s in range(2):
                acc = 0.0
                for j in range(n):
                    acc -= Q[j] * D[j, a, i] * u[j, s, i]
                z[a, s] = acc
        if not (cholesky(H, d) and rank_tol * trace * trace_of_inverse(H, d, x) < 1.0):
            return mass, lower, False
        for s in range(2):                       # L Lᵀ z = −g
            for a in range(d):
                x[a] = z[a, s]
            cholesky_solve(H, d, x)
            for a in range(d):
                z[a, s] = x[a]
        for j in range(n):
            if not act[j]:
                continue
            t0, t1 = u[j, 0, i], u[j, 1, i]
            for a in range(d):
                t0 += D[j, a, i] * z[a, 0]
                t1 += D[j, a, i] * z[a, 1]
            slope = t1 - t0
            if slope > 0.0:
                up, dn = (hi[i, j] - t0) / slope, (lo[i, j] - t0) / slope
            elif slope < 0.0:
                up, dn = (lo[i, j] - t0) / slope, (hi[i, j] - t0) / slope
            else:
                up = -np.inf if t0 < lo[i, j] or t0 > hi[i, j] else np.inf
                dn = -np.inf
            if up < mass:                        # (nan: no limit)
                mass = up
            if dn > lower:
                lower = dn
    return mass, lower, True
