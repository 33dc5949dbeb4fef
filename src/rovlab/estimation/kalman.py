"""Discrete Kalman filter for the depth-and-heading model, with fusion and automatic dead reckoning.

Recursion (Sandøy 2016, sec. 5.1; Brown & Hwang 2012, ch. 4), at sample k:

1. correct with the samples y_k that arrived (sensor management in
   :mod:`rovlab.estimation.fusion` decides which are used and with what variance),
2. report the corrected x_k, P_k,
3. project with the input u_k held over [t_k, t_k + h):  x^- = Phi x + Delta u,
   P^- = Phi P Phi^T + Q   (Q from Van Loan: no Gamma Q Gamma^T: rovlab's correction of Sandøy 2016, sec. 5.1.2).

**Sequential scalar updates.** R is diagonal (independent sensors), so the stacked update with
all samples of a step equals the same update done one channel at a time (Bierman 1977, ch. II;
Brown & Hwang 2012, sec. 4.3) -- exact in exact arithmetic, and checked against filterpy's
stacked update to 1e-9 in the tests. Scalar updates need no matrix inverse (one division per
channel), make gating, drop-out and the recovery weighting per channel natural (a channel is
simply skipped or weighted), and cost O(n^2) per channel. Each scalar update is the **Joseph
form** P+ = (I - k h^T) P (I - k h^T)^T + r k k^T, evaluated as two rank-one products
(M = P - k (P h)^T, then P+ = M + (r k - M h) k^T), which keeps P positive semi-definite even
where the short form P - k h^T P loses it to cancellation (a 2e-9 m^2 Qualisys variance against
a metre-scale prior). Rows of states uncorrelated with the measurement (P h = 0) are left
untouched, P is kept exactly symmetric, psi is kept in (-pi, pi] and its innovations wrapped.

**Compiled kernels** (numba ``njit(cache=True)``, callable from Python and from other njit code
such as the closed-loop simulator). All arrays are float64 and C-contiguous unless noted; the
kernels work *in place* on x, P, ch (copy first if the input must be kept) and never allocate:

``model``
    the constant filter description, one flat float64 array built once by
    ``pack_model(Phi, Delta, Q, H, cfg, wrap)`` (``DepthHeadingFilter.packed``):
    ``[n, p, m, len(sp), Phi (n*n), Delta (n*p), Q (n*n), H (m*n), cfg (m*N_CFG), wrap (n), sp, kappa (p)]``
    with sp = Phi in CSR form and kappa each input's relative uncertainty. ``unpack_model(model)``
    returns the views ``(Phi, Delta, Q, H, cfg, wrap, sp, kappa)``. cfg layout: rovlab.estimation.fusion.
``work``
    scratch, ``kf_workspace(n, m)`` (``work_size(n, m)`` floats); allocate once, reuse.
``kf_predict(model, x, P, u, work) -> flags``
    x (n), P (n x n), u (p). Non-finite entries of u count as 0 (flag FLAG_INPUT).
``kf_correct(model, x, P, ch, t, y, present, rep, work) -> n_used``
    sensor management, then the sequential Joseph updates. ch (m x N_CH): per-channel state
    (updated); t [s]; y (m): raw samples (before lever-arm correction); present (m, bool or
    0/1 floats): which samples arrived; rep (m x N_REP): per-channel report (output).
``kf_step(model, x, P, ch, t, u, y, present, xc, Pc, rep, work) -> flags``
    kf_correct, copy of the corrected estimate into xc (n), Pc (n x n), then kf_predict: on
    return x, P hold the prior for the next sample. Flags: FLAG_INPUT, FLAG_TIME (t not
    finite: no sample used, timeouts frozen).
``kf_run(model, x, P, ch, t, u, y, present, n_predict, X, V, status, reason, event, innov, S,
flags) -> None``
    the offline filter: kf_step over N samples in one compiled loop. t (N), u (N x p),
    y (N x m), present (N x m, bool), n_predict (N, int64: projections after sample k, 1
    normally, more to bridge a gap in a log). Outputs: X (N x n) corrected estimates,
    V (N x n) their variances, status/reason/event (N x m, int8 codes of fusion),
    innov/S (N x m) prior innovations and their variances, flags (N, int8). On return x, P,
    ch hold the belief after the last sample.
``kf_update_scalar(x, P, h, value, r, angle, wrap, work) -> None``
    one Joseph update with value = h x + v, v ~ N(0, r) (h (n), wrap (n) 1.0 for angle states).

A closed-loop simulator keeps x, P, ch, xc, Pc, rep and work as its own arrays and calls
``kf_step(filt.packed, ...)`` once per filter sample from its njit loop.

For Python, rovlab.estimation.filtering.DepthHeadingFilter wraps them: ``step(belief, t, u, y) ->
(belief, report)`` with a Belief an immutable value (x, P, per-channel management state, time)
that can be saved and restored, and ``run(t, u, y)`` for a whole log (one call of kf_run);
rovlab.estimation.streaming feeds a long log through it in chunks.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.lib.stride_tricks import as_strided

from rovlab._jit import WITHOUT_NRT, njit
from rovlab.estimation.fusion import (
    CFG_ANGLE,
    CFG_R,
    CFG_STATE,
    CH_REASON,
    CH_STATUS,
    N_CFG,
    N_CH,
    N_REP,
    REP_EVENT,
    REP_INNOV,
    REP_R,
    REP_S,
    manage_channels,
    wrap_angle,
)

FLAG_INPUT = 1  # the input had non-finite entries (replaced by 0)
FLAG_TIME = 2  # the time was not finite (no sample used)
# bound once: Python-level lookups are a measurable share of an online step (~2 us)
_empty = np.empty
_new = object.__new__
_setattr = object.__setattr__


# --------------------------------------------------------------------------------------------
# Compiled kernels
# --------------------------------------------------------------------------------------------

def pack_model(Phi: np.ndarray, Delta: np.ndarray, Q: np.ndarray, H: np.ndarray, cfg: np.ndarray,
               wrap: np.ndarray, kappa: np.ndarray | None = None) -> np.ndarray:
    """The flat float64 model array every kernel takes (layout in the module docstring); ``kappa``
    (p): each input's relative uncertainty (default 0: the inputs are known exactly)."""
    Phi = np.asarray(Phi, dtype=float)
    n = Phi.shape[0]
    Delta = np.asarray(Delta, dtype=float).reshape(n, -1)
    Q = np.asarray(Q, dtype=float).reshape(n, n)
    H = np.asarray(H, dtype=float).reshape(-1, n)
    cfg = np.asarray(cfg, dtype=float).reshape(H.shape[0], N_CFG)
    wrap = np.asarray(wrap, dtype=float).ravel()
    if Phi.shape != (n, n) or wrap.shape != (n,):
        raise ValueError(f"Phi must be square and wrap have {n} entries")
    kappa = np.zeros(Delta.shape[1]) if kappa is None else np.asarray(kappa, dtype=float).ravel()
    if kappa.shape != (Delta.shape[1],) or not np.all(np.isfinite(kappa)) or np.any(kappa < 0):
        raise ValueError(f"kappa must hold {Delta.shape[1]} finite non-negative numbers, got {kappa!r}")
    sp = _phi_csr(Phi)
    model = np.concatenate([
        [n, Delta.shape[1], H.shape[0], sp.size], Phi.ravel(), Delta.ravel(), Q.ravel(), H.ravel(),
        cfg.ravel(), wrap, sp, kappa,
    ])
    model.setflags(write=False)
    return model


