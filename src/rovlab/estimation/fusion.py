"""Sensor fusion and automatic dead reckoning: per-channel sensor management (Sandøy 2016, sec. 5.1).

Every fused measurement is a *channel* j (e.g. ``qualisys.z``) with a row h_j of H, a nominal
variance R_j and its own management state. At each sample the compiled kernel
:func:`manage_channels` decides, channel by channel, whether the sample is used and with what
weight. The design (docs/estimation.md explains it with its sources) follows one rule: **a test
that involves the filter's prediction may reject a sample, but a sensor is only declared lost on
evidence that does not depend on the filter being right**, because a filter that is wrong (an
overconfident start, an unmodelled force, a model that does not match the plant) would otherwise
throw away the very sensors that could correct it.

Checks that do not involve the filter (a sensor fault whatever the filter believes):

* **timeout**: no finite sample for longer than ``timeout`` -> LOST (reason TIMEOUT);
* **non-finite sample** (NaN or inf marked present): LOST at once (reason NONFINITE); the value
  never reaches the state;
* **stuck / variance check**: the samples are cut into blocks of ``CFG_STUCK_N`` samples; a
  block whose scatter sum(y - mean y)^2 / R_j falls below the lower chi-square quantile
  ``CFG_STUCK_BOUND`` (N - 1 dof, false-alarm probability 1e-9) is not noise of variance R_j:
  the sensor repeats a frozen value -> LOST (reason STUCK) until a block scatters again. Motion
  of the vehicle only adds scatter, so the check cannot be fooled by the filter or the model.
  With ``CFG_STUCK_BOUND`` = 0 the block is stuck only when every sample in it is the same number
  (the *repetition* check): for a channel whose source is an autopilot's estimate (ArduSub's AHRS
  heading is smooth, so a still vehicle's scatter is far below the white-noise bound R_j: on the
  real log ../shared/data/ardusub/small.tlog the scatter check called 35 % of the rows stuck) or
  a sensor quantised coarser than its noise, where a frozen value is an exact repetition;

Checks against the prediction:

* **innovation gate**: with the prior x^-, P^- of this sample, nu = y - offset - h x^- (wrapped
  to (-pi, pi] for angle channels) and S = h P^- h^T + R_j; the sample passes when
  nu^2 / S <= chi2_{1}(p) (``CFG_GATE``; infinite = no gate). A failing sample is not used
  (event REJECTED); ``lose_after`` consecutive failures declare the channel LOST (reason GATE).
  Gating is done against the prior of the whole sample, so its outcome does not depend on the
  order of the channels.
* **start-up phase**: until ``CFG_STARTUP`` seconds after the first step the gate is not
  applied (every finite sample is used). The gate assumes a consistent filter, which a filter
  that has just started is not: P0 = 0 in the thesis design, a wrong initial state, uDrone's
  6.7 N of net buoyancy not yet in the bias estimate. The default length is computed from the
  design (rovlab.estimation.model.startup_time): the Riccati recursion's convergence from P0
  plus five time constants of the steady-state filter's error dynamics.
* **consensus**: a sample that fails the gate is used anyway when another channel of the same
  state also fails it and the two samples agree with each other within the gate (chi-square on
  their difference, variance R_i + R_j): the prediction is what is wrong. Both samples must
  still pass the gate with R widened 1e4 times, so two sensors reporting the same absurd value
  do not overrule the model.
* **maneuver**: the second failure in a row, with the same sign as the first and not smaller,
  and within sqrt(gate S) + a_m tau^2 / 2 of the prediction (tau: time since the channel's last
  used sample, a_m: ``maneuver_acceleration``), is used with the normal Kalman update -- unless
  a witness refutes it. This is how a change the model missed looks (a float floods, a tether
  pulls): the truth accelerates away from the prediction, so the innovation grows from one
  sample to the next by what a bounded acceleration can do; the first such sample is rejected
  (an outlier cannot be told from it yet), the second is used, and the normal update (not a
  reset of the measured state alone) lets the velocity and bias estimates learn the change
  through their correlations -- the test of what was missed is a maneuver test in the sense of
  Bar-Shalom, Li & Kirubarajan (2001, ch. 11, maneuvering targets): a deviation a bounded unknown acceleration
  explains. An isolated outlier has no second failure; an erratic or offset sensor is outside
  the allowance (or refuted by a witness) and keeps failing. While a maneuver is followed
  (CH_MANEUVER), a first failure in its direction within the allowance is used at once, until a
  sample passes the gate by itself. Before this rule, a 5 N buoyancy
  loss on uDrone had Qualisys z declared lost and under-weighted for seconds, and the vehicle
  sank 0.37 m instead of 2.8 cm (heave-buoyancy-step; 2.5 cm with the gate off).
* **persistence**: a sample that fails the gate right after a sample of the same channel that
  failed it too, by the same amount (chi-square on the difference of the two innovations), is
  used -- unless a witness (below) refutes it. An outlier is isolated; a deviation that persists
  is a change the model missed (a rare large process-noise event, an unmodelled force), and
  rejecting it makes the filter dead-reckon further from the truth with every sample. The
  prediction was then overconfident: the variance of the measured state alone is widened so
  that this innovation is a 1-sigma event (a covariance reset of that state), and the update
  moves that state to the sample without dragging the velocity and bias estimates along through
  P's correlations (their gains shrink as S grows). Scaling all of P instead (the adaptive
  fading filter of Xia et al. 1994) claims the rates and biases are as wrong as the measured
  state and kicked r_hat to several rad/s; spreading the change over the recovery ramp let the
  estimate fall behind a real change of the truth. With no witness a sensor offset cannot be
  told from such a change, and the sensor is followed (as after ``reacquire`` seconds anyway).
* **re-acquisition**: a channel lost by the gate whose samples keep failing it for
  ``reacquire`` seconds is re-admitted (RECOVERING) -- unless a *witness* refutes it: another
  channel of the same state whose sample passes the gate and disagrees with this one beyond the
  gate (chi-square on the difference, R_i + R_j). The model is then corroborated by an
  independent sensor precise enough to tell, and the disagreeing sensor stays out (an offset
  sensor). A witness too imprecise to separate the two samples says nothing. Without a
  witness, disagreeing that long points to a diverged estimate rather than to an outlier, and
  dead reckoning forever is the worse failure. 0 disables this.

**Recovery** (a LOST channel whose sample is accepted): the correction is spread evenly over
the next N = ``CFG_RAMP_N`` samples by under-weighting (Lear's underweighting; Zanetti, DeMars &
Bishop 2010): the k-th sample after the return (k = 1..N) is used with

    R_eff = R_j + (N - k) s,   s = h P^- h^T   (the prior variance of the measured quantity),

i.e. with the gain g_k = s / (R_eff + s) <= 1 / (N - k + 1) on the measured state, whatever P
has grown to during the drop-out. When the drop-out made s >> R_j, sample k removes 1/(N-k+1)
of what is left of the error, so each of the N samples applies about 1/N of the correction (the
other states move in proportion: their gains are scaled by the same factor). The ramp is never
longer than the sensor was away: a channel whose last used sample is T seconds old returns over
min(N, ceil(N T / recovery time)) samples. The error a short absence leaves is small and still
growing with whatever the model missed (a float flooding: the sensor was gated out because the
truth moved away from the prediction), and under-weighting it for the full recovery time made
the estimate trail the moving vehicle for seconds. The covariance
update uses the nominal R_j in the Joseph form, which is exact for any gain, so P stays the
honest covariance of the under-weighted estimate (it shrinks as the error does) and the next
sample's s reflects what is left. After N samples the channel is OK again. N = 0
(``recovery_time_s = 0``) returns abruptly, as the thesis did.
Every sample, returning or not, is gated with the filter's honest S = s + R_j: the
under-weighting changes the gain, not what the filter believes.

**Manual override** (``ch[j, CH_MODE]``): MODE_OFF forces the channel off (status OFF, samples
ignored); releasing it to MODE_AUTO returns through the recovery path; MODE_ON uses every finite
sample without gating (the recovery ramp still applies after a loss).

Layouts (module constants, usable inside numba code):

* ``cfg[j, :]`` (float64, m x N_CFG, constant): CFG_OFFSET (subtracted from the raw sample: the
  lever-arm correction z_VO = z_sensor - l_z), CFG_R (nominal variance), CFG_TIMEOUT [s],
  CFG_GATE (chi-square threshold on nu^2/S; inf = off), CFG_LOSE_AFTER (count), CFG_RAMP_TIME
  [s] (for reports), CFG_RAMP_N (recovery samples N; 0 = abrupt), CFG_ANGLE (1.0: wrap the
  innovation), CFG_REACQUIRE [s] (0 = never), CFG_STATE (i when the row h_j of H is the unit
  vector e_i, which enables a faster update; -1 for a general row), CFG_STARTUP [s],
  CFG_STUCK_N (samples per block; 0 = no stuck check), CFG_STUCK_BOUND (lower bound on the
  block's scatter / R), CFG_MANEUVER (the maneuver allowance a_m, SI units per s^2; 0 = off).
* ``ch[j, :]`` (float64, m x N_CH, part of the belief): CH_STATUS (STATUS_*), CH_REASON
  (REASON_*, why it is lost/off), CH_MODE (MODE_*), CH_FAILS (consecutive gate failures),
  CH_LAST_T (time of the last finite sample; NaN = none yet, set to the first step's time),
  CH_RAMP_T0 (time of the return), CH_FAIL_T0 (time of the first failure of the current run),
  CH_T0 (time of the first step: start of the start-up phase), CH_RAMP_K (samples used since
  the return), CH_STUCK (1 while
  the last block was stuck), CH_BLK_N, CH_BLK_Y0, CH_BLK_S1, CH_BLK_S2 (the current block:
  count, first value, sum and sum of squares of the deviations from it), CH_PREV_NU, CH_PREV_S
  (innovation and its variance of the last sample that failed the gate), CH_USED_T (time of the
  last sample used; NaN = none yet), CH_RAMP_NE (the recovery samples of the current return),
  CH_MANEUVER (+1 or -1 while a maneuver is being followed: the sign of its innovations; 0 = none).
* ``rep[j, :]`` (float64, m x N_REP, per-step report): REP_EVENT (EVENT_*), REP_INNOV
  (prior innovation, NaN without a usable sample), REP_S (its variance h P^- h^T + R_j, what
  the gate tests), REP_R (the variance the sample is weighted with: R_j, or R_eff while
  recovering).

For logs, :func:`status_code` folds status and reason into one small integer whose label is
``STATUS_CODE_LABELS[code]`` (0-3 are the STATUS_* codes themselves, so a log of plain statuses
reads the same way, with 'lost' for an unknown reason).
"""

