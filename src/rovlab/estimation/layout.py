"""The layout of sensor management's arrays and its codes, without numba.

The compiled kernels of :mod:`rovlab.estimation.fusion` read a channel configuration (m x
N_CFG), keep a channel state (m x N_CH) and fill a report (m x N_REP); this module names their
columns and the status, reason, mode and event codes, so that designing a filter, reading a log
or labelling a status (``rovlab design``, ``rovlab filter``'s set-up) needs no numba import.
:mod:`rovlab.estimation.fusion` re-exports every name.
"""

from __future__ import annotations

import numpy as np

# channel configuration columns
CFG_OFFSET, CFG_R, CFG_TIMEOUT, CFG_GATE, CFG_LOSE_AFTER, CFG_RAMP_TIME, CFG_RAMP_N, CFG_ANGLE, \
    CFG_REACQUIRE, CFG_STATE, CFG_STARTUP, CFG_STUCK_N, CFG_STUCK_BOUND, CFG_MANEUVER = range(14)
N_CFG = 14
# channel state columns
CH_STATUS, CH_REASON, CH_MODE, CH_FAILS, CH_LAST_T, CH_RAMP_T0, CH_FAIL_T0, CH_T0, CH_RAMP_K, CH_STUCK, \
    CH_BLK_N, CH_BLK_Y0, CH_BLK_S1, CH_BLK_S2, CH_PREV_NU, CH_PREV_S, CH_USED_T, CH_RAMP_NE, CH_MANEUVER = range(19)
N_CH = 19
# report columns
REP_EVENT, REP_INNOV, REP_S, REP_R = range(4)
N_REP = 4

STATUS_OK, STATUS_RECOVERING, STATUS_LOST, STATUS_OFF = 0, 1, 2, 3
REASON_NONE, REASON_TIMEOUT, REASON_NONFINITE, REASON_GATE, REASON_MANUAL, REASON_STUCK = 0, 1, 2, 3, 4, 5
MODE_AUTO, MODE_OFF, MODE_ON = 0, 1, 2
EVENT_NONE, EVENT_USED, EVENT_REJECTED, EVENT_NONFINITE, EVENT_IGNORED = 0, 1, 2, 3, 4

STATUS_NAMES = ("ok", "recovering", "lost", "off")
REASON_NAMES = ("", "timeout", "nonfinite", "gate", "manual", "stuck")
MODE_NAMES = ("auto", "off", "on")
EVENT_NAMES = ("none", "used", "rejected", "nonfinite", "ignored")
# status_code(status, reason) -> label; 0..3 coincide with STATUS_* (2: lost, reason unknown)
STATUS_CODE_LABELS = ("ok", "recovering", "lost", "off", "lost-timeout", "lost-nonfinite", "lost-gate",
                      "lost-manual", "lost-stuck")

STUCK_FALSE_ALARM = 1e-9  # per block: probability that noise of variance R looks stuck


def new_channel_state(m: int) -> np.ndarray:
    """Initial management state of m channels: OK, automatic, no sample seen yet."""
    ch = np.zeros((m, N_CH))
    for col in (CH_LAST_T, CH_RAMP_T0, CH_FAIL_T0, CH_T0, CH_USED_T):
        ch[:, col] = np.nan
    return ch


def status_label(status: int, reason: int) -> str:
    """'ok', 'recovering', 'off' or 'lost-<reason>' (e.g. 'lost-timeout')."""
    name = STATUS_NAMES[int(status)]
    if int(status) == STATUS_LOST:
        return f"lost-{REASON_NAMES[int(reason)] or 'unknown'}"
    return name


def code_label(code: float) -> str:
    """The label of a :func:`status_code` value (or of a plain STATUS_* code)."""
    c = int(code)
    if not 0 <= c < len(STATUS_CODE_LABELS):
        raise ValueError(f"{code!r} is not a sensor status code (0..{len(STATUS_CODE_LABELS) - 1})")
    return STATUS_CODE_LABELS[c]
