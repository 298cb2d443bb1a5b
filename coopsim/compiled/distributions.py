"""The linear redundancy resolutions of the inverse dynamics over all samples in one compiled pass
(paper eqs. 28–36): each sample's grasp wrenches and torques for several net object wrenches, both
internal wrenches and the load-capacity ratio test against the motor lines.

The same formulas as the NumPy reference `coopsim.inverse.distributions` (rows S, k per grasp, r arms,
m = rk unknowns, n joints), per sample:

    'paper'         f_m = S W_m⁻¹ Sᵀ y / r,  W_m⁻¹ = 2I − W_m;
    'nonsqueezing'  f = M* Aᵀ K⁻¹ y,  K = A M* Aᵀ (Cholesky),  M* = blockdiag(S diag(m_i* I₃, R_o J_i* R_oᵀ) Sᵀ);
    'min_energy'    f = f_p + Z z,  f_p = C⁺ b,  b = [y; −P τ_arms],  D = Jᵀ Z,  (Dᵀ Q D) z = −Dᵀ Q (τ_arms + Jᵀ f_p),

with C⁺ = Q₁ R⁻ᵀ and Z = Q₂ from a Householder QR of Cᵀ = Q [R; 0] (C = [A; P Jᵀ], factored once per
sample for every net wrench; the reference takes an SVD, and the minimiser f is the same); τ = τ_arms + Jᵀ f.
Where Jᵀ is block-diagonal per arm (each joint moves one grasp), no joint is passive and the arms' Hessians
H_a = J_a Q_a J_aᵀ are well-conditioned (`_energy_blocks`), the same minimiser is taken arm by arm in O(r)
per sample instead of the null-space form's O(r³): f_a = H_a⁻¹ (A_aᵀ λ − J_a Q_a τ_arms,a) with
(Σ_a A_a H_a⁻¹ A_aᵀ) λ = y + Σ_a A_a H_a⁻¹ J_a Q_a τ_arms,a; and every Jᵀ f sums each row's nonzero span only.
Internal wrenches at C (`coopsim.inverse.distributions.internal_operator`), projected on the modelled
rows: paper F_I^m = SᵀS (W_m Sᵀ f_m − Σ_j W_j Sᵀ f_j / r), non-squeezing F_I^m = SᵀS W_m Sᵀ [f − M* Aᵀ K⁻¹ A f]_m.
The ratio test is `coopsim.inverse.distributions.mass_limits` of τ(μ) = a + μ b, a = τ(y₀), b = τ(y₀ + y₁) − a.

A sample whose minimum-energy equations the pass cannot certify well-conditioned (C Cᵀ = RᵀR or
H = Dᵀ Q D with rank_tol·trace(G)·trace(G⁻¹) ≥ 1, the bound of `coopsim.compiled.capacity`: it holds at every
sample where the forward model's rank rule finds the rank lost, and at a few ill-conditioned ones) or
whose K is not positive definite is flagged; the caller takes the NumPy path there.
"""

import numpy as np

from coopsim.compiled.linalg import cholesky, cholesky_solve, trace_of_inverse
from coopsim.compiled.toolchain.jit import entry, kernel

PAPER, NONSQUEEZING, MIN_ENERGY = 0, 1, 2     # the methods' rows in the pass's outputs
ARM_CONDITION = 3e3     # the arm-by-arm minimum energy only where every trace(H_a)·trace(H_a⁻¹) <= this


@kernel
def _row_spans(JT, k, span):
    """span (n, 2) ← per row j of Jᵀ the columns [first, last + 1) of its nonzero entries ([0, 0): none);
    True when every row's lie in one arm's k columns (Jᵀ block-diagonal per arm)."""
    n, m = JT.shape
    blocked = True
    for j in range(n):
        span[j, 0], span[j, 1] = 0, 0
        for a in range(m):
            if JT[j, a] != 0.0:
                if span[j, 1] == 0:
                    span[j, 0] = a
                span[j, 1] = a + 1
        if span[j, 1] > 0 and span[j, 0] // k != (span[j, 1] - 1) // k:
            blocked = False
    return blocked