from __future__ import annotations

import math

import numpy as np

from rovlab._jit import WITHOUT_NRT, njit
from rovlab.core.angles import wrap_angle  # noqa: F401  (re-exported for the filter kernels)
from rovlab.estimation.layout import (  # noqa: F401  (re-exported: the layout and codes live there)
    CFG_ANGLE,
    CFG_GATE,
    CFG_LOSE_AFTER,
    CFG_MANEUVER,
    CFG_OFFSET,
    CFG_R,
    CFG_RAMP_N,
    CFG_RAMP_TIME,
    CFG_REACQUIRE,
    CFG_STARTUP,
    CFG_STATE,
    CFG_STUCK_BOUND,
    CFG_STUCK_N,
    CFG_TIMEOUT,
    CH_BLK_N,
    CH_BLK_S1,
    CH_BLK_S2,
    CH_BLK_Y0,
    CH_FAIL_T0,
    CH_FAILS,
    CH_LAST_T,
    CH_MANEUVER,
    CH_MODE,
    CH_PREV_NU,
    CH_PREV_S,
    CH_RAMP_K,
    CH_RAMP_NE,
    CH_RAMP_T0,
    CH_REASON,
    CH_STATUS,
    CH_STUCK,
    CH_T0,
    CH_USED_T,
    EVENT_IGNORED,
    EVENT_NAMES,
    EVENT_NONE,
    EVENT_NONFINITE,
    EVENT_REJECTED,
    EVENT_USED,
    MODE_AUTO,
    MODE_NAMES,
    MODE_OFF,
    MODE_ON,
    N_CFG,
    N_CH,
    N_REP,
    REASON_GATE,
    REASON_MANUAL,
    REASON_NAMES,
    REASON_NONE,
    REASON_NONFINITE,
    REASON_STUCK,
    REASON_TIMEOUT,
    REP_EVENT,
    REP_INNOV,
    REP_R,
    REP_S,
    STATUS_CODE_LABELS,
    STATUS_LOST,
    STATUS_NAMES,
    STATUS_OFF,
    STATUS_OK,
    STATUS_RECOVERING,
    STUCK_FALSE_ALARM,
    code_label,
    new_channel_state,
    status_label,
)


