"""Thruster kernels on packed rows, in plain Python written in numba's subset (no numba import).

:mod:`rovlab.models.thrusters` publishes them compiled (``bank_force``, ``bank_pwm``: what the
simulator's compiled loop calls) and uses these plain versions where a command runs them a few
times only, so that one-shot commands (``rovlab thruster``, ``allocate``, ``vehicle show``) never
import numba nor compile anything. Row layout: the ``K_*`` columns below.
"""

from __future__ import annotations

import numpy as np

# Columns of a packed thruster row.
K_KIND, K_NEUTRAL, K_DEAD, K_KLP, K_KNLP, K_KLN, K_KNLN, K_PMIN, K_PMAX = range(9)
# KIND_QUADRATIC: the dead band shifts the curve (it starts at the band's edge); KIND_CUT: the same curve of
# u = pwm - neutral, cut to zero within the band (ArduPilot SITL's SIM_Submarine)
KIND_QUADRATIC, KIND_TABLE, KIND_CUT = 0.0, 1.0, 2.0
ZERO_FORCE = 1e-10  # |f| below this [N] is commanded as neutral (it lies in the dead band anyway)
EDGE_FORCE = 2e-10  # [N]: the least force commanded on a side, i.e. that side's edge of the dead band

KERNELS = ("_quad_force", "_quad_pwm", "_cut_force", "_cut_least", "_cut_pwm", "_table_force", "_table_pwm", "_pwm",
           "_edge_pwm", "bank_force_into", "bank_pwm_into", "bank_pwm_hold_into", "bank_force", "bank_pwm")


def _quad_force(row: np.ndarray, pwm: float) -> float:
    pwm = min(max(pwm, row[K_PMIN]), row[K_PMAX])
    u = pwm - row[K_NEUTRAL]
    d = row[K_DEAD]
    if u > d:
        s = u - d
        return row[K_KLP] * s + row[K_KNLP] * s * s
    if u < -d:
        s = u + d
        return row[K_KLN] * s - row[K_KNLN] * s * s
    return 0.0


def _quad_pwm(row: np.ndarray, f: float) -> float:
    if abs(f) <= ZERO_FORCE:
        return row[K_NEUTRAL]
    if f > 0.0:
        s = 2.0 * f / (row[K_KLP] + np.sqrt(row[K_KLP] ** 2 + 4.0 * row[K_KNLP] * f))
        pwm = row[K_NEUTRAL] + row[K_DEAD] + s
    else:
        s = -2.0 * (-f) / (row[K_KLN] + np.sqrt(row[K_KLN] ** 2 + 4.0 * row[K_KNLN] * (-f)))
        pwm = row[K_NEUTRAL] - row[K_DEAD] + s
    return min(max(pwm, row[K_PMIN]), row[K_PMAX])


def _cut_force(row: np.ndarray, pwm: float) -> float:
    """KIND_CUT: f = K_L u + K_NL u|u| of the whole offset u = pwm - neutral, and 0 for |u| <= d."""
    pwm = min(max(pwm, row[K_PMIN]), row[K_PMAX])
    u = pwm - row[K_NEUTRAL]
    d = row[K_DEAD]
    if u > d:
        return row[K_KLP] * u + row[K_KNLP] * u * u
    if u < -d:
        return row[K_KLN] * u - row[K_KNLN] * u * u
    return 0.0


def _cut_least(row: np.ndarray, sign: float) -> float:
    """KIND_CUT: the least thrust [N] (its magnitude) on one side of the dead band, at the band's edge + 1 us
    (a pulse is whole microseconds: SITL's least pulse outside 1475-1525 us is 1526 us)."""
    u = row[K_DEAD] + 1.0
    if sign > 0.0:
        return row[K_KLP] * u + row[K_KNLP] * u * u
    return row[K_KLN] * u + row[K_KNLN] * u * u