@kernel
def _torques(JT, ta, f, tau, span):
    """tau ← τ_arms + Jᵀ f (one sample: JT (n, m), ta (n,), f (m,); the sum over each row's span of
    nonzero entries, `_row_spans`)."""
    for j in range(JT.shape[0]):
        acc = 0.0
        for a in range(span[j, 0], span[j, 1]):
            acc += JT[j, a] * f[a]
        tau[j] = ta[j] + acc


@kernel
def _paper(W, S, y, f, v6, w6):
    """f ← the paper's W⁺ distribution of y (one sample: W (r, 6, 6), y (k,), f (rk,))."""
    r, k = W.shape[0], S.shape[0]
    for j in range(6):
        acc = 0.0
        for q in range(k):
            acc += y[q] * S[q, j]
        v6[j] = acc
    for a in range(r):
        for i in range(6):
            acc = 0.0
            for j in range(6):
                acc += ((2.0 if i == j else 0.0) - W[a, i, j]) * v6[j]
            w6[i] = acc
        for q in range(k):
            acc = 0.0
            for j in range(6):
                acc += S[q, j] * w6[j]
            f[a * k + q] = acc / r


@kernel
def _nonsqueezing_factor(A, R, S, vm, vJ, MAt, K, B, T):
    """MAt ← M* Aᵀ (m, k) and K ← A M* Aᵀ (k, k), Cholesky-factored in place; False when K is not
    positive definite (one sample: A (k, m), R (3, 3) the object rotation; B (6, 6), T (k, 6) work)."""
    k = S.shape[0]
    r = vm.shape[0]
    for a in range(r):
        for i in range(6):
            for j in range(6):
                B[i, j] = 0.0
        for i in range(3):
            B[i, i] = vm[a]
        for i in range(3):                        # R J Rᵀ
            for j in range(3):
                acc = 0.0
                for p in range(3):
                    for q in range(3):
                        acc += R[i, p] * vJ[a, p, q] * R[j, q]
                B[3 + i, 3 + j] = acc
        for i in range(k):                        # T = S B
            for j in range(6):
                acc = 0.0
                for p in range(6):
                    acc += S[i, p] * B[p, j]
                T[i, j] = acc
        for i in range(k):                        # B ← S B Sᵀ (its top-left k × k)
            for q in range(k):
                acc = 0.0
                for p in range(6):
                    acc += T[i, p] * S[q, p]
                B[i, q] = acc
        for i in range(k):                        # MAt block rows = (S B Sᵀ) A_aᵀ
            for c in range(k):
                acc = 0.0
                for q in range(k):
                    acc += B[i, q] * A[c, a * k + q]
                MAt[a * k + i, c] = acc
    m = MAt.shape[0]
    for i in range(k):
        for c in range(k):
            acc = 0.0
            for p in range(m):
                acc += A[i, p] * MAt[p, c]
            K[i, c] = acc
    return cholesky(K, k)


@kernel
def _nonsqueezing(MAt, K, y, f, x):
    """f ← M* Aᵀ K⁻¹ y (one sample; K factored by `_nonsqueezing_factor`; x (k,) work)."""
    m, k = MAt.shape
    for q in range(k):
        x[q] = y[q]
    cholesky_solve(K, k, x)
    for a in range(m):
        acc = 0.0
        for q in range(k):
            acc += MAt[a, q] * x[q]
        f[a] = acc


@kernel
def _energy_factor(JT, Z, Q, rank_tol, D, H, x):
    """D ← Jᵀ Z (n, d) and H ← Dᵀ Q D (d, d), Cholesky-factored in place; False unless H is positive
    definite and certified well-conditioned, rank_tol·trace(H)·trace(H⁻¹) < 1 (x (d,) work)."""
    n, m = JT.shape
    d = Z.shape[1]
    for j in range(n):
        for c in range(d):
            acc = 0.0
            for a in range(m):
                acc += JT[j, a] * Z[a, c]
            D[j, c] = acc
    trace = 0.0
    for a in range(d):
        for b in range(a + 1):
            acc = 0.0
            for j in range(n):
                acc += Q[j] * D[j, a] * D[j, b]
            H[a, b] = acc
        trace += H[a, a]
    if d == 0:
        return True
    return cholesky(H, d) and rank_tol * trace * trace_of_inverse(H, d, x) < 1.0