@njit(cache=True)
def status_code(status, reason) -> int:
    """One integer for (status, reason): STATUS_* itself unless lost with a known reason, then
    3 + reason (4 timeout, 5 nonfinite, 6 gate, 7 manual, 8 stuck); see STATUS_CODE_LABELS."""
    s = int(status)
    r = int(reason)
    if s == STATUS_LOST and 1 <= r <= 5:
        return 3 + r
    return s


_PENDING = -1.0  # REP_EVENT while the step's decisions are being made


@njit(cache=True, inline="always")
def _fails_prior(rep, cfg, j):
    nu = rep[j, REP_INNOV]
    return not (nu * nu <= cfg[j, CFG_GATE] * rep[j, REP_S])


_CONSENSUS_WIDENING = 1e4  # consensus only within the gate with R widened this much


@njit(cache=True, inline="always")
def _plausible(rep, cfg, j):
    """Within the gate with the measurement variance widened by _CONSENSUS_WIDENING: rules out
    absurd samples (two sensors reporting the same garbage must not overrule the model)."""
    nu = rep[j, REP_INNOV]
    return nu * nu <= cfg[j, CFG_GATE] * (rep[j, REP_S] + (_CONSENSUS_WIDENING - 1.0) * cfg[j, CFG_R])


@njit(cache=True, **WITHOUT_NRT)  # called by the loop: compiled alike whoever calls it first
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
        if d * d <= cfg[j, CFG_GATE] * (cfg[j, CFG_R] + cfg[i, CFG_R]):
            return True
    return False