def _cut_pwm(row: np.ndarray, f: float) -> float:
    """KIND_CUT inverse. A demand the curve gives outside the band is its exact root; a smaller one (in the
    gap between no thrust and the least thrust outside the band, at its edge + 1 us) is rounded to whichever
    of the two is nearer in force: neutral below half the least thrust, the band's edge + 1 us from half on."""
    if abs(f) <= ZERO_FORCE:
        return row[K_NEUTRAL]
    if f > 0.0:
        least = _cut_least(row, 1.0)
        if f < least:
            pwm = row[K_NEUTRAL] + row[K_DEAD] + 1.0 if f >= 0.5 * least else row[K_NEUTRAL]
        else:
            pwm = row[K_NEUTRAL] + 2.0 * f / (row[K_KLP] + np.sqrt(row[K_KLP] ** 2 + 4.0 * row[K_KNLP] * f))
    else:
        least = _cut_least(row, -1.0)
        if -f < least:
            pwm = row[K_NEUTRAL] - row[K_DEAD] - 1.0 if -f >= 0.5 * least else row[K_NEUTRAL]
        else:
            pwm = row[K_NEUTRAL] - 2.0 * (-f) / (row[K_KLN] + np.sqrt(row[K_KLN] ** 2 + 4.0 * row[K_KNLN] * (-f)))
    return min(max(pwm, row[K_PMIN]), row[K_PMAX])


def _table_force(row: np.ndarray, grid_pwm: np.ndarray, grid_f: np.ndarray, pwm: float) -> float:
    pwm = min(max(pwm, row[K_PMIN]), row[K_PMAX])
    return np.interp(pwm, grid_pwm, grid_f)


def _table_pwm(row: np.ndarray, grid_pwm: np.ndarray, grid_f: np.ndarray, f: float) -> float:
    if abs(f) <= ZERO_FORCE:
        return row[K_NEUTRAL]
    n = grid_pwm.shape[0]
    if f > 0.0:
        # first grid point (from neutral upwards) whose force reaches f, then linear back
        for k in range(n - 1):
            if grid_pwm[k + 1] > row[K_NEUTRAL] and grid_f[k + 1] >= f and grid_f[k + 1] > grid_f[k]:
                t = (f - grid_f[k]) / (grid_f[k + 1] - grid_f[k])
                pwm = grid_pwm[k] + max(t, 0.0) * (grid_pwm[k + 1] - grid_pwm[k])
                return min(max(pwm, row[K_PMIN]), row[K_PMAX])
        return row[K_PMAX]
    for k in range(n - 1, 0, -1):
        if grid_pwm[k - 1] < row[K_NEUTRAL] and grid_f[k - 1] <= f and grid_f[k - 1] < grid_f[k]:
            t = (f - grid_f[k]) / (grid_f[k - 1] - grid_f[k])
            pwm = grid_pwm[k] + max(t, 0.0) * (grid_pwm[k - 1] - grid_pwm[k])
            return min(max(pwm, row[K_PMIN]), row[K_PMAX])
    return row[K_PMIN]


def _pwm(row: np.ndarray, grid_pwm: np.ndarray, grid_f: np.ndarray, f: float) -> float:
    if row[K_KIND] == KIND_QUADRATIC:
        return _quad_pwm(row, f)
    if row[K_KIND] == KIND_CUT:
        return _cut_pwm(row, f)
    return _table_pwm(row, grid_pwm, grid_f, f)


def _edge_pwm(row: np.ndarray, grid_pwm: np.ndarray, grid_f: np.ndarray, sign: float) -> float:
    """The PWM at one side's edge of the dead band, the last pulse of that side that gives no thrust (a cut
    band: neutral +- d; the others: where the least force of that side is commanded)."""
    if row[K_KIND] == KIND_CUT:
        return row[K_NEUTRAL] + sign * row[K_DEAD]
    return _pwm(row, grid_pwm, grid_f, sign * EDGE_FORCE)


def bank_force_into(rows: np.ndarray, grid_pwm: np.ndarray, grid_f: np.ndarray, pwm: np.ndarray,
                    out: np.ndarray) -> None:
    """Thrust of every thruster for a vector of PWM commands (saturated to their ranges) into out."""
    for i in range(rows.shape[0]):
        if rows[i, K_KIND] == KIND_QUADRATIC:
            out[i] = _quad_force(rows[i], pwm[i])
        elif rows[i, K_KIND] == KIND_CUT:
            out[i] = _cut_force(rows[i], pwm[i])
        else:
            out[i] = _table_force(rows[i], grid_pwm, grid_f[i], pwm[i])