@kernel
def _constraint_basis(A, JT, pidx, rank_tol, X, V, Qm, L, Cp, Z, x):
    """Cp ← C⁺ = Q₁ R⁻ᵀ (m, c) and Z ← Q₂ (m, d) of C = [A; P Jᵀ] (c = k + #passive rows, m columns) from a
    Householder QR of Cᵀ = Q [R; 0]; False unless c ≤ m and C Cᵀ = RᵀR is certified well-conditioned,
    rank_tol·trace(RᵀR)·trace((RᵀR)⁻¹) < 1 (X, V (m, c), Qm (m, m), L (c, c), x (c,) work)."""
    k, m = A.shape
    c = k + pidx.shape[0]
    if c > m:
        return False
    for a in range(m):
        for q in range(k):
            X[a, q] = A[q, a]
        for p in range(c - k):
            X[a, k + p] = JT[pidx[p], a]
    for j in range(c):                            # Householder: X ← H_j X, v_j in V[j:, j]
        norm = 0.0
        for a in range(j, m):
            norm += X[a, j] * X[a, j]
        norm = np.sqrt(norm)
        alpha = -norm if X[j, j] >= 0.0 else norm
        vv = 0.0
        for a in range(j, m):
            V[a, j] = X[a, j] - (alpha if a == j else 0.0)
            vv += V[a, j] * V[a, j]
        if not vv > 0.0:
            return False
        for q in range(j, c):
            acc = 0.0
            for a in range(j, m):
                acc += V[a, j] * X[a, q]
            acc *= 2.0 / vv
            for a in range(j, m):
                X[a, q] -= acc * V[a, j]
        x[j] = vv
    trace = 0.0
    for i in range(c):                            # L = Rᵀ, R the upper triangle of X
        for j in range(c):
            L[i, j] = X[j, i] if j <= i else 0.0
            trace += L[i, j] * L[i, j]
        if L[i, i] == 0.0:
            return False
    for a in range(m):                            # Qm = H_0 … H_{c-1}
        for q in range(m):
            Qm[a, q] = 1.0 if a == q else 0.0
    for j in range(c - 1, -1, -1):
        vv = x[j]
        for q in range(m):
            acc = 0.0
            for a in range(j, m):
                acc += V[a, j] * Qm[a, q]
            acc *= 2.0 / vv
            for a in range(j, m):
                Qm[a, q] -= acc * V[a, j]
    for a in range(m):                            # Cp[a] = R⁻¹ Q₁[a]ᵀ (back substitution), Z = Q₂
        for q in range(c - 1, -1, -1):
            acc = Qm[a, q]
            for p in range(q + 1, c):
                acc -= L[p, q] * Cp[a, p]
            Cp[a, q] = acc / L[q, q]
        for q in range(m - c):
            Z[a, q] = Qm[a, c + q]
    return rank_tol * trace * trace_of_inverse(L, c, x) < 1.0


@kernel
def _min_energy(JT, ta, Cp, Z, D, H, pidx, Q, y, f, b, u, z, span):
    """f ← f_p + Z z, the minimum-energy distribution of y (one sample; D, H from `_energy_factor`; b (c,),
    u (n,), z (d,) work)."""
    n, m = JT.shape
    k, c, d = y.shape[0], Cp.shape[1], Z.shape[1]
    for q in range(k):
        b[q] = y[q]
    for p in range(c - k):
        b[k + p] = -ta[pidx[p]]
    for a in range(m):
        acc = 0.0
        for q in range(c):
            acc += Cp[a, q] * b[q]
        f[a] = acc
    _torques(JT, ta, f, u, span)
    for a in range(d):
        acc = 0.0
        for j in range(n):
            acc -= D[j, a] * Q[j] * u[j]
        z[a] = acc
    cholesky_solve(H, d, z)
    for a in range(m):
        acc = 0.0
        for q in range(d):
            acc += Z[a, q] * z[q]
        f[a] += acc


