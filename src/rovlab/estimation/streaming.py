"""A long log through an offline filter, a chunk of rows at a time (memory flat on long logs).

:class:`StreamingFilter` drives a filter with the interface of
rovlab.estimation.filtering.DepthHeadingFilter (``initial_belief``, ``run``; also
rovlab.estimation.offline.ComponentFilter): it puts each row on the filter's grid of sample
times (:func:`period_steps`: the period nearest its time, counted from the log's first row),
fuses the samples of several rows in one period one after another and predicts between periods,
bridges gaps by prediction, restarts from the prior after a gap too long to bridge, treats absurd
values as faulty samples and holds non-finite inputs (:func:`hold_last`). So every sample of a
log is used whatever its rate: a 20 Hz heading at h = 0.1 s (two per period), a 2 Hz pressure
(one every five), jittered time stamps. (:func:`plan_steps` is the stricter rule of the Python
API's one-shot run, rovlab.estimation.filtering: a log on the grid, k h apart.)
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


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


def period_steps(t: np.ndarray, h: float, t_ref: float, *, max_steps: int | None = MAX_GAP_STEPS
                 ) -> tuple[np.ndarray, np.ndarray, int | None]:
    """(predictions between consecutive rows, restart per interval, index of the first bad interval
    or None) for rows at times ``t`` on the grid t_ref + k h: row i belongs to the period nearest
    its time, and the predictions between two rows are the periods between theirs -- 0 for rows in
    the same period (their samples are fused one after another), k for a gap of k periods. More
    than ``max_steps``: a restart (the filter starts again from its prior after it); a time that is
    not finite or a period earlier than the one before: bad. In floating point, so absurd times
    (1e18 s) cannot overflow an integer."""
    t = np.asarray(t, dtype=float)
    with np.errstate(over="ignore", invalid="ignore"):
        period = np.floor((t - t_ref) / h + 0.5)
        k = np.diff(period)
        restart = np.zeros(k.size, dtype=bool)
        if max_steps is not None:
            restart = ~(k <= max_steps) & (k > 0)  # includes an infinite interval
        bad = ~restart & ((k < 0) | ~np.isfinite(k) | (k > 2.0 ** 53))
    first = int(np.argmax(bad)) if bad.any() else None
    n = np.zeros(k.size, dtype=np.int64)
    ok = ~restart & ~bad
    n[ok] = k[ok].astype(np.int64)
    return n, restart, first


class IntervalError(ValueError):
    """An interval between two samples that is no whole number of filter samples."""

    def __init__(self, row: int, dt: float, h: float) -> None:
        super().__init__(f"row {row}: a step of {dt:.6g} s is no whole number of h = {h:g} s")
        self.row, self.dt, self.h = row, dt, h


class StreamingFilter:
    """The offline filter over a log fed a chunk of rows at a time (memory flat on long logs).

    Each :meth:`feed` returns the FilterRun pieces (rovlab.estimation.filtering) of the rows it could finish: the
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

    def __init__(self, filt: Any, *, max_gap_steps: int = MAX_GAP_STEPS) -> None:
        self.filt = filt
        self.h = filt.model.h
        self.max_gap_steps = int(max_gap_steps)
        self.belief = filt.initial_belief()
        self.row = 0  # log index of the first row not returned yet
        self.restarts = 0
        self.restart_rows: list[int] = []
        self.absurd = 0
        self._t_ref: float | None = None  # the grid's origin: the log's first row
        self._pending: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._restart_next = False
        self._u_last = np.zeros(filt.p)

    def feed(self, t: np.ndarray, u: np.ndarray, y: np.ndarray, *, final: bool = False) -> list[Any]:
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
        if self._t_ref is None:
            self._t_ref = float(t[0])
        steps, gap, bad = period_steps(t, self.h, self._t_ref, max_steps=self.max_gap_steps)
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


__all__ = ("IntervalError", "MAX_ABS_SAMPLE", "MAX_GAP_STEPS", "StreamingFilter", "hold_last", "period_steps",
           "plan_steps", "steps_between")
