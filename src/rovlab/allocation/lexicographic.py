"""Exact prioritised (lexicographic) thrust allocation as small compiled LP/QP solves.

Problem. The demanded wrench tau (6) is split into priority levels l = 0..L-1 (disjoint DOF
groups); tau_l holds tau's entries on level l's DOFs and zeros elsewhere. Find fractions
alpha_l in [0, 1] and thruster forces f with

    B f = sum_l alpha_l tau_l,        f_min <= f <= f_max   (asymmetric, per thruster)

that maximise alpha_0, then alpha_1 with alpha_0 held at its optimum, and so on: the
lexicographic optimum of prioritised allocation (Johansen & Fossen 2013, "Control allocation -
a survey", Automatica 49(5), 1087-1103; the LP form of direction-preserving allocation is Bodson
2002, "Evaluation of optimization methods for control allocation", J. Guid. Control Dyn. 25(4)).
Each level is scaled along its own direction, never bent, and every DOF demanded zero (K = M = 0
in 4-DOF use) is an equality. When every level reaches 1 the demand is met exactly. Among the
force vectors giving the optimal fractions the one with the least weighted effort f^T W f is
returned (for a square B there is only one).

Variables. With T = W^-1/2 pinv(B W^-1/2) (the weighted pseudo-inverse) and N = W^-1/2 Z, Z an
orthonormal basis of null(B W^-1/2), every force vector reproducing the wrench is

    f = sum_l alpha_l d_l + N z,      d_l = T tau_l,

so the problem lives in y = [alpha (L); z (q)] with q = n - rank(B) (0 for uDrone, 2 for the
8-thruster BlueROV2 Heavy) under the 2n + 2L inequalities G y <= h (thruster and fraction
bounds). For a rank-deficient B this gives the pseudo-inverse's (least-squares) wrench scaled per
level, as the plain pseudo-inverse would.

Solvers (both primal active-set methods: every iterate is feasible, so even an iteration cap
returns limits-respecting, non-bending forces):

* LP, one stage per level: the inequality-form simplex (Fletcher 1987, *Practical Methods of
  Optimization*, 2nd ed., ch. 8): a p x p working matrix of active constraint rows - "free"
  coordinate rows while the point is not yet a vertex - and its inverse, updated by a rank-one
  pivot; the row with the most negative multiplier leaves, the ratio test picks the blocking
  constraint; Bland's smallest-index rule after repeated degenerate steps. Stage k starts from
  stage k-1's optimum with alpha_{k-1} fixed by an equality row, so it warm-starts.
* QP for z (least-distance, min |z|^2 over the optimal face): the primal active-set method of
  Nocedal & Wright 2006, *Numerical Optimization*, 2nd ed., Algorithm 16.3.
"""

from __future__ import annotations

import numpy as np

_FREE, _INEQ, _FIXED = 0, 1, 2  # kinds of working-matrix row
_NULL_TOL = 1e-6  # residual norm below which a projector column is taken as dependent
_DIR_TOL = 1e-12  # relative size of G_i d treated as zero in the ratio test
_DUAL_TOL = 1e-11  # multiplier size treated as zero (optimality)
_DEGENERATE_BEFORE_BLAND = 8


def null_basis(B: np.ndarray, T: np.ndarray, s: np.ndarray, redistribute: bool) -> np.ndarray:
    """N (n x q): W^-1/2 times an orthonormal basis of null(B W^-1/2), s = W^-1/2 diagonal.

    Built from the orthogonal projector I - S^-1 T B S (S = diag(s)) by Gram-Schmidt with
    column pivoting, so q = n - rank(B) comes out of the same pass. ``redistribute=False``
    returns q = 0 (forces restricted to the pseudo-inverse's range)."""
    n = B.shape[1]
    if not redistribute or n == 0:
        return np.zeros((n, 0))
    P = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            acc = 0.0
            for k in range(B.shape[0]):
                acc += T[i, k] * B[k, j]
            P[i, j] = (1.0 if i == j else 0.0) - acc * s[j] / s[i]
    Z = np.zeros((n, n))
    q = 0
    used = np.zeros(n, dtype=np.bool_)
    for _ in range(n):
        best, jb = 0.0, -1
        for j in range(n):
            if used[j]:
                continue
            nrm = 0.0
            for i in range(n):
                nrm += P[i, j] * P[i, j]
            if nrm > best:
                best, jb = nrm, j
        if jb < 0 or np.sqrt(best) < _NULL_TOL:
            break
        used[jb] = True
        nrm = np.sqrt(best)
        for i in range(n):
            Z[i, q] = P[i, jb] / nrm
        # remove the new direction from the remaining columns
        for j in range(n):
            if used[j]:
                continue
            dot = 0.0
            for i in range(n):
                dot += Z[i, q] * P[i, j]
            for i in range(n):
                P[i, j] -= dot * Z[i, q]
        q += 1
    N = np.empty((n, q))
    for i in range(n):
        for c in range(q):
            N[i, c] = s[i] * Z[i, c]
    return N