@kernel
def _energy_blocks(JT, ta, A, Q, span, rank_tol, Hs, Gs, hs, SK, x):
    """The minimum-energy equations arm by arm when Jᵀ is block-diagonal (`_row_spans`) and no joint is
    passive: H_a = Σ_j Q_j J_j J_jᵀ over arm a's joints (k × k, Cholesky-factored in Hs[a]), hs[a] ←
    H_a⁻¹ Σ_j Q_j J_j τ_arms,j, Gs[a] ← H_a⁻¹ A_aᵀ and SK ← Σ_a A_a H_a⁻¹ A_aᵀ (Cholesky). False unless
    every H_a and SK is positive definite, A Aᵀ is certified well-conditioned,
    rank_tol·trace(A Aᵀ)·trace((A Aᵀ)⁻¹) < 1, and so is H = blockdiag(H_a):
    rank_tol·max_a trace(H_a)·max_a trace(H_a⁻¹) < 1 (it bounds the condition of H, hence of the reduced
    Hessian Zᵀ H Z of the null-space form: its eigenvalues lie in H's range), and every arm's
    trace(H_a)·trace(H_a⁻¹) <= ARM_CONDITION: this form's rounding grows with the arms' conditions, the
    null-space form's with Zᵀ H Z's only, so the other samples take the null-space form. x (k,) work."""
    n, m = JT.shape
    k, r = A.shape[0], Hs.shape[0]
    for i in range(k):                            # A Aᵀ, its certificate
        for q in range(i + 1):
            acc = 0.0
            for p in range(m):
                acc += A[i, p] * A[q, p]
            SK[i, q] = acc
    trace = 0.0
    for i in range(k):
        trace += SK[i, i]
    if not (cholesky(SK, k) and rank_tol * trace * trace_of_inverse(SK, k, x) < 1.0):
        return False
    for a in range(r):
        for p in range(k):
            hs[a, p] = 0.0
            for q in range(k):
                Hs[a, p, q] = 0.0
    for j in range(n):
        if span[j, 1] == 0:
            continue
        a = span[j, 0] // k
        off = a * k
        for p in range(k):
            w = Q[j] * JT[j, off + p]
            hs[a, p] += w * ta[j]
            for q in range(p + 1):
                Hs[a, p, q] += w * JT[j, off + q]
    top, inv, worst = 0.0, 0.0, 0.0
    for a in range(r):
        trace = 0.0
        for p in range(k):
            trace += Hs[a, p, p]
        if not cholesky(Hs[a], k):
            return False
        trace_inv = trace_of_inverse(Hs[a], k, x)
        top, inv, worst = max(top, trace), max(inv, trace_inv), max(worst, trace * trace_inv)
        cholesky_solve(Hs[a], k, hs[a])
        for q in range(k):                        # Gs[a][:, q] = H_a⁻¹ (row q of A_a)
            for p in range(k):
                x[p] = A[q, a * k + p]
            cholesky_solve(Hs[a], k, x)
            for p in range(k):
                Gs[a, p, q] = x[p]
    if not (rank_tol * top * inv < 1.0 and worst <= ARM_CONDITION):
        return False
    for i in range(k):
        for q in range(i + 1):
            acc = 0.0
            for a in range(r):
                for p in range(k):
                    acc += A[i, a * k + p] * Gs[a, p, q]
            SK[i, q] = acc
    return cholesky(SK, k)


@kernel
def _min_energy_blocks(A, Gs, hs, SK, y, f, lam):
    """f ← the minimum-energy distribution of y from `_energy_blocks`: f_a = H_a⁻¹ (A_aᵀ λ − g_a),
    SK λ = y + Σ_a A_a H_a⁻¹ g_a (one sample; lam (k,) work)."""
    k, r = A.shape[0], Gs.shape[0]
    for q in range(k):
        acc = y[q]
        for a in range(r):
            for p in range(k):
                acc += A[q, a * k + p] * hs[a, p]
        lam[q] = acc
    cholesky_solve(SK, k, lam)
    for a in range(r):
        for p in range(k):
            acc = -hs[a, p]
            for q in range(k):
                acc += Gs[a, p, q] * lam[q]
            f[a * k + p] = acc