def _phi_csr(Phi: np.ndarray) -> np.ndarray:
    """Phi in compressed-sparse-row form: [nnz | col (nnz) | val (nnz) | rowptr (n+1)].

    The prediction runs over the nonzeros of Phi only (12 of 36 for the depth-and-heading model).
    """
    n = Phi.shape[0]
    rows, cols = np.nonzero(Phi)  # row-major order
    rowptr = np.searchsorted(rows, np.arange(n + 1))
    return np.concatenate([[rows.size], cols, Phi[rows, cols], rowptr]).astype(float)


@njit(cache=True, inline="always")
def _view2(a, o, rows, cols):
    """2-D C-ordered view of a[o:o + rows*cols] (as_strided: reshape costs a library call)."""
    return as_strided(a[o:o + rows * cols], shape=(rows, cols), strides=(cols * 8, 8))


@njit(cache=True, inline="always")
def unpack_model(model):
    """Views (Phi, Delta, Q, H, cfg, wrap, structure, kappa) of a packed model."""
    n = int(model[0])
    p = int(model[1])
    m = int(model[2])
    ls = int(model[3])
    o = 4
    Phi = _view2(model, o, n, n)
    o += n * n
    Delta = _view2(model, o, n, p)
    o += n * p
    Q = _view2(model, o, n, n)
    o += n * n
    H = _view2(model, o, m, n)
    o += m * n
    cfg = _view2(model, o, m, N_CFG)
    o += m * N_CFG
    wrap = model[o:o + n]
    o += n
    sp = model[o:o + ls]
    o += ls
    kappa = model[o:o + p]
    return Phi, Delta, Q, H, cfg, wrap, sp, kappa


