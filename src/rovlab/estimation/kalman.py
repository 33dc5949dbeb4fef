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
    ``[n, p, m, len(sp), Phi (n*n), Delta (n*p), Q (n*n), H (m*n), cfg (m*N_CFG), wrap (n), sp]``
    with sp = Phi in CSR form. ``unpack_model(model)`` returns the views
    ``(Phi, Delta, Q, H, cfg, wrap, sp)``. cfg layout: rovlab.estimation.fusion.
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

For Python, :class:`DepthHeadingFilter` wraps them: ``step(belief, t, u, y) -> (belief, report)``
with :class:`Belief` an immutable value (x, P, per-channel management state, time) that can be
saved and restored, and ``run(t, u, y)`` for a whole log (one call of kf_run).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.lib.stride_tricks import as_strided

from rovlab._jit import njit
from rovlab.estimation.fusion import (
    CFG_ANGLE,
    CFG_R,
    CFG_STATE,
    CH_MODE,
    CH_REASON,
    CH_STATUS,
    EVENT_NAMES,
    MODE_AUTO,
    MODE_NAMES,
    MODE_OFF,
    MODE_ON,
    N_CFG,
    N_CH,
    N_REP,
    REP_EVENT,
    REP_INNOV,
    REP_R,
    REP_S,
    STATUS_LOST,
    STATUS_NAMES,
    manage_channels,
    new_channel_state,
    status_label,
    wrap_angle,
)
from rovlab.estimation.model import FilterModel

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
               wrap: np.ndarray) -> np.ndarray:
    """The flat float64 model array every kernel takes (layout in the module docstring)."""
    Phi = np.asarray(Phi, dtype=float)
    n = Phi.shape[0]
    Delta = np.asarray(Delta, dtype=float).reshape(n, -1)
    Q = np.asarray(Q, dtype=float).reshape(n, n)
    H = np.asarray(H, dtype=float).reshape(-1, n)
    cfg = np.asarray(cfg, dtype=float).reshape(H.shape[0], N_CFG)
    wrap = np.asarray(wrap, dtype=float).ravel()
    if Phi.shape != (n, n) or wrap.shape != (n,):
        raise ValueError(f"Phi must be square and wrap have {n} entries")
    sp = _phi_csr(Phi)
    model = np.concatenate([
        [n, Delta.shape[1], H.shape[0], sp.size], Phi.ravel(), Delta.ravel(), Q.ravel(), H.ravel(),
        cfg.ravel(), wrap, sp,
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
    """Views (Phi, Delta, Q, H, cfg, wrap, structure) of a packed model."""
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
    return Phi, Delta, Q, H, cfg, wrap, sp


@njit(cache=True)
def work_size(n, m):
    return n * n + 6 * n + m


def kf_workspace(n: int, m: int) -> np.ndarray:
    """Scratch memory for the kernels (allocate once, reuse every step)."""
    return np.empty(work_size(n, m))


@njit(cache=True)
def predict_arrays(x, P, Delta, Q, wrap, sp, u, work):
    """kf_predict on unpacked model arrays (for loops that unpack once)."""
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


@njit(cache=True)
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
def step_arrays(Delta, Q, H, cfg, wrap, sp, x, P, ch, t, u, y, present, xc, Pc, rep, work):
    """kf_step on unpacked model arrays (for loops that unpack once)."""
    correct_arrays(x, P, ch, H, cfg, wrap, t, y, present, rep, work)
    n = x.shape[0]
    for i in range(n):
        xc[i] = x[i]
        for j in range(n):
            Pc[i, j] = P[i, j]
    flags = predict_arrays(x, P, Delta, Q, wrap, sp, u, work)
    if not math.isfinite(t):
        flags |= FLAG_TIME
    return flags


@njit(cache=True)
def kf_predict(model, x, P, u, work):
    Phi, Delta, Q, H, cfg, wrap, sp = unpack_model(model)
    return predict_arrays(x, P, Delta, Q, wrap, sp, u, work)


@njit(cache=True)
def kf_correct(model, x, P, ch, t, y, present, rep, work):
    Phi, Delta, Q, H, cfg, wrap, sp = unpack_model(model)
    return correct_arrays(x, P, ch, H, cfg, wrap, t, y, present, rep, work)


@njit(cache=True)
def kf_step(model, x, P, ch, t, u, y, present, xc, Pc, rep, work):
    Phi, Delta, Q, H, cfg, wrap, sp = unpack_model(model)
    return step_arrays(Delta, Q, H, cfg, wrap, sp, x, P, ch, t, u, y, present, xc, Pc, rep, work)


@njit(cache=True, nogil=True)  # only arrays: a log's reader and writer threads run alongside
def kf_run(model, x, P, ch, t, u, y, present, n_predict, X, V, status, reason, event, innov, S, flags):
    Phi, Delta, Q, H, cfg, wrap, sp = unpack_model(model)
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
            f |= predict_arrays(x, P, Delta, Q, wrap, sp, u[k], work)
        if not math.isfinite(t[k]):
            f |= FLAG_TIME
        flags[k] = np.int8(f)


# Entry points of the Python step API: one dispatch into memory allocated by the caller.
# state = [n, m, t, x, P, ch]; out = [state' | xc, Pc, rep, flags | present, work].

def _out_size(n: int, m: int) -> int:
    return 3 + n + n * n + m * N_CH + n + n * n + m * N_REP + 1 + m + n * n + 6 * n + m


@njit(cache=True)
def _online_into(model, state, t, u, y, present, use_present, out):
    Phi, Delta, Q, H, cfg, wrap, sp = unpack_model(model)
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
    out[ls + lr - 1] = step_arrays(Delta, Q, H, cfg, wrap, sp, x, P, ch, t, u, y, pres, xc, Pc, rep, work)


@njit(cache=True)
def _online_present(model, state, t, u, y, present, out):
    _online_into(model, state, t, u, y, present, True, out)


@njit(cache=True)
def _online(model, state, t, u, y, out):
    _online_into(model, state, t, u, y, y, False, out)


# --------------------------------------------------------------------------------------------
# Python API
# --------------------------------------------------------------------------------------------

def _ro(view: np.ndarray) -> np.ndarray:
    view.flags.writeable = False
    return view


@dataclass(frozen=True, slots=True, eq=False)
class Belief:
    """What the filter knows before a sample: prior x, P, per-channel management state, time.

    An immutable value: one float array ``data = [n, m, t, x, P, channels, ...]`` (after a
    step, ``data`` is that step's whole output buffer; only the head is the belief) that no
    filter function modifies. The properties return read-only views. A belief can be kept,
    passed around, saved with ``to_dict`` (JSON-ready) and restored with ``from_dict``.
    """

    data: np.ndarray  # do not modify in place

    @staticmethod
    def make(x: np.ndarray, P: np.ndarray, channels: np.ndarray, t: float = math.nan) -> Belief:
        x = np.asarray(x, dtype=float).ravel()
        n = x.size
        P = np.asarray(P, dtype=float)
        channels = np.asarray(channels, dtype=float)
        if P.shape != (n, n) or channels.ndim != 2 or channels.shape[1] != N_CH:
            raise ValueError(f"belief needs x (n), P (n x n) and channels (m x {N_CH}); got "
                             f"{x.shape}, {P.shape}, {channels.shape}")
        return Belief(np.concatenate([[n, channels.shape[0], t], x, P.ravel(), channels.ravel()]))

    @property
    def n(self) -> int:
        return int(self.data[0])

    @property
    def m(self) -> int:
        return int(self.data[1])

    @property
    def t(self) -> float:
        """Time of the last sample processed (NaN before the first)."""
        return float(self.data[2])

    @property
    def x(self) -> np.ndarray:
        """Prior state estimate [z, psi, w, r, b_w, b_r] for the next sample."""
        return _ro(self.data[3:3 + self.n])

    @property
    def P(self) -> np.ndarray:
        n = self.n
        return _ro(self.data[3 + n:3 + n + n * n].reshape(n, n))

    @property
    def channels(self) -> np.ndarray:
        """m x N_CH management state (layout in rovlab.estimation.fusion)."""
        n, m = self.n, self.m
        return _ro(self.data[3 + n + n * n:3 + n + n * n + m * N_CH].reshape(m, N_CH))

    def to_dict(self) -> dict:
        return {"t": self.t, "x": self.x.tolist(), "P": self.P.tolist(),
                "channels": self.channels.tolist()}

    @staticmethod
    def from_dict(d: Mapping) -> Belief:
        return Belief.make(np.array(d["x"], dtype=float), np.array(d["P"], dtype=float),
                           np.array(d["channels"], dtype=float), float(d.get("t", math.nan)))


class Report:
    """What one step produced: the corrected estimate at t_k and what each channel did.

    A read-only view on the step's output buffer ``[belief after the step | xc, Pc, rep, flags |
    scratch]`` (a plain slotted class: it is created at every step).
    """

    __slots__ = ("data",)

    def __init__(self, data: np.ndarray) -> None:
        self.data = data

    def _o(self) -> tuple[int, int, int]:
        n, m = int(self.data[0]), int(self.data[1])
        return n, m, 3 + n + n * n + m * N_CH

    @property
    def t(self) -> float:
        return float(self.data[2])

    @property
    def x(self) -> np.ndarray:
        """Corrected estimate x_k = [z, psi, w, r, b_w, b_r]."""
        n, _, o = self._o()
        return _ro(self.data[o:o + n])

    @property
    def P(self) -> np.ndarray:
        """Its covariance P_k."""
        n, _, o = self._o()
        return _ro(self.data[o + n:o + n + n * n].reshape(n, n))

    @property
    def channel_report(self) -> np.ndarray:
        """m x N_REP: event, innovation, innovation variance, R used (rovlab.estimation.fusion)."""
        n, m, o = self._o()
        o += n + n * n
        return _ro(self.data[o:o + m * N_REP].reshape(m, N_REP))

    @property
    def channel_state(self) -> np.ndarray:
        """m x N_CH management state after this sample."""
        n, m, _ = self._o()
        return _ro(self.data[3 + n + n * n:3 + n + n * n + m * N_CH].reshape(m, N_CH))

    @property
    def innovation(self) -> np.ndarray:
        return self.channel_report[:, REP_INNOV]

    @property
    def innovation_variance(self) -> np.ndarray:
        return self.channel_report[:, REP_S]

    @property
    def variance_used(self) -> np.ndarray:
        return self.channel_report[:, REP_R]

    @property
    def events(self) -> tuple[str, ...]:
        return tuple(EVENT_NAMES[int(e)] for e in self.channel_report[:, REP_EVENT])

    @property
    def status(self) -> tuple[str, ...]:
        """Per channel after this sample: 'ok', 'recovering', 'off' or 'lost-<reason>'."""
        ch = self.channel_state
        return tuple(status_label(s, r) for s, r in zip(ch[:, CH_STATUS], ch[:, CH_REASON]))

    @property
    def flags(self) -> int:
        """FLAG_INPUT | FLAG_TIME bits of this step."""
        n, m, o = self._o()
        return int(self.data[o + n + n * n + m * N_REP])


@dataclass(frozen=True, eq=False)
class FilterRun:
    """Result of filtering a whole log (one row per sample)."""

    t: np.ndarray
    x: np.ndarray  # N x n corrected estimates
    variance: np.ndarray  # N x n
    status: np.ndarray  # N x m, int8 STATUS_*
    reason: np.ndarray  # N x m, int8 REASON_*
    event: np.ndarray  # N x m, int8 EVENT_*
    innovation: np.ndarray  # N x m (prior innovation; NaN without a usable sample)
    innovation_variance: np.ndarray  # N x m
    flags: np.ndarray  # N, int8
    belief: Any  # after the last sample: a Belief (DepthHeadingFilter), the component (rovlab.estimation.offline)
    states: tuple[str, ...]
    channels: tuple[str, ...]

    def status_labels(self, j: int) -> list[str]:
        labels = {}
        out = []
        for s, r in zip(self.status[:, j].tolist(), self.reason[:, j].tolist()):
            key = (s, r)
            if key not in labels:
                labels[key] = status_label(s, r)
            out.append(labels[key])
        return out

    def lost_fraction(self) -> dict[str, float]:
        """Share of samples each channel spent lost or off."""
        return {name: float(np.mean(self.status[:, j] >= STATUS_LOST)) for j, name in enumerate(self.channels)}


class DepthHeadingFilter:
    """The discrete Kalman filter of one :class:`FilterModel` (immutable; state lives in Beliefs)."""

    def __init__(self, model: FilterModel) -> None:
        self.model = model
        self.n = len(model.states)
        self.m = len(model.channels)
        self.p = model.Delta.shape[1]
        self.H = np.ascontiguousarray(model.H)
        self.cfg = model.channel_config()
        self.wrap = model.wrap_states()
        self.packed = pack_model(model.Phi, model.Delta, model.Q, self.H, self.cfg, self.wrap)
        self._out_size = _out_size(self.n, self.m)

    @classmethod
    def from_files(cls, vehicle: str = "udrone", config: str = "default") -> DepthHeadingFilter:
        from rovlab.estimation.model import build_filter_model
        from rovlab.params.design import load_design_config
        from rovlab.params.vehicle import load_vehicle

        return cls(build_filter_model(load_vehicle(vehicle), load_design_config(config)))

    @property
    def channels(self) -> tuple[str, ...]:
        return self.model.channel_names

    def channel_index(self, name: str) -> int:
        try:
            return self.channels.index(name)
        except ValueError:
            raise KeyError(f"no channel {name!r}; the filter fuses {', '.join(self.channels)}") from None

    # -- beliefs ------------------------------------------------------------------------------
    def initial_belief(self, x0: np.ndarray | None = None, P0: np.ndarray | None = None) -> Belief:
        x = self.model.x0 if x0 is None else np.asarray(x0, dtype=float)
        P = self.model.P0 if P0 is None else np.asarray(P0, dtype=float)
        if x.shape != (self.n,) or P.shape != (self.n, self.n):
            raise ValueError(f"x0 must have {self.n} entries and P0 be {self.n}x{self.n}")
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
            raise ValueError("x0 and P0 must be finite")
        if not np.allclose(P, P.T, rtol=1e-12, atol=0.0) or np.min(np.linalg.eigvalsh(0.5 * (P + P.T))) < \
                -1e-12 * max(1.0, float(np.max(np.abs(P)))):
            raise ValueError("P0 must be symmetric positive semi-definite")
        return Belief.make(x, 0.5 * (P + P.T), new_channel_state(self.m))

    def with_mode(self, belief: Belief, channel: str, mode: str) -> Belief:
        """A copy of ``belief`` with a channel forced 'off', forced 'on' or back to 'auto'."""
        if mode not in MODE_NAMES:
            raise ValueError(f"mode must be one of {', '.join(MODE_NAMES)}, got {mode!r}")
        ch = belief.channels.copy()
        ch[self.channel_index(channel), CH_MODE] = {"auto": MODE_AUTO, "off": MODE_OFF, "on": MODE_ON}[mode]
        return Belief.make(belief.x, belief.P, ch, belief.t)

    def status(self, belief: Belief) -> dict[str, str]:
        ch = belief.channels
        return {name: status_label(ch[j, CH_STATUS], ch[j, CH_REASON]) for j, name in enumerate(self.channels)}

    # -- one sample -----------------------------------------------------------------------------
    def _y(self, y) -> np.ndarray:
        if y is None:
            return np.full(self.m, np.nan)
        if isinstance(y, Mapping):
            arr = np.full(self.m, np.nan)
            for name, value in y.items():
                arr[self.channel_index(name)] = np.nan if value is None else float(value)
            return arr
        return np.asarray(y, dtype=float)

    def step(self, belief: Belief, t: float, u: np.ndarray, y, present: np.ndarray | None = None
             ) -> tuple[Belief, Report]:
        """Correct with the samples of time t, report x_k, project with u: (next belief, report).

        ``y``: array in channel order (NaN = no sample; inf = a faulty sample) or a mapping
        {channel name: value or None}. ``present`` (bool per channel) marks samples explicitly,
        so that a NaN marked present counts as a faulty sample.
        """
        if type(y) is not np.ndarray:
            y = self._y(y)
        if type(u) is not np.ndarray:
            u = np.asarray(u, dtype=float)
        out = _empty(self._out_size)
        if present is None:
            _online(self.packed, belief.data, t, u, y, out)
        else:
            _online_present(self.packed, belief.data, t, u, y, np.asarray(present, dtype=np.bool_), out)
        b = _new(Belief)
        _setattr(b, "data", out)
        return b, Report(out)

    def correct(self, belief: Belief, t: float, y, present: np.ndarray | None = None
                ) -> tuple[Belief, Report]:
        """Only the correction: the returned belief holds the corrected x_k, P_k."""
        x, P, ch = belief.x.copy(), belief.P.copy(), belief.channels.copy()
        y = self._y(y)
        if y.shape != (self.m,):
            raise ValueError(f"y must have one value per channel ({', '.join(self.channels)}), got shape {y.shape}")
        pres = ~np.isnan(y) if present is None else np.asarray(present, dtype=np.bool_)
        rep = np.empty((self.m, N_REP))
        kf_correct(self.packed, x, P, ch, float(t), y, pres, rep, kf_workspace(self.n, self.m))
        new = Belief.make(x, P, ch, float(t))
        return new, Report(np.concatenate([new.data, x, P.ravel(), rep.ravel(), [0.0]]))

    def predict(self, belief: Belief, u: np.ndarray) -> Belief:
        """Only the projection over one step h with the input u held."""
        x, P = belief.x.copy(), belief.P.copy()
        u = np.asarray(u, dtype=float)
        if u.shape != (self.p,):
            raise ValueError(f"u must have {self.p} values (Z, N), got shape {u.shape}")
        kf_predict(self.packed, x, P, u, kf_workspace(self.n, self.m))
        return Belief.make(x, P, belief.channels, belief.t)

    # -- a whole log ------------------------------------------------------------------------
    def run(self, t: np.ndarray, u: np.ndarray, y: np.ndarray, *, present: np.ndarray | None = None,
            belief: Belief | None = None, n_predict: np.ndarray | None = None,
            hold_input: bool = True) -> FilterRun:
        """Filter N samples in one compiled loop.

        t (N), u (N x p), y (N x m) in channel order with NaN = no sample (unless ``present``
        says otherwise). ``hold_input``: a non-finite input entry repeats the previous value
        (0 before the first), as a zero-order hold would. ``n_predict`` (N, default 1): number
        of steps h to project after each sample (see :func:`steps_between`).
        """
        t = np.ascontiguousarray(t, dtype=float)
        N = t.size
        u = np.ascontiguousarray(np.asarray(u, dtype=float).reshape(N, self.p))
        y = np.ascontiguousarray(np.asarray(y, dtype=float).reshape(N, self.m))
        if hold_input and not np.all(np.isfinite(u)):
            u = hold_last(u)
        pres = (~np.isnan(y)) if present is None else np.ascontiguousarray(present, dtype=np.bool_)
        npred = np.ones(N, dtype=np.int64) if n_predict is None else np.ascontiguousarray(n_predict,
                                                                                          dtype=np.int64)
        if pres.shape != (N, self.m) or npred.shape != (N,) or np.any(npred < 0):
            raise ValueError("present must be N x m and n_predict N non-negative counts")
        b = self.initial_belief() if belief is None else belief
        if b.n != self.n or b.m != self.m:
            raise ValueError(f"the belief (n = {b.n}, m = {b.m}) does not belong to this filter "
                             f"(n = {self.n}, m = {self.m})")
        x, P, ch = b.x.copy(), b.P.copy(), b.channels.copy()
        X = np.empty((N, self.n))
        V = np.empty((N, self.n))
        status = np.empty((N, self.m), dtype=np.int8)
        reason = np.empty((N, self.m), dtype=np.int8)
        event = np.empty((N, self.m), dtype=np.int8)
        innov = np.empty((N, self.m))
        S = np.empty((N, self.m))
        flags = np.empty(N, dtype=np.int8)
        kf_run(self.packed, x, P, ch, t, u, y, pres, npred, X, V, status, reason, event, innov, S, flags)
        final = Belief.make(x, P, ch, float(t[-1]) if N else b.t)
        return FilterRun(t=t, x=X, variance=V, status=status, reason=reason, event=event, innovation=innov,
                         innovation_variance=S, flags=flags, belief=final, states=self.model.states,
                         channels=self.channels)


def hold_last(u: np.ndarray, initial: np.ndarray | None = None) -> np.ndarray:
    """Replace non-finite entries by the last finite value above them (``initial``, default 0,
    before the first: the value held from an earlier chunk of the same log)."""
    u = np.array(u, dtype=float)
    for col in range(u.shape[1]):
        v = u[:, col]
        ok = np.isfinite(v)
        if ok.all():
            continue
        start = 0.0 if initial is None or not math.isfinite(initial[col]) else float(initial[col])
        idx = np.where(ok, np.arange(v.size), -1)
        np.maximum.accumulate(idx, out=idx)
        u[:, col] = np.where(idx >= 0, v[np.maximum(idx, 0)], start)
    return u


MAX_GAP_STEPS = 10_000  # a longer gap (in filter samples) restarts the offline filter from its prior
MAX_ABS_SAMPLE = 1e6  # |sample| or |input| beyond this (SI) is a faulty value, like inf


def plan_steps(dt: np.ndarray, h: float, *, tolerance: float = 0.25, max_steps: int | None = MAX_GAP_STEPS
               ) -> tuple[np.ndarray, np.ndarray, int | None]:
    """(predictions per interval, restart per interval, index of the first bad interval or None).

    ``dt``: the intervals between consecutive samples. An interval of k filter samples (k h,
    within ``tolerance * h``) is bridged by k predictions (dead reckoning through a gap). One of
    more than ``max_steps`` samples is not predicted through: ``restart`` marks it, and the
    filter starts again from its prior at the sample after it (the work stays bounded whatever
    the gap: 1e8 s at h = 0.1 s would be 1e9 predictions). Computed in floating point, so that
    absurd intervals (1e18 s) cannot overflow an integer. Not positive, not finite (without a
    ``max_steps``) or off the grid by more than ``tolerance``: bad.
    """
    dt = np.asarray(dt, dtype=float)
    with np.errstate(over="ignore", invalid="ignore"):
        return _plan_steps(dt, np.rint(dt / h), h, tolerance, max_steps)


def _plan_steps(dt, k, h, tolerance, max_steps):
    n = np.ones(dt.size, dtype=np.int64)
    restart = np.zeros(dt.size, dtype=bool)
    if max_steps is not None:
        restart = (dt > 0) & ~(k <= max_steps)  # includes an infinite interval (overflowed difference)
    off = np.abs(dt - k * h) > tolerance * h
    bad = ~restart & ((k < 1) | off | ~np.isfinite(dt) | (k > 2.0 ** 53))
    first = int(np.argmax(bad)) if bad.any() else None
    ok = ~restart & ~bad
    n[ok] = k[ok].astype(np.int64)
    n[restart] = 0
    return n, restart, first


def steps_between(t: np.ndarray, h: float, *, tolerance: float = 0.25) -> tuple[np.ndarray, int | None]:
    """(predictions after each sample, index of the first bad interval or None).

    A log sampled at the filter's rate has t_{k+1} - t_k = h: one prediction per sample. A gap
    of a whole number of samples is bridged by that many predictions (dead reckoning through
    the gap). An interval further than ``tolerance * h`` from a multiple of h, or not positive,
    cannot be filtered with this discretisation: its index (k + 1) is returned. (No limit on a
    gap here: :class:`StreamingFilter` restarts after long ones.)
    """
    t = np.asarray(t, dtype=float)
    n = np.ones(t.size, dtype=np.int64)
    if t.size < 2:
        return n, None
    steps, _, bad = plan_steps(np.diff(t), h, tolerance=tolerance, max_steps=None)
    if bad is not None:
        return n, bad + 1
    n[:-1] = steps
    return n, None


class IntervalError(ValueError):
    """An interval between two samples that is no whole number of filter samples."""

    def __init__(self, row: int, dt: float, h: float) -> None:
        super().__init__(f"row {row}: a step of {dt:.6g} s is no whole number of h = {h:g} s")
        self.row, self.dt, self.h = row, dt, h


class StreamingFilter:
    """The offline filter over a log fed a chunk of rows at a time (memory flat on long logs).

    Each :meth:`feed` returns the :class:`FilterRun` pieces of the rows it could finish: the
    last row of a chunk waits for the next chunk (its projection depends on the interval to the
    following row); ``final=True`` finishes everything. Rows fed in the order of the log.

    Bounded, explained behaviour on absurd logs (documented in docs/estimation.md):

    * a gap of more than ``max_gap_steps`` filter samples restarts the filter from its prior
      (initial belief) at the row after it (``restarts`` counts them, ``restart_rows`` lists the
      first few);
    * a sample or input beyond +-``MAX_ABS_SAMPLE`` (1e6, SI) counts as faulty, exactly like
      inf: the channel reports it not finite, an input is held (``absurd`` counts them);
    * a non-finite input repeats the previous finite one (zero-order hold), across chunks.
    """

    def __init__(self, filt: Any, *, max_gap_steps: int = MAX_GAP_STEPS,
                 tolerance: float = 0.25) -> None:
        self.filt = filt
        self.h = filt.model.h
        self.max_gap_steps = int(max_gap_steps)
        self.tolerance = tolerance
        self.belief = filt.initial_belief()
        self.row = 0  # log index of the first row not returned yet
        self.restarts = 0
        self.restart_rows: list[int] = []
        self.absurd = 0
        self._pending: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._restart_next = False
        self._u_last = np.zeros(filt.p)

    def feed(self, t: np.ndarray, u: np.ndarray, y: np.ndarray, *, final: bool = False) -> list[FilterRun]:
        t = np.asarray(t, dtype=float).ravel()
        u = np.asarray(u, dtype=float).reshape(t.size, self.filt.p)
        y = np.array(y, dtype=float).reshape(t.size, self.filt.m)
        big = np.abs(y) > MAX_ABS_SAMPLE
        big_u = np.abs(u) > MAX_ABS_SAMPLE
        self.absurd += int(big.sum() + big_u.sum())
        if big.any():
            y[big] = np.inf  # a faulty sample, not a missing one
        if big_u.any():
            u = np.where(big_u, np.nan, u)
        u = hold_last(u, self._u_last)
        if u.shape[0]:
            self._u_last = u[-1].copy()
        if self._pending is not None:
            pt, pu, py = self._pending
            t, u, y = np.concatenate([pt, t]), np.concatenate([pu, u]), np.concatenate([py, y])
        if t.size == 0:
            return []
        done = t.size if final else t.size - 1
        self._pending = None if final else (t[-1:].copy(), u[-1:].copy(), y[-1:].copy())
        if done == 0:
            return []
        # interval i lies between rows i and i + 1; the last row of a final chunk projects once
        steps, gap, bad = plan_steps(np.diff(t), self.h, tolerance=self.tolerance, max_steps=self.max_gap_steps)
        if bad is not None:
            raise IntervalError(self.row + bad + 1, float(t[bad + 1] - t[bad]), self.h)
        n_predict = np.ones(done, dtype=np.int64)
        n_predict[:min(done, steps.size)] = steps[:done]
        restart = np.zeros(done, dtype=bool)  # restart[i]: start again from the prior at row i
        restart[0] = self._restart_next
        restart[1:] = gap[:done - 1]
        self._restart_next = bool(gap[done - 1]) if done < t.size else False
        runs = []
        cuts = [0] + np.flatnonzero(restart).tolist() + [done]
        for a, b in zip(cuts[:-1], cuts[1:]):
            if b <= a:
                continue
            if restart[a]:
                self.restarts += 1
                if len(self.restart_rows) < 5:
                    self.restart_rows.append(self.row + a)
                self.belief = self.filt.initial_belief()
            run = self.filt.run(t[a:b], u[a:b], y[a:b], belief=self.belief, n_predict=n_predict[a:b],
                                hold_input=False)
            self.belief = run.belief
            runs.append(run)
        self.row += done
        return runs


def status_code_names() -> dict[str, tuple[str, ...]]:
    """Names of the integer codes used in FilterRun.status/reason/event."""
    from rovlab.estimation.fusion import REASON_NAMES

    return {"status": STATUS_NAMES, "reason": REASON_NAMES, "event": EVENT_NAMES}


__all__ = (
    "Belief", "DepthHeadingFilter", "FLAG_INPUT", "FLAG_TIME", "FilterRun", "IntervalError", "MAX_ABS_SAMPLE",
    "MAX_GAP_STEPS", "Report", "StreamingFilter", "hold_last", "kf_correct", "kf_predict", "kf_run", "kf_step",
    "kf_update_scalar", "plan_steps", "steps_between",
)