@kernel
def _internal(W, S, MAt, K, f, Fp, Fn, g, x, v6, w6):
    """Fp, Fn (r, 6) ← the paper and non-squeezing internal wrenches at C of f (one sample; g (m,),
    x (k,), v6, w6 (6,) work; K factored)."""
    r, k = W.shape[0], S.shape[0]
    m = MAt.shape[0]
    for i in range(6):
        w6[i] = 0.0
    for a in range(r):                            # W_a Sᵀ f_a, and their mean
        _wrench_at_c(W[a], S, f, a * k, Fp[a], v6)
        for i in range(6):
            w6[i] += Fp[a, i] / r
    for q in range(k):                            # g = f − M* Aᵀ K⁻¹ (A f): A f = S Σ_a W_a Sᵀ f_a
        acc = 0.0
        for j in range(6):
            acc += S[q, j] * w6[j]
        x[q] = acc * r
    for a in range(r):
        for i in range(6):
            Fp[a, i] -= w6[i]
    cholesky_solve(K, k, x)
    for p in range(m):
        acc = 0.0
        for q in range(k):
            acc += MAt[p, q] * x[q]
        g[p] = f[p] - acc
    for a in range(r):
        _wrench_at_c(W[a], S, g, a * k, Fn[a], v6)
    _project(S, Fp, w6)
    _project(S, Fn, w6)


@kernel
def _wrench_at_c(Wa, S, f, off, out, v6):
    """out (6,) ← W_a Sᵀ f[off:off + k] (an arm's grasp wrench moved to C; v6 (6,) work)."""
    k = S.shape[0]
    for j in range(6):
        acc = 0.0
        for q in range(k):
            acc += S[q, j] * f[off + q]
        v6[j] = acc
    for i in range(6):
        acc = 0.0
        for j in range(6):
            acc += Wa[i, j] * v6[j]
        out[i] = acc


@kernel
def _project(S, F, w6):
    """F (r, 6) ← SᵀS F row by row (the modelled components; w6 (6,) work)."""
    k = S.shape[0]
    for a in range(F.shape[0]):
        for i in range(6):
            acc = 0.0
            for q in range(k):
                sf = 0.0
                for j in range(6):
                    sf += S[q, j] * F[a, j]
                acc += S[q, i] * sf
            w6[i] = acc
        for i in range(6):
            F[a, i] = w6[i]


@kernel
def _limits(a, t1, lo, hi, up, dn):
    """up, dn (n,) ← `coopsim.inverse.distributions.mass_limits` of lo ≤ a + μ b ≤ hi, b = t1 − a (one sample)."""
    for j in range(a.shape[0]):
        b = t1[j] - a[j]
        if b > 0.0:
            u, v = (hi[j] - a[j]) / b, (lo[j] - a[j]) / b
        elif b < 0.0:
            u, v = (lo[j] - a[j]) / b, (hi[j] - a[j]) / b
        else:
            u = -np.inf if (a[j] < lo[j] or a[j] > hi[j]) else np.inf
            v = -np.inf
        up[j] = np.inf if np.isnan(u) else u
        dn[j] = v