@njit(cache=True, **WITHOUT_NRT)  # called by the loop: compiled alike whoever calls it first
def _witnessed(rep, cfg, value, j, m):
    """Another channel of the same state refutes channel j's sample at this step: its own sample
    passes the gate (it agrees with the prediction) and disagrees with channel j's beyond the gate
    (chi-square on the difference, variance R_i + R_j). A witness too imprecise to tell the two
    apart (the pressure sensor against a millimetre of Qualisys disagreement) says nothing."""
    k = int(cfg[j, CFG_STATE])
    if k < 0 or math.isnan(value[j]):
        return False
    for i in range(m):
        if i == j or int(cfg[i, CFG_STATE]) != k or math.isnan(value[i]) or math.isnan(rep[i, REP_INNOV]):
            continue
        if _fails_prior(rep, cfg, i):
            continue
        d = value[j] - value[i]
        if cfg[j, CFG_ANGLE] != 0.0:
            d = wrap_angle(d)
        if d * d > cfg[j, CFG_GATE] * (cfg[j, CFG_R] + cfg[i, CFG_R]):
            return True
    return False


@njit(cache=True, inline="always")
def _stuck_check(ch, cfg, j, v):
    """Feed one finite sample into the block variance check; returns 1 (block stuck), 0 (block
    scatters like noise) or -1 (block not complete yet)."""
    nb = int(cfg[j, CFG_STUCK_N])
    if nb < 2:
        return -1
    cnt = int(ch[j, CH_BLK_N])
    if cnt == 0:
        ch[j, CH_BLK_Y0] = v
        ch[j, CH_BLK_S1] = 0.0
        ch[j, CH_BLK_S2] = 0.0
    else:
        d = v - ch[j, CH_BLK_Y0]
        if cfg[j, CFG_ANGLE] != 0.0:
            d = wrap_angle(d)
        ch[j, CH_BLK_S1] += d
        ch[j, CH_BLK_S2] += d * d
    cnt += 1
    if cnt < nb:
        ch[j, CH_BLK_N] = cnt
        return -1
    ch[j, CH_BLK_N] = 0.0
    if cfg[j, CFG_STUCK_BOUND] == 0.0:  # repetition check: every sample of the block the same number
        return 1 if ch[j, CH_BLK_S2] == 0.0 else 0
    s1 = ch[j, CH_BLK_S1]
    scatter = ch[j, CH_BLK_S2] - s1 * s1 / nb  # sum of squared deviations from the block mean
    return 1 if scatter < cfg[j, CFG_STUCK_BOUND] * cfg[j, CFG_R] else 0