def bank_pwm_into(rows: np.ndarray, grid_pwm: np.ndarray, grid_f: np.ndarray, force: np.ndarray,
                  out: np.ndarray) -> None:
    """PWM command of every thruster for a vector of thrusts (saturated to their ranges) into out.

    A cut dead band's inverse rounds a demand in its gap (:func:`_cut_pwm`) and leaves ``force[i]`` the
    demand: a caller's achieved wrench (and so an LQG filter's input) is the allocated one, and the
    rounding error is a force the filter's bias estimate takes up -- the integral action that moves a
    small steady demand across the gap. Told the rounded thrust instead, the bias saw no error and the
    heading stopped 2 deg short of a 45 deg step (ardusub-sitl-step; ArduSub SITL: 4.6 deg RMS)."""
    for i in range(rows.shape[0]):
        if rows[i, K_KIND] == KIND_QUADRATIC:
            out[i] = _quad_pwm(rows[i], force[i])
        elif rows[i, K_KIND] == KIND_CUT:
            out[i] = _cut_pwm(rows[i], force[i])
        else:
            out[i] = _table_pwm(rows[i], grid_pwm, grid_f[i], force[i])


def bank_pwm_hold_into(rows: np.ndarray, grid_pwm: np.ndarray, grid_f: np.ndarray, force: np.ndarray,
                       side: np.ndarray, sum_f: np.ndarray, hold_us: float, out: np.ndarray) -> None:
    """PWM commands as :func:`bank_pwm_into`, with a hysteresis across the dead band.

    The inverse jumps the dead band: the least force either way is commanded at its edge
    (neutral +- d), so a demand that changes sign from sample to sample -- noise on a demand near
    zero -- becomes a square wave of 2 d into the ESC. Here a thruster keeps the side of the dead
    band it is on (``side[i]``: +1, -1, or 0 at neutral) until the demand for the other side,
    summed since it last gave thrust on its own side (``sum_f[i]``, a one-sided cumulative sum:
    noise about zero mostly cancels in it, a small steady demand grows it), needs at least
    ``hold_us`` of PWM beyond that side's edge; until then it waits at the edge of its own side (no
    thrust) and ``force[i]`` is set to 0, the thrust it gives, so the caller's achieved wrench says
    so. A zero demand (|f| <= ZERO_FORCE) is neutral and clears the state. ``side`` and ``sum_f``
    are updated in place. ``hold_us = 0`` is :func:`bank_pwm_into` exactly. A cut dead band
    (KIND_CUT) jumps it too, from the band's edge + 1 us on either side; its edge is neutral +- d
    (no thrust), and a demand for the other side that its inverse rounds to neutral is short of
    that side's edge, so it waits.
    """
    for i in range(rows.shape[0]):
        f = force[i]
        if abs(f) <= ZERO_FORCE:
            out[i] = rows[i, K_NEUTRAL]
            side[i] = 0.0
            sum_f[i] = 0.0
            continue
        sign = 1.0 if f > 0.0 else -1.0
        if side[i] == -sign and hold_us > 0.0:
            acc = sum_f[i] + f  # the other side's demand since this side last gave thrust
            edge = _edge_pwm(rows[i], grid_pwm, grid_f[i], sign)  # the other side's edge
            # PWM beyond that edge (signed: a cut band rounds a small demand to neutral, short of the edge)
            if sign * (_pwm(rows[i], grid_pwm, grid_f[i], acc) - edge) < hold_us:
                sum_f[i] = acc
                out[i] = _edge_pwm(rows[i], grid_pwm, grid_f[i], side[i])  # wait at this side's edge
                force[i] = 0.0
                continue
        elif side[i] == sign and hold_us > 0.0:
            acc = sum_f[i] + f  # demand on this side repays what the other side asked for
            sum_f[i] = min(acc, 0.0) if sign > 0.0 else max(acc, 0.0)
            out[i] = _pwm(rows[i], grid_pwm, grid_f[i], f)
            continue
        side[i] = sign
        sum_f[i] = 0.0
        out[i] = _pwm(rows[i], grid_pwm, grid_f[i], f)


def bank_force(rows: np.ndarray, grid_pwm: np.ndarray, grid_f: np.ndarray, pwm: np.ndarray) -> np.ndarray:
    """Thrust of every thruster for a vector of PWM commands (saturated to their ranges)."""
    out = np.empty(rows.shape[0])
    bank_force_into(rows, grid_pwm, grid_f, pwm, out)
    return out


def bank_pwm(rows: np.ndarray, grid_pwm: np.ndarray, grid_f: np.ndarray, force: np.ndarray) -> np.ndarray:
    """PWM command of every thruster for a vector of thrusts (saturated to their ranges)."""
    out = np.empty(rows.shape[0])
    bank_pwm_into(rows, grid_pwm, grid_f, force, out)
    return out