@entry
def linear_pass(JT, A, ta, W, R_o, S, vm, vJ, pidx, Q, ys, which, wrench_of, lo, hi, pairs, rank_tol, f, tau, Fp, Fn,
                up, dn, unsure):
    """The linear resolutions of s net object wrenches at N samples, their internal wrenches and ratio tests.

    Rows of the method axis: PAPER, NONSQUEEZING, MIN_ENERGY (module docstring); a method's outputs are
    written where `which` selects it, and not at the samples `unsure` flags for it.

    Args:
        JT: (N, n, m) Jᵀ (`coopsim.inverse.problem.InverseProblem.JT`).
        A: (N, k, m) A = [S W_1 Sᵀ … S W_r Sᵀ].
        ta: (N, n) N·m (N on a prismatic joint), τ_arms.
        W: (N, r, 6, 6) the grasp matrices W_m.
        R_o: (N, 3, 3) the object rotation, world ← object frame.
        S: (k, 6) the constraint rows.
        vm: (r,) kg, the non-squeezing virtual masses m_i*.
        vJ: (r, 3, 3) kg·m², the virtual inertias J_i*, object frame.
        pidx: (p,) int64, the passive joints' indices (the rows P Jᵀ of C).
        Q: (n,) the energy weights (0 on passive joints).
        ys: (s, N, k) [N; N·m] the net object wrenches, rows S, world axes.
        which: (3,) bool, the methods to compute.
        wrench_of: the index into ys whose internal wrenches are written (−1: none).
        lo, hi: (N, n) N·m, the motor lines τ_min, τ_max.
        pairs: (P, 2) int64, the (y₀, y₀ + y₁) indices into ys of each ratio test.
        rank_tol: the forward model's rank tolerance (λ_min/λ_max) for the certificates of C Cᵀ and Dᵀ Q D.
        f: (3, s, N, m) [N; N·m], written: the grasp wrenches.
        tau: (3, s, N, n) N·m, written: the torques.
        Fp: (3, N, r, 6) [N; N·m], written: the paper internal wrenches at C of ys[wrench_of].
        Fn: (3, N, r, 6) [N; N·m], written: the non-squeezing internal wrenches at C of ys[wrench_of].
        up: (3, P, N, n) kg, written: the largest carried mass per motor line (`mass_limits`).
        dn: (3, P, N, n) kg, written: the smallest.
        unsure: (3, N) bool, written: the samples the NumPy path is to solve (K not positive definite
            for every method when internal wrenches are asked; C Cᵀ or Dᵀ Q D for min_energy).
    """
    N, n, m = JT.shape
    k, r, s = A.shape[1], W.shape[1], ys.shape[0]
    c = k + pidx.shape[0]
    d = max(m - c, 0)
    X, V, Qm, L = np.empty((m, c)), np.empty((m, c)), np.empty((m, m)), np.empty((c, c))
    Cp, Z, xc = np.empty((m, c)), np.empty((m, d)), np.empty(c)
    MAt, K = np.empty((m, k)), np.empty((k, k))
    B, T = np.empty((6, 6)), np.empty((k, 6))
    D, H = np.empty((n, max(d, 1))), np.empty((max(d, 1), max(d, 1)))
    v6, w6, x, xd = np.empty(6), np.empty(6), np.empty(k), np.empty(max(d, 1))
    b, u, z, g = np.empty(c), np.empty(n), np.empty(max(d, 1)), np.empty(m)
    span, Hs, Gs, hs = np.empty((n, 2), np.int64), np.empty((r, k, k)), np.empty((r, k, k)), np.empty((r, k))
    SK = np.empty((k, k))
    need_k = which[NONSQUEEZING] or wrench_of >= 0
    for i in range(N):
        for meth in range(3):
            unsure[meth, i] = False
        blocked = _row_spans(JT[i], k, span)
        k_ok, by_arm = True, False
        if need_k:
            k_ok = _nonsqueezing_factor(A[i], R_o[i], S, vm, vJ, MAt, K, B, T)
        if which[MIN_ENERGY]:
            by_arm = (blocked and pidx.shape[0] == 0
                      and _energy_blocks(JT[i], ta[i], A[i], Q, span, rank_tol, Hs, Gs, hs, SK, x))
            unsure[MIN_ENERGY, i] = not (by_arm or (
                _constraint_basis(A[i], JT[i], pidx, rank_tol, X, V, Qm, L, Cp, Z, xc)
                and _energy_factor(JT[i], Z, Q, rank_tol, D, H, xd)))
        for meth in range(3):
            if not which[meth]:
                continue
            if (need_k and not k_ok) or unsure[meth, i]:
                unsure[meth, i] = True
                continue
            for q in range(s):
                fq = f[meth, q, i]
                if meth == PAPER:
                    _paper(W[i], S, ys[q, i], fq, v6, w6)
                elif meth == NONSQUEEZING:
                    _nonsqueezing(MAt, K, ys[q, i], fq, x)
                elif by_arm:
                    _min_energy_blocks(A[i], Gs, hs, SK, ys[q, i], fq, x)
                else:
                    _min_energy(JT[i], ta[i], Cp, Z, D, H, pidx, Q, ys[q, i], fq, b, u, z, span)
                _torques(JT[i], ta[i], fq, tau[meth, q, i], span)
            if wrench_of >= 0:
                _internal(W[i], S, MAt, K, f[meth, wrench_of, i], Fp[meth, i], Fn[meth, i], g, x, v6, w6)
            for p in range(pairs.shape[0]):
                _limits(tau[meth, pairs[p, 0], i], tau[meth, pairs[p, 1], i], lo[i], hi[i], up[meth, p, i],
                        dn[meth, p, i])