@njit(cache=True, **WITHOUT_NRT)  # called by the loop: compiled alike whoever calls it first
def _inflate(P, H, cfg, j, nu, s):
    """The prediction of channel j's quantity was found wrong (a jump the model missed): widen its
    variance so that this innovation is a 1-sigma event, h P h^T + R = nu^2. For a unit row h = e_i
    the jump is added to P_ii alone (a jump of that state, uncorrelated with the others: the
    velocity and bias estimates are not dragged along); for a general row the covariance of the
    correlated states is scaled (fading memory, P <- D P D). Both keep P positive semi-definite.
    Returns the new h P h^T + R."""
    r = cfg[j, CFG_R]
    hph = s - r
    extra = nu * nu - s
    if not (hph > 0.0 and extra > 0.0):
        return s
    idx = int(cfg[j, CFG_STATE])
    if idx >= 0:
        P[idx, idx] += extra
        return nu * nu
    n = P.shape[0]
    f = math.sqrt((nu * nu - r) / hph)
    for i in range(n):
        pi = 0.0
        for k in range(n):
            pi += P[i, k] * H[j, k]
        if pi == 0.0:
            continue  # uncorrelated with the measurement: untouched
        for k in range(n):
            P[i, k] *= f
            P[k, i] *= f
    return nu * nu


@njit(cache=True, inline="always")
def _ramp_samples(ch, cfg, j, t):
    """Recovery samples for a channel returning at time t: CFG_RAMP_N, but no longer than it was
    away (its last used sample; never used: the full ramp)."""
    n_ramp = cfg[j, CFG_RAMP_N]
    away = t - ch[j, CH_USED_T]
    if n_ramp < 1.0 or not (away >= 0.0) or not (cfg[j, CFG_RAMP_TIME] > 0.0):
        return n_ramp
    return min(n_ramp, max(1.0, math.ceil(n_ramp * away / cfg[j, CFG_RAMP_TIME] - 1e-9)))


@njit(cache=True, inline="always")
def _weight(ch, cfg, j, status, t):
    """Share g of the innovation the next sample may apply (1 = the normal Kalman update)."""
    if cfg[j, CFG_RAMP_N] < 1.0:
        return 1.0
    if status == STATUS_LOST:
        return 1.0 / _ramp_samples(ch, cfg, j, t)
    if status == STATUS_RECOVERING:
        return 1.0 / max(ch[j, CH_RAMP_NE] - ch[j, CH_RAMP_K], 1.0)
    return 1.0