@njit(cache=True)
def work_size(n, m):
    return n * n + 6 * n + m


def kf_workspace(n: int, m: int) -> np.ndarray:
    """Scratch memory for the kernels (allocate once, reuse every step)."""
    return np.empty(work_size(n, m))


@njit(cache=True, **WITHOUT_NRT)  # called by the loop: compiled alike whoever calls it first
def predict_arrays(x, P, Delta, Q, wrap, sp, u, work, kappa):
    """kf_predict on unpacked model arrays (for loops that unpack once).

    An input known only to a relative accuracy kappa_l (e.g. the wrench a real vehicle's thrusters
    give for their PWM: the thrust curve at the battery's voltage, ventilation at the surface, none
    out of the water) adds the covariance of its error, sigma_l = kappa_l |u_l| held over the sample:
    P += (kappa_l u_l)^2 Delta_l Delta_l^T. kappa = 0 adds nothing (the thesis's filter)."""
    n = x.shape[0]
    p = u.shape[0]
    nn = n * n
    ou = nn + 5 * n
    nnz = int(sp[0])
    ocol = 1
    oval = ocol + nnz
    orow = oval + nnz
    flags = 0
    for l in range(p):
        ul = u[l]
        if math.isfinite(ul):
            work[ou + l] = ul
        else:
            work[ou + l] = 0.0
            flags |= FLAG_INPUT
    for i in range(n):
        acc = 0.0
        for e in range(int(sp[orow + i]), int(sp[orow + i + 1])):
            acc += sp[oval + e] * x[int(sp[ocol + e])]
        for l in range(p):
            acc += Delta[i, l] * work[ou + l]
        work[nn + i] = acc
    for i in range(n):
        a = work[nn + i]
        x[i] = wrap_angle(a) if wrap[i] != 0.0 else a
    # P <- Phi P Phi^T + Q over the nonzeros of Phi; M = Phi P in work[:n*n]
    for i in range(n):
        r0 = i * n
        for j in range(n):
            work[r0 + j] = 0.0
        for e in range(int(sp[orow + i]), int(sp[orow + i + 1])):
            f = sp[oval + e]
            k = int(sp[ocol + e])
            for j in range(n):
                work[r0 + j] += f * P[k, j]
    for j in range(n):
        a = int(sp[orow + j])
        b = int(sp[orow + j + 1])
        for i in range(j + 1):
            acc = Q[i, j]
            r0 = i * n
            for e in range(a, b):
                acc += work[r0 + int(sp[ocol + e])] * sp[oval + e]
            P[i, j] = acc
            P[j, i] = acc
    for l in range(p):
        g = kappa[l] * work[ou + l]
        if g != 0.0:
            g2 = g * g
            for i in range(n):
                di = g2 * Delta[i, l]
                if di != 0.0:
                    for j in range(i + 1):
                        c = di * Delta[j, l]
                        P[i, j] += c
                        if j != i:
                            P[j, i] += c
    return flags


