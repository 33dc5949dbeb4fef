"""Thruster models: PWM command <-> thrust (Sandøy 2016, ch. 2).

Two models, chosen per thruster in the vehicle file:

* ``quadratic``: the dead-band fit of the MC-Lab rig. With the PWM offset u = pwm - neutral
  and dead band d, s = u - d (u > d) or s = u + d (u < -d), and f = K_L s + K_NL s|s|
  (K_L, K_NL taken from the forward or the reverse set). The inverse is the exact root of
  the quadratic, written in the cancellation-free form s = 2 f / (K_L + sqrt(K_L^2 + 4 K_NL |f|)).
  With ``deadband_kind = "cut"`` (ArduPilot SITL's submarine) the band is cut out of the curve
  instead: s = u for |u| > d, f = 0 within it, so thrust jumps from 0 to f(d + 1 us) at the
  band's edge. Its inverse rounds a demand in that gap to the nearer in force of neutral and
  neutral +- (d + 1 us): neutral below half of f(d + 1 us), the edge + 1 us from half on.
* ``table``: Blue Robotics' T200 bollard-thrust tables (10-20 V, September 2019), linear in
  supply voltage and in PWM. The tables are made monotone from neutral outwards (the maker's
  data dips by a few grams at full reverse) so that the forward map and its inverse agree.

Commands are saturated to each thruster's [pwm_min_us, pwm_max_us]; thrust limits follow.
The ``ThrusterBank`` packs all thrusters of a vehicle into arrays for compiled per-step code.
The kernels (``bank_force``, ``bank_pwm``) are compiled on first access, so importing this module
does not import numba (see :mod:`rovlab._jit`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from importlib import resources

import numpy as np

from rovlab._jit import WITH_NRT, LazyKernels
from rovlab.models import thruster_kernels as _plain
from rovlab.models.thruster_kernels import (  # noqa: F401  (re-exported: the row layout)
    K_DEAD,
    K_KIND,
    K_KLN,
    K_KLP,
    K_KNLN,
    K_KNLP,
    K_NEUTRAL,
    K_PMAX,
    K_PMIN,
    KIND_CUT,
    KIND_QUADRATIC,
    KIND_TABLE,
    ZERO_FORCE,
)
from rovlab.params.vehicle import Thruster, Vehicle

KGF = 9.80665  # N per kilogram-force
TABLE_VOLTAGES = (10, 12, 14, 16, 18, 20)
TABLE_PWM = np.arange(1100.0, 1900.0 + 1e-9, 4.0)  # the maker's grid [us]


@functools.cache
def t200_raw_table(voltage: int) -> tuple[np.ndarray, np.ndarray]:
    """(pwm_us, force_N) of the maker's table at one of the tabulated voltages."""
    if voltage not in TABLE_VOLTAGES:
        raise ValueError(f"no T200 table at {voltage} V; tabulated: {TABLE_VOLTAGES}")
    text = (resources.files("rovlab.models") / "data" / "t200" / f"T200-Thrusters-{voltage}V.csv").read_text(
        encoding="utf-8")
    pwm, force = [], []
    for line in text.splitlines()[1:]:
        cells = [c.strip() for c in line.split(",")]
        if len(cells) < 6 or not cells[0]:
            continue
        pwm.append(float(cells[0]))
        force.append(float(cells[5]) * KGF)
    return np.array(pwm), np.array(force)


def t200_force_table(voltage: float) -> np.ndarray:
    """Thrust [N] on TABLE_PWM at a supply voltage in [10, 20] V, linear between tables,
    made monotone outwards from neutral."""
    if not 10.0 <= voltage <= 20.0:
        raise ValueError(f"T200 supply voltage must be within 10-20 V, got {voltage}")
    volts = np.array(TABLE_VOLTAGES, dtype=float)
    j = int(np.clip(np.searchsorted(volts, voltage) - 1, 0, len(volts) - 2))
    lo_v, hi_v = volts[j], volts[j + 1]
    a = (voltage - lo_v) / (hi_v - lo_v)
    p_lo, f_lo = t200_raw_table(int(lo_v))
    p_hi, f_hi = t200_raw_table(int(hi_v))
    force = (1 - a) * np.interp(TABLE_PWM, p_lo, f_lo) + a * np.interp(TABLE_PWM, p_hi, f_hi)
    mid = int(np.searchsorted(TABLE_PWM, 1500.0))
    force[mid:] = np.maximum.accumulate(np.maximum(force[mid:], 0.0))
    force[: mid + 1] = np.minimum.accumulate(np.minimum(force[: mid + 1], 0.0)[::-1])[::-1]
    return force


# --------------------------------------------------------------------------------------------
# Kernels on packed rows: plain Python in rovlab.models.thruster_kernels, compiled on first use
# --------------------------------------------------------------------------------------------