def _pivot(Ainv: np.ndarray, row: np.ndarray, j: int) -> None:
    """Replace row j of the working matrix A by ``row``, updating A^-1 in place (A' = A with
    row j replaced; requires row . A^-1 e_j != 0)."""
    p = Ainv.shape[0]
    v = np.zeros(p)
    for k in range(p):
        acc = 0.0
        for r in range(p):
            acc += row[r] * Ainv[r, k]
        v[k] = acc
    piv = v[j]
    for r in range(p):
        Ainv[r, j] /= piv
    for k in range(p):
        if k != j and v[k] != 0.0:
            for r in range(p):
                Ainv[r, k] -= v[k] * Ainv[r, j]


def _lp_stage(G: np.ndarray, h: np.ndarray, gnorm: np.ndarray, m: int, y: np.ndarray, Ainv: np.ndarray,
              ci: np.ndarray, kind: np.ndarray, obj: int, max_iter: int) -> int:
    """Maximise y[obj] over G[:m] y <= h[:m] from the feasible y, with the working matrix given
    by (ci, kind, Ainv); rows m.. of G are the coordinate rows e_k. Returns the iterations."""
    p = y.shape[0]
    in_basis = np.zeros(G.shape[0], dtype=np.bool_)
    for j in range(p):
        in_basis[ci[j]] = True
    d = np.zeros(p)
    degenerate = 0
    it = 0
    while it < max_iter:
        it += 1
        # multipliers lambda_j = e_obj^T A^-1 e_j of the working rows; choose one to leave
        bland = degenerate >= _DEGENERATE_BEFORE_BLAND
        jl, best, sigma = -1, 0.0, 0.0
        for j in range(p):
            lam = Ainv[obj, j]
            if kind[j] == _FIXED:
                continue
            if kind[j] == _FREE:
                score, sg = abs(lam), (1.0 if lam > 0.0 else -1.0)
            else:
                score, sg = -lam, -1.0
            if score <= _DUAL_TOL:
                continue
            if bland:
                if jl < 0 or ci[j] < ci[jl]:
                    jl, best, sigma = j, score, sg
            elif score > best:
                jl, best, sigma = j, score, sg
        if jl < 0:
            break  # optimal
        dnorm = 0.0
        for r in range(p):
            d[r] = sigma * Ainv[r, jl]
            dnorm = max(dnorm, abs(d[r]))
        # ratio test over the constraints not in the working set
        ib, tb, gb = -1, np.inf, 0.0
        for i in range(m):
            if in_basis[i]:
                continue
            gd = 0.0
            gy = 0.0
            for r in range(p):
                gd += G[i, r] * d[r]
                gy += G[i, r] * y[r]
            if gd <= _DIR_TOL * gnorm[i] * dnorm:
                continue
            t = max(h[i] - gy, 0.0) / gd
            if t < tb or (t == tb and (bland and i < ib or not bland and gd > gb)):
                ib, tb, gb = i, t, gd
        if ib < 0:
            break  # unbounded: cannot happen with bounded fractions and forces; keep y
        for r in range(p):
            y[r] += tb * d[r]
        degenerate = degenerate + 1 if tb * dnorm <= 1e-14 * (1.0 + np.max(np.abs(y))) else 0
        _pivot(Ainv, G[ib], jl)
        in_basis[ci[jl]] = False
        in_basis[ib] = True
        ci[jl] = ib
        kind[jl] = _INEQ
    return it


def _fix_coordinate(G: np.ndarray, m: int, k: int, Ainv: np.ndarray, ci: np.ndarray, kind: np.ndarray) -> None:
    """Hold y[k] at its current value from now on: make an equality row of the working matrix
    that pins it (the coordinate row e_k, or a bound of y[k] already in the working set)."""
    p = Ainv.shape[0]
    for j in range(p):
        if ci[j] == m + k or (kind[j] == _INEQ and _is_bound_of(G, ci[j], k)):
            kind[j] = _FIXED
            return
    jb, best = -1, 0.0
    for j in range(p):
        if kind[j] != _FIXED and abs(Ainv[k, j]) > best:
            jb, best = j, abs(Ainv[k, j])
    if jb < 0:
        return  # y[k] is already determined by the fixed rows
    _pivot(Ainv, G[m + k], jb)
    ci[jb] = m + k
    kind[jb] = _FIXED