@njit(cache=True, inline="always")
def _update_row(x, P, H, j, idx, value, r_gain, r, angle, wrap, work):
    """Joseph update with the scalar measurement value = H[j] x + v, v ~ N(0, r).

    The gain is computed with r_gain >= r (under-weighting a returning sensor; r_gain = r is
    the Kalman gain); the covariance with the true r, which the Joseph form allows for any gain.
    """
    n = x.shape[0]
    op = n * n + n
    ok = op + n
    oc = ok + n
    oa = oc + n
    if idx >= 0:  # H[j] = e_idx
        for i in range(n):
            work[op + i] = P[i, idx]
        hx = x[idx]
        hp = P[idx, idx]
    else:
        hx = 0.0
        for i in range(n):
            acc = 0.0
            for k in range(n):
                acc += P[i, k] * H[j, k]
            work[op + i] = acc
            hx += H[j, i] * x[i]
        hp = 0.0
        for i in range(n):
            hp += H[j, i] * work[op + i]
    s = hp + r_gain
    nu = value - hx
    if angle:
        nu = wrap_angle(nu)
    # Joseph form as two rank-one products: M = (I - k h^T) P = P - k p^T (P symmetric);
    # P+ = M (I - k h^T)^T + r k k^T = M + c k^T, c = r k - M h, M h = p - k (h^T p).
    # Rows and columns with p_i = 0 have k_i = c_i = 0 and stay as they are, so only the
    # "active" states (those correlated with the measurement) are visited.
    na = 0
    for i in range(n):
        pi = work[op + i]
        if pi != 0.0:
            ki = pi / s
            work[ok + i] = ki
            x[i] += ki * nu
            if wrap[i] != 0.0:
                x[i] = wrap_angle(x[i])
            work[oc + i] = r * ki - (pi - ki * hp)
            work[oa + na] = i
            na += 1
    for a in range(na):
        i = int(work[oa + a])
        ki = work[ok + i]
        ci = work[oc + i]
        for b in range(a, na):
            jj = int(work[oa + b])
            v = (P[i, jj] - ki * work[op + jj]) + ci * work[ok + jj]
            P[i, jj] = v
            P[jj, i] = v


@njit(cache=True)
def kf_update_scalar(x, P, h, value, r, angle, wrap, work):
    H = h.reshape((1, h.shape[0]))
    idx = -1
    nz = 0
    for i in range(h.shape[0]):
        if h[i] != 0.0:
            nz += 1
            idx = i
    if not (nz == 1 and h[idx] == 1.0):
        idx = -1
    _update_row(x, P, H, 0, idx, value, r, r, angle, wrap, work)


@njit(cache=True, **WITHOUT_NRT)  # called by the loop: compiled alike whoever calls it first
def correct_arrays(x, P, ch, H, cfg, wrap, t, y, present, rep, work):
    """kf_correct on unpacked model arrays (for loops that unpack once)."""
    m = H.shape[0]
    n = x.shape[0]
    ov = n * n + 6 * n
    value = work[ov:ov + m]
    used = manage_channels(x, P, ch, H, cfg, t, y, present, rep, value)
    if used:
        for j in range(m):
            v = work[ov + j]
            if not math.isnan(v):
                _update_row(x, P, H, j, int(cfg[j, CFG_STATE]), v, rep[j, REP_R], cfg[j, CFG_R],
                            cfg[j, CFG_ANGLE] != 0.0, wrap, work)
    return used


@njit(cache=True)
def step_arrays(Delta, Q, H, cfg, wrap, sp, kappa, x, P, ch, t, u, y, present, xc, Pc, rep, work):
    """kf_step on unpacked model arrays (for loops that unpack once)."""
    correct_arrays(x, P, ch, H, cfg, wrap, t, y, present, rep, work)
    n = x.shape[0]
    for i in range(n):
        xc[i] = x[i]
        for j in range(n):
            Pc[i, j] = P[i, j]
    flags = predict_arrays(x, P, Delta, Q, wrap, sp, u, work, kappa)
    if not math.isfinite(t):
        flags |= FLAG_TIME
    return flags


@njit(cache=True)
def kf_predict(model, x, P, u, work):
    Phi, Delta, Q, H, cfg, wrap, sp, kappa = unpack_model(model)
    return predict_arrays(x, P, Delta, Q, wrap, sp, u, work, kappa)


@njit(cache=True)
def kf_correct(model, x, P, ch, t, y, present, rep, work):
    Phi, Delta, Q, H, cfg, wrap, sp, kappa = unpack_model(model)
    return correct_arrays(x, P, ch, H, cfg, wrap, t, y, present, rep, work)


