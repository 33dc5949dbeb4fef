"""The depth-and-heading Kalman filter from Python: beliefs, one step at a time, a whole log.

:class:`DepthHeadingFilter` wraps the compiled kernels of :mod:`rovlab.estimation.kalman` (the
recursion, the sensor management and the packed model are described there):
``step(belief, t, u, y) -> (belief, report)`` with :class:`Belief` an immutable value (x, P,
per-channel management state, time) that can be saved and restored, and ``run(t, u, y)`` for a
whole log (one call of kf_run) giving a :class:`FilterRun`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from rovlab.estimation.fusion import (
    CH_MODE,
    CH_REASON,
    CH_STATUS,
    EVENT_NAMES,
    MODE_AUTO,
    MODE_NAMES,
    MODE_OFF,
    MODE_ON,
    N_CH,
    N_REP,
    REP_EVENT,
    REP_INNOV,
    REP_R,
    REP_S,
    STATUS_LOST,
    STATUS_NAMES,
    new_channel_state,
    status_label,
)
from rovlab.estimation.kalman import (
    _empty,
    _new,
    _online,
    _online_present,
    _out_size,
    _setattr,
    kf_correct,
    kf_predict,
    kf_run,
    kf_workspace,
    pack_model,
)
from rovlab.estimation.model import FilterModel
from rovlab.estimation.streaming import hold_last


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
        self.packed = pack_model(model.Phi, model.Delta, model.Q, self.H, self.cfg, self.wrap,
                                 getattr(model, "input_uncertainty", None))
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


def status_code_names() -> dict[str, tuple[str, ...]]:
    """Names of the integer codes used in FilterRun.status/reason/event."""
    from rovlab.estimation.fusion import REASON_NAMES

    return {"status": STATUS_NAMES, "reason": REASON_NAMES, "event": EVENT_NAMES}


__all__ = ("Belief", "DepthHeadingFilter", "FilterRun", "Report", "status_code_names")