def _is_bound_of(G: np.ndarray, i: int, k: int) -> bool:
    """Row i of G is a multiple of e_k (it bounds coordinate k alone)."""
    if G[i, k] == 0.0:
        return False
    for r in range(G.shape[1]):
        if r != k and G[i, r] != 0.0:
            return False
    return True


def _solve_small(M: np.ndarray, b: np.ndarray) -> np.ndarray:
    """M x = b by Gaussian elimination with partial pivoting (M is k x k, k tiny)."""
    k = b.shape[0]
    A = M.copy()
    x = b.copy()
    for c in range(k):
        piv = c
        for r in range(c + 1, k):
            if abs(A[r, c]) > abs(A[piv, c]):
                piv = r
        if piv != c:
            for cc in range(k):
                A[c, cc], A[piv, cc] = A[piv, cc], A[c, cc]
            x[c], x[piv] = x[piv], x[c]
        for r in range(c + 1, k):
            fct = A[r, c] / A[c, c]
            for cc in range(c, k):
                A[r, cc] -= fct * A[c, cc]
            x[r] -= fct * x[c]
    for c in range(k - 1, -1, -1):
        acc = x[c]
        for cc in range(c + 1, k):
            acc -= A[c, cc] * x[cc]
        x[c] = acc / A[c, c]
    return x


def least_distance(Gz: np.ndarray, hz: np.ndarray, z: np.ndarray, max_iter: int) -> int:
    """min |z|^2 subject to Gz z <= hz from a feasible z (updated in place): the primal active-set
    method (Nocedal & Wright 2006, Algorithm 16.3) with an empty initial working set. The step
    is minus z's component in the null space of the working rows (an orthonormal basis Q of
    them is rebuilt each iteration, q being tiny); rows dependent on the working ones never
    block (their step product is zero up to round-off)."""
    m, q = Gz.shape
    work = np.zeros(q, dtype=np.int64)
    nw = 0
    member = np.zeros(m, dtype=np.bool_)
    Q = np.zeros((q, q))
    step = np.zeros(q)
    resid = np.zeros(q)
    it = 0
    while it < max_iter:
        it += 1
        for a in range(nw):  # Gram-Schmidt of the working rows (independent by construction)
            for r in range(q):
                Q[a, r] = Gz[work[a], r]
            for b in range(a):
                dot = 0.0
                for r in range(q):
                    dot += Q[b, r] * Q[a, r]
                for r in range(q):
                    Q[a, r] -= dot * Q[b, r]
            nrm = 0.0
            for r in range(q):
                nrm += Q[a, r] * Q[a, r]
            nrm = np.sqrt(nrm)
            for r in range(q):
                Q[a, r] /= nrm
        pn = 0.0
        zn = 0.0
        for r in range(q):
            step[r] = -z[r]
            zn = max(zn, abs(z[r]))
        for a in range(nw):
            dot = 0.0
            for r in range(q):
                dot += Q[a, r] * z[r]
            for r in range(q):
                step[r] += dot * Q[a, r]
        for r in range(q):
            pn = max(pn, abs(step[r]))
        if pn <= 1e-12 * (1.0 + zn):
            if nw == 0:
                break
            # multipliers: z + G_W^T mu = 0  ->  (G_W G_W^T) mu = -G_W z
            M = np.empty((nw, nw))
            bw = np.empty(nw)
            for a in range(nw):
                acc = 0.0
                for r in range(q):
                    acc += Gz[work[a], r] * z[r]
                bw[a] = -acc
                for b in range(nw):
                    acc = 0.0
                    for r in range(q):
                        acc += Gz[work[a], r] * Gz[work[b], r]
                    M[a, b] = acc
            mu = _solve_small(M, bw)
            jmin, mmin = -1, -1e-12 * (1.0 + zn)
            for a in range(nw):
                if mu[a] < mmin:
                    jmin, mmin = a, mu[a]
            if jmin < 0:
                break  # KKT point: optimal
            member[work[jmin]] = False
            for a in range(jmin, nw - 1):
                work[a] = work[a + 1]
            nw -= 1
            continue
        tb, ib = 1.0, -1
        for i in range(m):
            if member[i]:
                continue
            gd = 0.0
            gz = 0.0
            gn = 0.0
            for r in range(q):
                gd += Gz[i, r] * step[r]
                gz += Gz[i, r] * z[r]
                gn = max(gn, abs(Gz[i, r]))
            if gd <= 0.0:
                continue
            # a row in the span of the working rows has G_i step = 0 in exact arithmetic
            for r in range(q):
                resid[r] = Gz[i, r]
            for a in range(nw):
                dot = 0.0
                for r in range(q):
                    dot += Q[a, r] * Gz[i, r]
                for r in range(q):
                    resid[r] -= dot * Q[a, r]
            rn = 0.0
            for r in range(q):
                rn = max(rn, abs(resid[r]))
            if rn <= 1e-9 * gn:
                continue
            t = max(hz[i] - gz, 0.0) / gd
            if t < tb:
                tb, ib = t, i
        for r in range(q):
            z[r] += tb * step[r]
        if ib >= 0:
            work[nw] = ib
            member[ib] = True
            nw += 1
    return it