@njit(cache=True)
def kf_step(model, x, P, ch, t, u, y, present, xc, Pc, rep, work):
    Phi, Delta, Q, H, cfg, wrap, sp, kappa = unpack_model(model)
    return step_arrays(Delta, Q, H, cfg, wrap, sp, kappa, x, P, ch, t, u, y, present, xc, Pc, rep, work)


@njit(cache=True, nogil=True)  # only arrays: a log's reader and writer threads run alongside
def kf_run(model, x, P, ch, t, u, y, present, n_predict, X, V, status, reason, event, innov, S, flags):
    Phi, Delta, Q, H, cfg, wrap, sp, kappa = unpack_model(model)
    N = t.shape[0]
    n = x.shape[0]
    m = H.shape[0]
    rep = np.empty((m, N_REP))
    work = np.empty(work_size(n, m))
    for k in range(N):
        correct_arrays(x, P, ch, H, cfg, wrap, t[k], y[k], present[k], rep, work)
        for i in range(n):
            X[k, i] = x[i]
            V[k, i] = P[i, i]
        for j in range(m):
            status[k, j] = np.int8(ch[j, CH_STATUS])
            reason[k, j] = np.int8(ch[j, CH_REASON])
            event[k, j] = np.int8(rep[j, REP_EVENT])
            innov[k, j] = rep[j, REP_INNOV]
            S[k, j] = rep[j, REP_S]
        f = 0
        for _ in range(n_predict[k]):
            f |= predict_arrays(x, P, Delta, Q, wrap, sp, u[k], work, kappa)
        if not math.isfinite(t[k]):
            f |= FLAG_TIME
        flags[k] = np.int8(f)


# Entry points of the Python step API: one dispatch into memory allocated by the caller.
# state = [n, m, t, x, P, ch]; out = [state' | xc, Pc, rep, flags | present, work].

def _out_size(n: int, m: int) -> int:
    return 3 + n + n * n + m * N_CH + n + n * n + m * N_REP + 1 + m + n * n + 6 * n + m


@njit(cache=True)
def _online_into(model, state, t, u, y, present, use_present, out):
    Phi, Delta, Q, H, cfg, wrap, sp, kappa = unpack_model(model)
    n = int(model[0])
    p = int(model[1])
    m = int(model[2])
    ls = 3 + n + n * n + m * N_CH
    lr = n + n * n + m * N_REP + 1
    if y.shape[0] != m or u.shape[0] != p or (use_present and present.shape[0] != m):
        raise ValueError("y (and present) need one value per channel and u one per input")
    if state.shape[0] < ls or int(state[0]) != n or int(state[1]) != m or out.shape[0] != ls + lr + m + \
            work_size(n, m):
        raise ValueError("the belief does not belong to this filter")
    out[:ls] = state[:ls]
    out[2] = t
    op = ls + lr
    for j in range(m):
        if use_present:
            out[op + j] = 1.0 if present[j] else 0.0
        else:
            out[op + j] = 0.0 if math.isnan(y[j]) else 1.0
    x = out[3:3 + n]
    P = _view2(out, 3 + n, n, n)
    ch = _view2(out, 3 + n + n * n, m, N_CH)
    xc = out[ls:ls + n]
    Pc = _view2(out, ls + n, n, n)
    rep = _view2(out, ls + n + n * n, m, N_REP)
    pres = out[op:op + m]
    work = out[op + m:]
    out[ls + lr - 1] = step_arrays(Delta, Q, H, cfg, wrap, sp, kappa, x, P, ch, t, u, y, pres, xc, Pc, rep, work)


@njit(cache=True)
def _online_present(model, state, t, u, y, present, out):
    _online_into(model, state, t, u, y, present, True, out)


@njit(cache=True)
def _online(model, state, t, u, y, out):
    _online_into(model, state, t, u, y, y, False, out)


__all__ = (
    "FLAG_INPUT", "FLAG_TIME", "kf_correct", "kf_predict", "kf_run", "kf_step", "kf_update_scalar",
    "pack_model", "unpack_model", "work_size", "kf_workspace",
)