# WITH_NRT (reference counting on): some allocate, and the closed loop that calls them is compiled without reference
# counting, which they would otherwise inherit (rovlab.sim.loop)
_kernels = LazyKernels(_plain, _plain.KERNELS, cache=True, **WITH_NRT)
__getattr__ = _kernels.module_getattr(__name__)  # bank_force, bank_pwm: numba dispatchers


# --------------------------------------------------------------------------------------------
# Python-level API
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class ThrusterBank:
    """All thrusters of a vehicle in packed arrays (row i = thruster i)."""

    names: tuple[str, ...]
    rows: np.ndarray  # (n, 9) packed parameters
    grid_pwm: np.ndarray  # (G,) common PWM grid of tabulated thrusters
    grid_force: np.ndarray  # (n, G) thrust on the grid (zeros for quadratic thrusters)
    f_min: np.ndarray  # most negative thrust each can give [N]
    f_max: np.ndarray  # most positive thrust each can give [N]

    @classmethod
    def from_vehicle(cls, vehicle: Vehicle) -> ThrusterBank:
        return cls.from_thrusters(vehicle.thrusters)

    @classmethod
    def from_thrusters(cls, thrusters: tuple[Thruster, ...] | list[Thruster]) -> ThrusterBank:
        n = len(thrusters)
        rows = np.zeros((n, 9))
        grid_force = np.zeros((n, TABLE_PWM.size))
        for i, t in enumerate(thrusters):
            rows[i, K_NEUTRAL] = t.pwm_neutral_us
            rows[i, K_DEAD] = t.deadband_us
            rows[i, K_PMIN] = t.pwm_min_us
            rows[i, K_PMAX] = t.pwm_max_us
            if t.model == "quadratic":
                assert t.curve is not None
                rows[i, K_KIND] = KIND_CUT if t.deadband_kind == "cut" else KIND_QUADRATIC
                rows[i, K_KLP:K_KNLN + 1] = (t.curve.K_L_pos, t.curve.K_NL_pos, t.curve.K_L_neg, t.curve.K_NL_neg)
            else:
                assert t.voltage is not None
                rows[i, K_KIND] = KIND_TABLE
                grid_force[i] = t200_force_table(t.voltage)
        f_lo = _plain.bank_force(rows, TABLE_PWM, grid_force, rows[:, K_PMIN].copy())
        f_hi = _plain.bank_force(rows, TABLE_PWM, grid_force, rows[:, K_PMAX].copy())
        for arr in (rows, grid_force, f_lo, f_hi):
            arr.setflags(write=False)
        return cls(tuple(t.name for t in thrusters), rows, TABLE_PWM, grid_force, f_lo, f_hi)

    def force(self, pwm_us: np.ndarray, *, compiled: bool = True) -> np.ndarray:
        """Thrust [N] for a PWM command per thruster (saturated). ``compiled=False`` runs the plain
        Python kernel (no numba import or compilation: for a one-off call)."""
        kernel = _kernels.compiled()["bank_force"] if compiled else _plain.bank_force
        return kernel(self.rows, self.grid_pwm, self.grid_force, _vec(pwm_us, len(self.names), "pwm_us"))

    def pwm(self, force: np.ndarray, *, compiled: bool = True) -> np.ndarray:
        """PWM [us] per thruster for a thrust per thruster (saturated); ``compiled`` as in force()."""
        kernel = _kernels.compiled()["bank_pwm"] if compiled else _plain.bank_pwm
        return kernel(self.rows, self.grid_pwm, self.grid_force, _vec(force, len(self.names), "force"))


def _vec(values: np.ndarray, n: int, what: str) -> np.ndarray:
    arr = np.ascontiguousarray(values, dtype=float)
    if arr.shape != (n,):
        raise ValueError(f"{what}: expected {n} values (one per thruster), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what}: values must be finite, got {arr.tolist()}")
    return arr


def force_from_pwm(thruster: Thruster, pwm_us: float) -> float:
    """Thrust [N] of one thruster for a PWM command [us] (saturated to its range).

    One-off conversions run the plain kernels (no compilation); use a :class:`ThrusterBank` for
    many."""
    return float(ThrusterBank.from_thrusters([thruster]).force(np.array([pwm_us]), compiled=False)[0])


def pwm_from_force(thruster: Thruster, force: float) -> float:
    """PWM command [us] giving a thrust [N] (saturated to the thruster's range); plain kernels."""
    return float(ThrusterBank.from_thrusters([thruster]).pwm(np.array([force]), compiled=False)[0])


def thrust_limits(thruster: Thruster) -> tuple[float, float]:
    """(most negative, most positive) thrust [N] within the PWM range."""
    bank = ThrusterBank.from_thrusters([thruster])
    return float(bank.f_min[0]), float(bank.f_max[0])