def lexicographic_allocate(B: np.ndarray, T: np.ndarray, s: np.ndarray, f_min: np.ndarray, f_max: np.ndarray,
                           tau: np.ndarray, level: np.ndarray, n_levels: int, redistribute: bool):
    """(f, fraction per DOF): the lexicographic optimum described in the module docstring.

    ``level[j]`` is DOF j's priority level (0 = highest); levels with nothing demanded, and DOFs
    demanded zero, report fraction 1. ``redistribute=False`` restricts the forces to the
    pseudo-inverse's range (no use of B's null space)."""
    n = B.shape[1]
    frac = np.ones(6)
    # levels that demand something, in priority order
    lv_of = np.zeros(n_levels, dtype=np.int64)
    L = 0
    for lv in range(n_levels):
        for j in range(6):
            if level[j] == lv and tau[j] != 0.0:
                lv_of[L] = lv
                L += 1
                break
    f = np.zeros(n)
    if L == 0:
        return f, frac
    # d_l = T tau_l
    D = np.zeros((n, L))
    for k in range(L):
        for i in range(n):
            acc = 0.0
            for j in range(6):
                if level[j] == lv_of[k]:
                    acc += T[i, j] * tau[j]
            D[i, k] = acc
    # fast path: the whole demand through the pseudo-inverse is within the limits
    inside = True
    for i in range(n):
        acc = 0.0
        for k in range(L):
            acc += D[i, k]
        f[i] = acc
        if acc > f_max[i] or acc < f_min[i]:
            inside = False
    if inside:
        return f, frac
    N = null_basis(B, T, s, redistribute)
    q = N.shape[1]
    p = L + q
    m = 2 * n + 2 * L
    # constraint rows G y <= h, then the p coordinate rows e_k (for free / fixed working rows)
    G = np.zeros((m + p, p))
    h = np.zeros(m + p)
    for i in range(n):
        for k in range(L):
            G[2 * i, k] = D[i, k]
            G[2 * i + 1, k] = -D[i, k]
        for c in range(q):
            G[2 * i, L + c] = N[i, c]
            G[2 * i + 1, L + c] = -N[i, c]
        h[2 * i] = f_max[i]
        h[2 * i + 1] = -f_min[i]
    for k in range(L):
        G[2 * n + 2 * k, k] = 1.0
        h[2 * n + 2 * k] = 1.0
        G[2 * n + 2 * k + 1, k] = -1.0
    for k in range(p):
        G[m + k, k] = 1.0
    gnorm = np.zeros(m)
    for i in range(m):
        for r in range(p):
            gnorm[i] = max(gnorm[i], abs(G[i, r]))
    # start at y = 0 (no force: feasible as f_min <= 0 <= f_max), working matrix = identity
    y = np.zeros(p)
    Ainv = np.eye(p)
    ci = np.arange(m, m + p)
    kind = np.zeros(p, dtype=np.int64)
    max_iter = 20 * (m + p)
    for k in range(L):
        _lp_stage(G, h, gnorm, m, y, Ainv, ci, kind, k, max_iter)
        y[k] = min(max(y[k], 0.0), 1.0)
        _fix_coordinate(G, m, k, Ainv, ci, kind)
    if q > 0:
        # least effort over the optimal face: min |z|^2 with the fractions fixed
        Gz = np.zeros((2 * n, q))
        hz = np.zeros(2 * n)
        for i in range(n):
            base = 0.0
            for k in range(L):
                base += D[i, k] * y[k]
            for c in range(q):
                Gz[2 * i, c] = N[i, c]
                Gz[2 * i + 1, c] = -N[i, c]
            hz[2 * i] = f_max[i] - base
            hz[2 * i + 1] = base - f_min[i]
        z = y[L:].copy()
        least_distance(Gz, hz, z, 10 * (2 * n + q))
        y[L:] = z
    for i in range(n):
        acc = 0.0
        for r in range(p):
            acc += G[2 * i, r] * y[r]
        # round-off only (the iterates are feasible): keep the forces exactly within the limits
        f[i] = min(max(acc, f_min[i]), f_max[i])
    for j in range(6):
        if tau[j] != 0.0:
            for k in range(L):
                if lv_of[k] == level[j]:
                    frac[j] = y[k]
    return f, frac
