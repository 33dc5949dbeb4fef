"""A complementary depth-and-heading filter: the estimator of rovlab's plugin example.

States z, psi, w, r. Between samples the filter integrates a simple heave and yaw model,
w_dot = (Z - d_w w - (B - W)) / m_w and r_dot = (N - d_r r) / m_r (the vehicle's rigid-body and
added mass, its linear damping and net buoyancy B - W; what it leaves out, the corrections take up). A sample of z or psi pulls
the position by ``k_pos`` times the innovation and the rate by ``k_vel`` times it per second; a
sample of w or r pulls the rate by ``k_rate``: the classic second-order complementary filter
(e.g. Fossen 2011, sec. 11.2, fixed-gain observers). It keeps no covariance: ``P`` is a fixed
nominal diagonal from the [complementary] table, so the NEES the simulator logs is only indicative.

The channels' bookkeeping is rovlab's (``ch``, ``rep``: rovlab.estimation.layout): a channel with no
sample for ``timeout_s`` is reported lost (timeout), and back to ok with its next sample.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from rovlab.core.components import ComponentInfo, EstimatorSpec, register_component, register_estimator
from rovlab.estimation.layout import (
    CH_LAST_T,
    CH_REASON,
    CH_STATUS,
    EVENT_USED,
    REASON_NONE,
    REASON_TIMEOUT,
    REP_EVENT,
    REP_INNOV,
    REP_R,
    REP_S,
    STATUS_LOST,
    STATUS_OK,
    new_channel_state,
)
from rovlab.estimation.model import make_channels
from rovlab.models.kinetics import mass_matrix

STATES = ("z", "psi", "w", "r")
_INDEX = {q: i for i, q in enumerate(STATES)}


@dataclass(frozen=True)
class ComplementaryConfig:
    """The [complementary] table of a design file (SI units)."""

    k_pos: float = 0.5  # position (z, psi) correction per sample, times the innovation
    k_vel: float = 1.0  # rate (w, r) correction per second of position innovation [1/s]
    k_rate: float = 0.5  # rate correction per rate sample, times the innovation
    timeout_s: float = 0.5  # a channel with no sample this long is lost
    nominal_std: tuple[float, float, float, float] = (0.01, 0.02, 0.02, 0.02)  # sqrt(diag P) reported
    source: str = "rovlab_example_plugin defaults"


class Complementary(NamedTuple):
    """The component: constants, then the state the loop reads (x, P, ch)."""

    q: np.ndarray  # (m) int64: state index of each channel's quantity
    angle: np.ndarray  # (m) bool: the channel measures the heading (innovation wrapped)
    offset: np.ndarray  # (m) lever-arm offset of each channel (rovlab.estimation.model.Channel.offset)
    variance: np.ndarray  # (m) the channel's variance (reported as part of S)
    k_pos: float
    k_vel: float
    k_rate: float
    timeout: float
    h: float
    m_w: float
    d_w: float
    net_up: float  # B - W [N]: the net buoyancy, pushing up (negative z)
    m_r: float
    d_r: float
    x: np.ndarray  # (4) z, psi, w, r
    P: np.ndarray  # (4, 4) fixed nominal covariance
    ch: np.ndarray  # (m, N_CH) rovlab's channel bookkeeping


@njit(cache=False)
def _wrap(a):
    return a - 2.0 * math.pi * math.floor((a + math.pi) / (2.0 * math.pi))


@njit(cache=False)
def _correct(est, t, y, present, rep):
    x = est.x
    for j in range(est.q.shape[0]):
        if present[j] and math.isfinite(y[j]):
            i = est.q[j]
            e = y[j] - est.offset[j] - x[i]
            if est.angle[j]:
                e = _wrap(e)
            if i < 2:  # a position: pull it and its rate
                x[i] += est.k_pos * e
                x[i + 2] += est.k_vel * est.h * e
            else:  # a rate
                x[i] += est.k_rate * e
            rep[j, REP_EVENT] = EVENT_USED
            rep[j, REP_INNOV] = e
            rep[j, REP_S] = est.P[i, i] + est.variance[j]
            rep[j, REP_R] = est.variance[j]
            est.ch[j, CH_LAST_T] = t
            est.ch[j, CH_STATUS] = STATUS_OK
            est.ch[j, CH_REASON] = REASON_NONE
        elif not t - est.ch[j, CH_LAST_T] <= est.timeout:  # (no sample yet counts from the start)
            if not math.isnan(est.ch[j, CH_LAST_T]) or t > est.timeout:
                est.ch[j, CH_STATUS] = STATUS_LOST
                est.ch[j, CH_REASON] = REASON_TIMEOUT
    x[1] = _wrap(x[1])


@njit(cache=False)
def _predict(est, t, tau):
    x = est.x
    h = est.h
    z, psi, w, r = x[0], x[1], x[2], x[3]
    x[0] = z + h * w
    x[1] = _wrap(psi + h * r)
    x[2] = w + h * (tau[2] - est.d_w * w - est.net_up) / est.m_w
    x[3] = r + h * (tau[3] - est.d_r * r) / est.m_r


register_estimator(Complementary, state=("x", "P", "ch"), correct=_correct, predict=_predict)


def build(vehicle, config) -> EstimatorSpec:
    """The filter for a vehicle and a design configuration (its [[measurements]] and sample time,
    the [complementary] table)."""
    from rovlab.params.validate import ConfigError

    cc: ComplementaryConfig = config.table("complementary")
    channels, problems = make_channels(vehicle, config, _INDEX, estimator="complementary")
    if problems:
        raise ConfigError(problems, "filter configuration")
    M = np.diag(mass_matrix(vehicle))
    values = config.model_values(vehicle)
    x0 = np.zeros(4)
    x0[0], x0[1] = config.initial_state[0], config.initial_state[1]
    kernel = Complementary(
        q=np.array([_INDEX[c.quantity] for c in channels], dtype=np.int64),
        angle=np.array([c.quantity == "psi" for c in channels], dtype=np.bool_),
        offset=np.array([c.offset for c in channels], dtype=float),
        variance=np.array([c.variance for c in channels], dtype=float),
        k_pos=cc.k_pos, k_vel=cc.k_vel, k_rate=cc.k_rate, timeout=cc.timeout_s, h=config.sample_time,
        m_w=float(M[2]), d_w=-values["Z_w"], net_up=float(vehicle.buoyancy - vehicle.weight), m_r=float(M[3]),
        d_r=-values["N_r"],
        x=x0, P=np.diag(np.square(cc.nominal_std)), ch=new_channel_state(len(channels)))
    return EstimatorSpec(kernel=kernel, states=STATES, nav=STATES, channels=tuple(channels), h=config.sample_time)


def read_table(t) -> ComplementaryConfig:
    """The [complementary] table, read with rovlab's TableReader (its checks and messages)."""
    base = ComplementaryConfig()
    source = t.string("source")
    k_pos = t.number("k_pos", base.k_pos, positive=True, hi=1.0, what="share of the innovation, 0 < k <= 1")
    k_vel = t.number("k_vel", base.k_vel, nonnegative=True, hi=100.0, what="1/s")
    k_rate = t.number("k_rate", base.k_rate, nonnegative=True, hi=1.0, what="share of the innovation")
    timeout = t.number("timeout_s", base.timeout_s, positive=True, what="s")
    std = t.vector("nominal_std", 4, what="sqrt(diag P) of z, psi, w, r (SI)") if t.has("nominal_std") \
        else np.array(base.nominal_std)
    t.finish()
    return ComplementaryConfig(k_pos, k_vel, k_rate, timeout, tuple(float(v) for v in std), source)


register_component(ComponentInfo(
    "complementary", "estimator", build, description="complementary depth-and-heading filter (plugin example)",
    parse_table=read_table, default_table=ComplementaryConfig, measurable=STATES))
