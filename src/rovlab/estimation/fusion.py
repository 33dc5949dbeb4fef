"""Sensor fusion and automatic dead reckoning: per-channel sensor management (SPEC section 5).

Every fused measurement is a *channel* j (e.g. ``qualisys.z``) with a row h_j of H, a nominal
variance R_j and its own management state. At each sample the compiled kernel
:func:`manage_channels` decides, channel by channel, whether the sample is used:

* **no sample** (``present[j]`` false): nothing to use. If no finite sample has arrived for
  longer than ``timeout`` the channel is declared LOST (reason TIMEOUT). The filter then simply
  runs without that row -- dead reckoning when no channel is left.
* **non-finite sample** (NaN or inf marked present): LOST at once (reason NONFINITE); the value
  never reaches the state.
* **innovation gate**: with the prior x^-, P^- of this sample, nu = y - offset - h x^- (wrapped
  to (-pi, pi] for angle channels) and S = h P^- h^T + R_eff; the sample passes when
  nu^2 / S <= chi2_{1}(p) (the gate threshold; infinite = no gate). A failing sample is not used
  (event REJECTED); ``lose_after`` consecutive failures declare the channel LOST (reason GATE).
  Gating is done against the prior of the whole sample, so its outcome does not depend on the
  order of the channels.
* **consensus**: a sample that fails the gate is used anyway when another channel of the same
  state also fails it and the two samples agree with each other within the gate (chi-square on
  their difference, variance R_i + R_j). Two independent sensors that agree with each other but
  not with the prediction mean the prediction is wrong -- an overconfident prior (P0 = 0 in the
  thesis design) or an unmodelled force such as uDrone's 6.7 N of buoyancy before the bias has
  converged -- and rejecting them would leave the filter dead-reckoning on the wrong model.
  Both samples must still pass the gate with R widened 1e4 times (as a returning sensor is
  tested), so two sensors reporting the same absurd value do not overrule the model.
* **recovery with a transitional variance**: a LOST channel whose sample passes the gate
  (tested with R = factor * R_j) becomes RECOVERING: its variance starts at factor * R_j and
  decays geometrically, R_eff = R_j * factor^(1 - s), s = (t - t_return) / ramp_time, to R_j,
  when the channel is OK again. This avoids the jump in the velocity estimate that a sudden
  return to a precise sensor causes (SPEC section 7, case 3).
* **re-acquisition**: a LOST channel whose samples keep failing the gate for ``reacquire`` seconds
  is re-admitted anyway (RECOVERING): a sensor that disagrees with the model for that long points
  to a diverged estimate rather than to an outlier, and dead reckoning forever is the worse
  failure. 0 disables this.
* **manual override** (``ch[j, CH_MODE]``): MODE_OFF forces the channel off (status OFF, samples
  ignored); releasing it to MODE_AUTO returns through the recovery path; MODE_ON uses every
  finite sample without gating (the transitional variance still applies after a loss).

Layouts (module constants, usable inside numba code):

* ``cfg[j, :]`` (float64, m x N_CFG, constant): CFG_OFFSET (subtracted from the raw sample: the
  lever-arm correction z_VO = z_sensor - l_z), CFG_R (nominal variance), CFG_TIMEOUT [s],
  CFG_GATE (chi-square threshold on nu^2/S; inf = off), CFG_LOSE_AFTER (count), CFG_RAMP_TIME
  [s] (0 = no ramp), CFG_RAMP_FACTOR (>= 1), CFG_ANGLE (1.0: wrap the innovation),
  CFG_REACQUIRE [s] (0 = never), CFG_STATE (i when the row h_j of H is the unit vector e_i,
  which enables a faster update; -1 for a general row).
* ``ch[j, :]`` (float64, m x N_CH, part of the belief): CH_STATUS (STATUS_*), CH_REASON
  (REASON_*, why it is lost/off), CH_MODE (MODE_*), CH_FAILS (consecutive gate failures),
  CH_LAST_T (time of the last finite sample; NaN = none yet, set to the first step's time),
  CH_RAMP_T0 (start of the current recovery ramp), CH_FAIL_T0 (time of the first failure of the
  current run).
* ``rep[j, :]`` (float64, m x N_REP, per-step report): REP_EVENT (EVENT_*), REP_INNOV
  (prior innovation, NaN without a usable sample), REP_S (its variance h P^- h^T + R_eff),
  REP_R (R_eff used or that would be used).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from rovlab.core.angles import wrap_angle  # noqa: F401  (re-exported for the filter kernels)

# channel configuration columns
CFG_OFFSET, CFG_R, CFG_TIMEOUT, CFG_GATE, CFG_LOSE_AFTER, CFG_RAMP_TIME, CFG_RAMP_FACTOR, CFG_ANGLE, \
    CFG_REACQUIRE, CFG_STATE = range(10)
N_CFG = 10
# channel state columns
CH_STATUS, CH_REASON, CH_MODE, CH_FAILS, CH_LAST_T, CH_RAMP_T0, CH_FAIL_T0 = range(7)
N_CH = 7
# report columns
REP_EVENT, REP_INNOV, REP_S, REP_R = range(4)
N_REP = 4

STATUS_OK, STATUS_RECOVERING, STATUS_LOST, STATUS_OFF = 0, 1, 2, 3
REASON_NONE, REASON_TIMEOUT, REASON_NONFINITE, REASON_GATE, REASON_MANUAL = 0, 1, 2, 3, 4
MODE_AUTO, MODE_OFF, MODE_ON = 0, 1, 2
EVENT_NONE, EVENT_USED, EVENT_REJECTED, EVENT_NONFINITE, EVENT_IGNORED = 0, 1, 2, 3, 4

STATUS_NAMES = ("ok", "recovering", "lost", "off")
REASON_NAMES = ("", "timeout", "nonfinite", "gate", "manual")
MODE_NAMES = ("auto", "off", "on")
EVENT_NAMES = ("none", "used", "rejected", "nonfinite", "ignored")



def new_channel_state(m: int) -> np.ndarray:
    """Initial management state of m channels: OK, automatic, no sample seen yet."""
    ch = np.zeros((m, N_CH))
    ch[:, CH_LAST_T] = np.nan
    ch[:, CH_RAMP_T0] = np.nan
    ch[:, CH_FAIL_T0] = np.nan
    return ch


def status_label(status: int, reason: int) -> str:
    """'ok', 'recovering', 'off' or 'lost-<reason>' (e.g. 'lost-timeout')."""
    name = STATUS_NAMES[int(status)]
    if int(status) == STATUS_LOST:
        return f"lost-{REASON_NAMES[int(reason)] or 'unknown'}"
    return name


_PENDING = -1.0  # REP_EVENT while the step's decisions are being made


@njit(cache=True, inline="always")
def _fails_prior(rep, cfg, j):
    nu = rep[j, REP_INNOV]
    return not (nu * nu <= cfg[j, CFG_GATE] * rep[j, REP_S])


_CONSENSUS_WIDENING = 1e4  # consensus only within the gate with R widened this much (as on recovery)


@njit(cache=True, inline="always")
def _plausible(rep, cfg, j):
    """Within the gate with the measurement variance widened by _CONSENSUS_WIDENING: rules out
    absurd samples (two sensors reporting the same garbage must not overrule the model)."""
    nu = rep[j, REP_INNOV]
    return nu * nu <= cfg[j, CFG_GATE] * (rep[j, REP_S] + (_CONSENSUS_WIDENING - 1.0) * rep[j, REP_R])


@njit(cache=True)
def _agrees_with_another(rep, cfg, value, j, m):
    """Consensus: another pending channel of the same state also fails the prior gate, and its
    (offset-corrected) sample agrees with channel j's within the gate (chi-square on the
    difference, variance R_j + R_i). Two independent sensors that agree with each other but not
    with the prediction say the prediction is wrong (an overconfident prior, an unmodelled force),
    not that both sensors failed at once."""
    k = int(cfg[j, CFG_STATE])
    if k < 0 or not _plausible(rep, cfg, j):
        return False
    for i in range(m):
        if i == j or math.isnan(rep[i, REP_INNOV]) or int(cfg[i, CFG_STATE]) != k:
            continue  # only channels with a usable sample of the same state this step
        if not _fails_prior(rep, cfg, i) or not _plausible(rep, cfg, i):
            continue  # channel i agrees with the prediction (j is the odd one out), or is absurd
        d = value[j] - value[i]
        if cfg[j, CFG_ANGLE] != 0.0:
            d = wrap_angle(d)
        if d * d <= cfg[j, CFG_GATE] * (rep[j, REP_R] + rep[i, REP_R]):
            return True
    return False


@njit(cache=True, inline="always")
def manage_channels(x, P, ch, H, cfg, t, y, present, rep, value) -> int:
    """Decide which samples of this step are used; update ``ch`` and ``rep`` in place.

    x (n), P (n x n): the prior of this sample. ch (m x N_CH), cfg (m x N_CFG), H (m x n),
    y (m), present (m, bool), rep (m x N_REP). Output value (m): the offset-corrected sample of
    each accepted channel, NaN for the others. Returns the number of accepted channels.
    A non-finite t disables all samples of this step (they are treated as absent).
    """
    m, n = H.shape
    t_ok = math.isfinite(t)
    n_accept = 0
    for j in range(m):
        value[j] = np.nan
        rep[j, REP_EVENT] = EVENT_NONE
        rep[j, REP_INNOV] = np.nan
        rep[j, REP_S] = np.nan
        status = int(ch[j, CH_STATUS])
        reason = int(ch[j, CH_REASON])
        mode = int(ch[j, CH_MODE])
        fails = int(ch[j, CH_FAILS])
        if t_ok and math.isnan(ch[j, CH_LAST_T]):
            ch[j, CH_LAST_T] = t  # the timeout counts from the first step
        r_nom = cfg[j, CFG_R]
        factor = cfg[j, CFG_RAMP_FACTOR]
        ramp = cfg[j, CFG_RAMP_TIME]
        ramps = factor > 1.0 and ramp > 0.0

        if mode == MODE_OFF:
            ch[j, CH_STATUS] = STATUS_OFF
            ch[j, CH_REASON] = REASON_MANUAL
            ch[j, CH_FAILS] = 0.0
            rep[j, REP_R] = np.nan
            if present[j]:
                rep[j, REP_EVENT] = EVENT_IGNORED
            continue
        if status == STATUS_OFF:  # released by hand: come back through the recovery path
            status = STATUS_LOST
            reason = REASON_MANUAL

        # variance this channel would be used with now
        r_eff = r_nom
        if status == STATUS_RECOVERING:
            frac = 1.0
            if ramps and t_ok:
                frac = max((t - ch[j, CH_RAMP_T0]) / ramp, 0.0)
            if frac >= 1.0:
                status = STATUS_OK
                reason = REASON_NONE
            else:
                r_eff = r_nom * factor ** (1.0 - frac)
        elif status == STATUS_LOST and ramps:
            r_eff = r_nom * factor
        rep[j, REP_R] = r_eff

        if not (present[j] and t_ok):
            if t_ok and status != STATUS_LOST and t - ch[j, CH_LAST_T] > cfg[j, CFG_TIMEOUT]:
                status = STATUS_LOST
                reason = REASON_TIMEOUT
                fails = 0
            ch[j, CH_STATUS] = status
            ch[j, CH_REASON] = reason
            ch[j, CH_FAILS] = fails
            continue

        v = y[j] - cfg[j, CFG_OFFSET]
        idx = int(cfg[j, CFG_STATE])
        if idx >= 0:
            hx = x[idx]
            s = r_eff + P[idx, idx]
        else:
            hx = 0.0
            s = r_eff
            for i in range(n):
                hi = H[j, i]
                if hi != 0.0:
                    hx += hi * x[i]
                    for k in range(n):
                        s += hi * P[i, k] * H[j, k]
        nu = v - hx
        if cfg[j, CFG_ANGLE] != 0.0:
            nu = wrap_angle(nu)
        if not (math.isfinite(v) and math.isfinite(nu) and math.isfinite(s) and s > 0.0):
            ch[j, CH_STATUS] = STATUS_LOST
            ch[j, CH_REASON] = REASON_NONFINITE
            ch[j, CH_FAILS] = 0.0
            rep[j, REP_EVENT] = EVENT_NONFINITE
            continue
        ch[j, CH_LAST_T] = t
        rep[j, REP_INNOV] = nu
        rep[j, REP_S] = s
        # the decision waits until every channel's innovation is known (consensus below)
        value[j] = v
        rep[j, REP_EVENT] = _PENDING
        ch[j, CH_STATUS] = status
        ch[j, CH_REASON] = reason
        ch[j, CH_FAILS] = fails

    for j in range(m):
        if rep[j, REP_EVENT] != _PENDING:
            continue
        status = int(ch[j, CH_STATUS])
        reason = int(ch[j, CH_REASON])
        mode = int(ch[j, CH_MODE])
        fails = int(ch[j, CH_FAILS])
        ramps = cfg[j, CFG_RAMP_FACTOR] > 1.0 and cfg[j, CFG_RAMP_TIME] > 0.0
        passed = mode == MODE_ON or not _fails_prior(rep, cfg, j)
        if (not passed and status == STATUS_LOST and fails > 0 and cfg[j, CFG_REACQUIRE] > 0.0
                and t - ch[j, CH_FAIL_T0] >= cfg[j, CFG_REACQUIRE]):
            passed = True  # re-acquisition: it has disagreed for too long to be an outlier
        if not passed and _agrees_with_another(rep, cfg, value, j, m):
            passed = True  # the sensors agree with each other, not with the prediction: the model is off
        if passed:
            if status == STATUS_LOST:
                if ramps:
                    status = STATUS_RECOVERING
                    ch[j, CH_RAMP_T0] = t
                else:
                    status = STATUS_OK
                reason = REASON_NONE
            fails = 0
            rep[j, REP_EVENT] = EVENT_USED
            n_accept += 1
        else:
            if fails == 0:
                ch[j, CH_FAIL_T0] = t
            fails += 1
            if status != STATUS_LOST and fails >= cfg[j, CFG_LOSE_AFTER]:
                status = STATUS_LOST
                reason = REASON_GATE
            rep[j, REP_EVENT] = EVENT_REJECTED
        ch[j, CH_STATUS] = status
        ch[j, CH_REASON] = reason
        ch[j, CH_FAILS] = fails
    for j in range(m):
        if rep[j, REP_EVENT] != EVENT_USED:
            value[j] = np.nan
    return n_accept
