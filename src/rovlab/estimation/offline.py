"""Any estimator over a log: the offline filter of ``rovlab filter --estimator NAME``.

The simulator and the vehicle node run an estimator through its slots (rovlab.core.components:
``estimator_correct`` with the samples of a step, ``estimator_predict`` with the wrench); so does
this module, over the rows of a log, so the offline and the in-loop estimator are the same
component. :class:`ComponentFilter` has the interface of
rovlab.estimation.filtering.DepthHeadingFilter that rovlab.estimation.streaming.StreamingFilter drives (``initial_belief``,
``run``): a log is filtered in chunks, with the same gap handling, restarts and refusals.

The belief between chunks is the component itself (its state arrays, rovlab.core.components.fresh).
Inputs are the wrench [X, Y, Z, N] of each row, held over the interval to the next row.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from rovlab._jit import WITHOUT_NRT, njit
from rovlab.core.components import EstimatorSpec, estimator_correct, estimator_predict, fresh
from rovlab.estimation.kalman import FLAG_TIME  # a row whose time is not finite
from rovlab.estimation.layout import CH_REASON, CH_STATUS, EVENT_NONE, N_REP, REP_EVENT, REP_INNOV, REP_S

WRENCH_COLUMNS = ("tau_X", "tau_Y", "tau_Z", "tau_N")  # the inputs, in the slots' order


class ReplayOut(NamedTuple):
    """What :func:`replay` fills per row (arrays the caller allocates)."""

    X: np.ndarray  # (N, n) corrected estimate
    V: np.ndarray  # (N, n) its variances
    status: np.ndarray  # (N, m) int8
    reason: np.ndarray  # (N, m) int8
    event: np.ndarray  # (N, m) int8
    innov: np.ndarray  # (N, m)
    S: np.ndarray  # (N, m)
    flags: np.ndarray  # (N) int8
    rep: np.ndarray  # (m, N_REP) scratch: the estimator's report of one row


@njit(cache=True, **WITHOUT_NRT)
def replay(est, t, tau, y, present, n_predict, out):
    """Row k of a log: correct the estimator with the samples y[k] (where present[k]), record what
    it reports, then predict n_predict[k] times with the wrench tau[k] (4: X, Y, Z, N)."""
    n = est.x.shape[0]
    m = y.shape[1]
    rep = out.rep
    for k in range(t.shape[0]):
        for j in range(m):  # what an estimator does not report on a channel: no event
            rep[j, REP_EVENT] = EVENT_NONE
            for col in range(1, rep.shape[1]):
                rep[j, col] = math.nan
        estimator_correct(est, t[k], y[k], present[k], rep)
        for i in range(n):
            out.X[k, i] = est.x[i]
            out.V[k, i] = est.P[i, i]
        for j in range(m):
            out.status[k, j] = np.int8(est.ch[j, CH_STATUS])
            out.reason[k, j] = np.int8(est.ch[j, CH_REASON])
            out.event[k, j] = np.int8(rep[j, REP_EVENT])
            out.innov[k, j] = rep[j, REP_INNOV]
            out.S[k, j] = rep[j, REP_S]
        for _ in range(n_predict[k]):
            estimator_predict(est, t[k], tau[k])
        out.flags[k] = np.int8(0 if math.isfinite(t[k]) else FLAG_TIME)


replay_uncached = njit(cache=False, **WITHOUT_NRT)(getattr(replay, "py_func", replay))


@dataclass(frozen=True)
class _Model:
    """What StreamingFilter and ``rovlab filter`` read of a filter's model."""

    h: float
    states: tuple[str, ...]
    channels: tuple[Any, ...]  # rovlab.estimation.model.Channel


class ComponentFilter:
    """An estimator component (an :class:`EstimatorSpec` built by its declaration) run over a log
    chunk by chunk, as rovlab.estimation.filtering.DepthHeadingFilter is."""

    p = len(WRENCH_COLUMNS)

    def __init__(self, spec: EstimatorSpec) -> None:
        self.spec = spec
        self.model = _Model(float(spec.h), tuple(spec.states), tuple(spec.channels))
        self.n = len(spec.states)
        self.m = len(spec.channels)
        kernel = spec.kernel
        self._replay = replay if type(kernel).__module__.startswith("rovlab.") else replay_uncached

    @property
    def channels(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.spec.channels)

    def initial_belief(self) -> Any:
        """The component at its initial state (its own copies of the state arrays)."""
        return fresh(self.spec.kernel)

    def run(self, t: np.ndarray, u: np.ndarray, y: np.ndarray, *, belief: Any = None,
            n_predict: np.ndarray | None = None, present: np.ndarray | None = None, hold_input: bool = False) -> Any:
        """Filter rows t (N), inputs u (N x 4: X, Y, Z, N) and samples y (N x m, NaN = none) from
        ``belief`` (default: the initial one); a rovlab.estimation.filtering.FilterRun whose belief is
        the component after the last row."""
        from rovlab.estimation.filtering import FilterRun
        from rovlab.estimation.streaming import hold_last

        t = np.ascontiguousarray(t, dtype=float)
        N = t.shape[0]
        u = np.ascontiguousarray(np.asarray(u, dtype=float).reshape(N, self.p))
        if hold_input and not np.all(np.isfinite(u)):
            u = np.ascontiguousarray(hold_last(u))
        y = np.ascontiguousarray(np.asarray(y, dtype=float).reshape(N, self.m))
        pres = (~np.isnan(y)) if present is None else np.ascontiguousarray(present, dtype=np.bool_)
        npred = np.ones(N, dtype=np.int64) if n_predict is None else np.ascontiguousarray(n_predict, dtype=np.int64)
        est = fresh(self.spec.kernel if belief is None else belief)
        out = ReplayOut(np.empty((N, self.n)), np.empty((N, self.n)), np.empty((N, self.m), dtype=np.int8),
                        np.empty((N, self.m), dtype=np.int8), np.empty((N, self.m), dtype=np.int8),
                        np.empty((N, self.m)), np.empty((N, self.m)), np.empty(N, dtype=np.int8),
                        np.empty((self.m, N_REP)))
        self._replay(est, t, u, y, pres, npred, out)
        return FilterRun(t=t, x=out.X, variance=out.V, status=out.status, reason=out.reason, event=out.event,
                         innovation=out.innov, innovation_variance=out.S, flags=out.flags, belief=est,
                         states=self.model.states, channels=self.channels)