@njit(cache=True, **WITHOUT_NRT)  # called by the loop: compiled alike whoever calls it first
def manage_channels(x, P, ch, H, cfg, t, y, present, rep, value) -> int:
    """Decide which samples of this step are used; update ``ch`` and ``rep`` in place.

    x (n), P (n x n): the prior of this sample. ch (m x N_CH), cfg (m x N_CFG), H (m x n),
    y (m), present (m, bool), rep (m x N_REP). Output value (m): the offset-corrected sample of
    each accepted channel, NaN for the others; rep[:, REP_R] holds the variance each accepted
    sample is to be weighted with (the covariance update uses the nominal CFG_R). Returns the
    number of accepted channels. A non-finite t disables all samples of this step (they are
    treated as absent).
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
        if t_ok and math.isnan(ch[j, CH_T0]):
            ch[j, CH_T0] = t  # and so does the start-up phase
        r_nom = cfg[j, CFG_R]

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
        if status == STATUS_RECOVERING and ch[j, CH_RAMP_K] >= ch[j, CH_RAMP_NE]:
            status = STATUS_OK
            reason = REASON_NONE

        if not (present[j] and t_ok):
            if t_ok and status != STATUS_LOST and t - ch[j, CH_LAST_T] > cfg[j, CFG_TIMEOUT]:
                status = STATUS_LOST
                reason = REASON_TIMEOUT
                fails = 0
            rep[j, REP_R] = r_nom
            ch[j, CH_STATUS] = status
            ch[j, CH_REASON] = reason
            ch[j, CH_FAILS] = fails
            continue

        v = y[j] - cfg[j, CFG_OFFSET]
        idx = int(cfg[j, CFG_STATE])
        if idx >= 0:
            hx = x[idx]
            hph = P[idx, idx]
        else:
            hx = 0.0
            hph = 0.0
            for i in range(n):
                hi = H[j, i]
                if hi != 0.0:
                    hx += hi * x[i]
                    for k in range(n):
                        hph += hi * P[i, k] * H[j, k]
        nu = v - hx
        if cfg[j, CFG_ANGLE] != 0.0:
            nu = wrap_angle(nu)
        if not (math.isfinite(v) and math.isfinite(nu) and math.isfinite(hph) and hph + r_nom > 0.0):
            ch[j, CH_STATUS] = STATUS_LOST
            ch[j, CH_REASON] = REASON_NONFINITE
            ch[j, CH_FAILS] = 0.0
            ch[j, CH_BLK_N] = 0.0
            rep[j, REP_R] = r_nom
            rep[j, REP_EVENT] = EVENT_NONFINITE
            continue
        ch[j, CH_LAST_T] = t
        stuck = _stuck_check(ch, cfg, j, v)
        if stuck == 1 and mode != MODE_ON:
            ch[j, CH_STUCK] = 1.0
            if status != STATUS_LOST or reason != REASON_STUCK:
                status = STATUS_LOST
                reason = REASON_STUCK
                fails = 0
        elif stuck >= 0:
            ch[j, CH_STUCK] = 0.0
        # the variance this sample would be weighted with: under-weighted while recovering; the
        # gate tests it against the filter's honest S (P stays honest under the under-weighting)
        g = _weight(ch, cfg, j, status, t)
        r_eff = r_nom + hph * (1.0 / g - 1.0) if g < 1.0 else r_nom
        rep[j, REP_R] = r_eff
        rep[j, REP_INNOV] = nu
        rep[j, REP_S] = hph + r_nom
        ch[j, CH_STATUS] = status
        ch[j, CH_REASON] = reason
        ch[j, CH_FAILS] = fails
        if ch[j, CH_STUCK] != 0.0:
            rep[j, REP_EVENT] = EVENT_REJECTED  # a frozen sensor is not used, whatever it says
            continue
        # the decision waits until every channel's innovation is known (consensus below)
        value[j] = v
        rep[j, REP_EVENT] = _PENDING

    for j in range(m):
        if rep[j, REP_EVENT] != _PENDING:
            continue
        status = int(ch[j, CH_STATUS])
        reason = int(ch[j, CH_REASON])
        mode = int(ch[j, CH_MODE])
        fails = int(ch[j, CH_FAILS])
        gated = t - ch[j, CH_T0] >= cfg[j, CFG_STARTUP]  # the start-up phase is over
        own = not _fails_prior(rep, cfg, j)
        passed = mode == MODE_ON or not gated or own
        if (not passed and status == STATUS_LOST and reason == REASON_GATE and fails > 0
                and cfg[j, CFG_REACQUIRE] > 0.0 and t - ch[j, CH_FAIL_T0] >= cfg[j, CFG_REACQUIRE]
                and not _witnessed(rep, cfg, value, j, m)):
            passed = True  # re-acquisition: disagreeing too long for an outlier, and no witness against it
        if not passed and _agrees_with_another(rep, cfg, value, j, m):
            passed = True  # the sensors agree with each other, not with the prediction: the model is off
        persists = False
        maneuver = 0.0
        if (not passed and gated and status != STATUS_LOST and cfg[j, CFG_MANEUVER] > 0.0
                and not math.isnan(ch[j, CH_USED_T])):
            # maneuver: the second failure in a row, growing in the same direction (or the first
            # failure in the direction of a maneuver being followed), within what a bounded
            # acceleration of the truth away from the prediction explains (normal update)
            nu = rep[j, REP_INNOV]
            prev = ch[j, CH_PREV_NU]
            tau = t - ch[j, CH_USED_T]
            allowance = math.sqrt(cfg[j, CFG_GATE] * rep[j, REP_S]) + 0.5 * cfg[j, CFG_MANEUVER] * tau * tau
            if fails == 1:
                trend = nu * prev > 0.0 and abs(nu) >= abs(prev)
            else:
                trend = fails == 0 and nu * ch[j, CH_MANEUVER] > 0.0
            if trend and abs(nu) <= allowance and not _witnessed(rep, cfg, value, j, m):
                passed = True
                maneuver = 1.0 if nu > 0.0 else -1.0
        if not passed and gated and fails > 0 and not _witnessed(rep, cfg, value, j, m):
            # persistence: the previous sample failed the gate too, and by the same amount within the
            # gate. An outlier is isolated; a deviation that persists is a change the model missed
            # (or an offset that, with no other sensor of this state, nothing can tell from one)
            d = rep[j, REP_INNOV] - ch[j, CH_PREV_NU]
            if cfg[j, CFG_ANGLE] != 0.0:
                d = wrap_angle(d)
            if d * d <= cfg[j, CFG_GATE] * (rep[j, REP_S] + ch[j, CH_PREV_S]):
                passed = True
                persists = True
                # the prediction is what was wrong: its covariance was too small (fading memory)
                rep[j, REP_S] = _inflate(P, H, cfg, j, rep[j, REP_INNOV], rep[j, REP_S])
        if passed:
            if persists and status == STATUS_RECOVERING:
                # the widened variance makes the under-weighting relative to it: keep the weight
                rep[j, REP_R] = cfg[j, CFG_R] + (rep[j, REP_S] - cfg[j, CFG_R]) * (
                    max(ch[j, CH_RAMP_NE] - ch[j, CH_RAMP_K], 1.0) - 1.0)
            if status == STATUS_LOST:
                if cfg[j, CFG_RAMP_N] >= 1.0:
                    status = STATUS_RECOVERING
                    ch[j, CH_RAMP_T0] = t
                    ch[j, CH_RAMP_K] = 0.0
                    ch[j, CH_RAMP_NE] = _ramp_samples(ch, cfg, j, t)
                else:
                    status = STATUS_OK
                reason = REASON_NONE
            if status == STATUS_RECOVERING:
                ch[j, CH_RAMP_K] += 1.0
            fails = 0
            ch[j, CH_USED_T] = t
            if maneuver != 0.0 or own:  # a maneuver is followed until a sample passes the gate itself
                ch[j, CH_MANEUVER] = maneuver
            rep[j, REP_EVENT] = EVENT_USED
            n_accept += 1
        else:
            if fails == 0:
                ch[j, CH_FAIL_T0] = t
            fails += 1
            ch[j, CH_PREV_NU] = rep[j, REP_INNOV]
            ch[j, CH_PREV_S] = rep[j, REP_S]
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
