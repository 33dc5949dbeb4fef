"""Sensor noise variances from resting logs (Sandøy 2016, sec. 4.4.1, table 4.8).

The vehicle rests (weighted down on the basin floor in the thesis, 6796 samples at 10 Hz). Each
channel's slow drift (temperature, tide, a settling vehicle) is removed by a least-squares
polynomial in time (degree 1 by default; 0 = mean only), and the sample variance of what is left,
with n - (degree + 1) degrees of freedom, is that channel's measurement variance: a diagonal
entry of a filter's R. A chi-square confidence interval assumes white noise; the optional
overlapping Allan deviation (IEEE Std 1139) shows whether that holds (slope -1/2 for white noise).

A resting log must look stationary once the drift is removed: the von Neumann ratio (mean square
successive difference over the variance; von Neumann 1941, Ann. Math. Statist. 12(4) 367-395) is
2 for white noise and falls towards 0 for steps and slow wandering. A channel whose ratio is below
``MIN_VON_NEUMANN_RATIO`` (e.g. a PWM staircase or a thrust log given by mistake) is refused
unless the caller asks otherwise (``rovlab identify noise --no-stationarity-check``).

Columns: ``time_s`` and one column per channel. For ``--update`` a column names its sensor and
channel as ``<sensor>.<channel>`` (``pressure.z``) or ``<channel>_<sensor>`` (``z_pressure``,
``psi_qualisys``), with the sensor name and channel as in the vehicle file's ``[[sensors]]``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.ident.fitting import IdentificationError, significant
from rovlab.io.tables import DataTable, read_table, require_increasing

MIN_SAMPLES = 20
MIN_VON_NEUMANN_RATIO = 0.2  # white noise: 2; a sensor's own low-pass filter lowers it a little
ALL_CHANNELS = ("x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "r")


@dataclass(frozen=True, eq=False)
class ChannelNoise:
    variance: float
    std: float
    ci95: tuple[float, float]  # chi-square interval of the variance (white-noise assumption)
    mean: float
    drift_per_s: float  # slope of the removed trend at the log's middle [unit/s]
    n: int
    residual: np.ndarray = field(repr=False)
    allan_tau_s: np.ndarray | None = field(default=None, repr=False)
    allan_dev: np.ndarray | None = field(default=None, repr=False)
    von_neumann_ratio: float = 2.0  # mean square successive difference / variance (white: 2)


@dataclass(frozen=True, eq=False)
class NoiseEstimate:
    channels: Mapping[str, ChannelNoise]
    time_s: np.ndarray
    detrend_degree: int
    rate_hz: float

    @property
    def variance(self) -> dict[str, float]:
        return {k: c.variance for k, c in self.channels.items()}

    def as_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "variance": self.variance,
            "std": {k: c.std for k, c in self.channels.items()},
            "ci95": {k: list(c.ci95) for k, c in self.channels.items()},
            "drift_per_s": {k: c.drift_per_s for k, c in self.channels.items()},
            "von_neumann_ratio": {k: c.von_neumann_ratio for k, c in self.channels.items()},
            "samples": int(self.time_s.size), "rate_hz": self.rate_hz, "detrend_degree": self.detrend_degree,
        }
        if any(c.allan_dev is not None for c in self.channels.values()):
            out["allan"] = {k: {"tau_s": np.asarray(c.allan_tau_s).tolist(), "adev": np.asarray(c.allan_dev).tolist()}
                            for k, c in self.channels.items() if c.allan_dev is not None}
        return out


def allan_deviation(x: np.ndarray, h: float, *, min_clusters: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Overlapping Allan deviation of samples x at spacing h, at octave cluster sizes.

    sigma^2(m h) = 1/2 mean((xbar_{k+m} - xbar_k)^2), xbar: means over m samples (IEEE 1139).
    """
    x = np.asarray(x, dtype=float)
    n = x.size
    c = np.concatenate([[0.0], np.cumsum(x - x.mean())])
    taus, devs = [], []
    m = 1
    while n // m >= min_clusters and 2 * m <= n:
        avg = (c[m:] - c[:-m]) / m  # all overlapping means of m samples
        d = avg[m:] - avg[:-m]
        taus.append(m * h)
        devs.append(float(np.sqrt(0.5 * np.mean(d**2))))
        m *= 2
    return np.array(taus), np.array(devs)


def von_neumann_ratio(res: np.ndarray) -> float:
    """Mean square successive difference over the variance of ``res`` (2 for white noise; NaN
    for a constant signal)."""
    res = np.asarray(res, dtype=float)
    var = float(np.mean((res - res.mean()) ** 2))
    if res.size < 3 or var == 0.0:
        return float("nan")
    return float(np.mean(np.diff(res) ** 2)) / var


def noise_variances(time_s: np.ndarray, channels: Mapping[str, np.ndarray], *, detrend: int = 1,
                    allan: bool = False, check_stationary: bool = True) -> NoiseEstimate:
    """Variance of each channel of a resting log after removing a polynomial drift.

    With ``check_stationary`` a channel whose detrended samples do not look like noise (von
    Neumann ratio below MIN_VON_NEUMANN_RATIO: steps, a staircase, slow wandering) is refused.
    """
    from scipy.stats import chi2

    t = np.asarray(time_s, dtype=float)
    if detrend not in (0, 1, 2, 3):
        raise IdentificationError(f"drift removal degree must be 0..3, got {detrend}")
    if t.size < MIN_SAMPLES:
        raise IdentificationError(f"{t.size} samples; a variance estimate needs at least {MIN_SAMPLES} "
                                  "(the thesis used 6796)")
    if not channels:
        raise IdentificationError("no channel columns besides time_s")
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.flatnonzero(dt <= 0)[0]) + 1
        raise IdentificationError(f"time does not increase at sample {i}")
    h = float(np.median(dt))
    tc = (t - t.mean()) / max(float(np.ptp(t)), 1e-12)
    V = np.vander(tc, detrend + 1)
    out: dict[str, ChannelNoise] = {}
    for name, values in channels.items():
        x = np.asarray(values, dtype=float)
        coef, *_ = np.linalg.lstsq(V, x, rcond=None)
        res = x - V @ coef
        dof = x.size - (detrend + 1)
        var = float(res @ res) / dof
        ci = (dof * var / float(chi2.ppf(0.975, dof)), dof * var / float(chi2.ppf(0.025, dof)))
        slope = float(coef[-2]) / max(float(np.ptp(t)), 1e-12) if detrend >= 1 else 0.0
        taus = devs = None
        if allan:
            taus, devs = allan_deviation(res, h)
        out[name] = ChannelNoise(var, float(np.sqrt(var)), ci, float(np.mean(x)), slope, int(x.size), res, taus, devs,
                                 von_neumann_ratio(res))
    if check_stationary:
        bad = {k: c.von_neumann_ratio for k, c in out.items() if c.von_neumann_ratio < MIN_VON_NEUMANN_RATIO}
        if bad:
            shown = ", ".join(f"{k!r} {r:.3g}" for k, r in bad.items())
            raise IdentificationError(
                f"not a resting log: after removing the drift, column(s) {shown} have a von Neumann ratio (mean "
                f"square successive difference / variance) below {MIN_VON_NEUMANN_RATIO:g}; white sensor noise gives "
                "about 2, steps or a staircase (a PWM or thrust log?) give nearly 0; expected samples of sensors at "
                "rest (--no-stationarity-check to use them anyway)")
    return NoiseEstimate(out, t, detrend, 1.0 / h)


def read_noise(path: str | Path) -> tuple[DataTable, dict[str, np.ndarray]]:
    table = read_table(path, required=("time_s",), what="resting sensor log")
    require_increasing(table, "time_s")
    cols = {c: table[c] for c in table.columns if c != "time_s"}
    if not cols:
        raise table.problem(None, None, "only time_s", "time_s and at least one channel column, e.g. z_pressure")
    return table, cols


def parse_channel_column(name: str) -> tuple[str, str] | None:
    """(sensor, channel) from ``sensor.channel`` or ``channel_sensor``; None if neither."""
    if "." in name:
        sensor, _, channel = name.partition(".")
        return (sensor, channel) if sensor and channel else None
    channel, sep, sensor = name.partition("_")
    if sep and sensor and channel in ALL_CHANNELS:
        return sensor, channel
    return None


def noise_edits(estimate: NoiseEstimate, vehicle, *, columns: Sequence[str] | None = None,
                digits: int = 4) -> dict[str, float]:
    """Vehicle-file edits ``sensors[name=S].variance.C`` for each column (see the module docstring).

    Raises with the list of columns that name no sensor/channel of the vehicle.
    """
    from rovlab.params.vehicle import SENSOR_CHANNELS

    edits: dict[str, float] = {}
    problems = []
    sensors = {s.name: s for s in vehicle.sensors}
    for col in columns if columns is not None else estimate.channels:
        parsed = parse_channel_column(col)
        if parsed is None:
            problems.append(f"{col!r} (expected <sensor>.<channel> or <channel>_<sensor>)")
            continue
        sensor, channel = parsed
        if sensor not in sensors:
            problems.append(f"{col!r} (no sensor named {sensor!r}; the vehicle has {', '.join(sensors) or 'none'})")
            continue
        allowed = SENSOR_CHANNELS.get(sensors[sensor].kind, ())
        if channel not in allowed:
            problems.append(f"{col!r} (a {sensors[sensor].kind} sensor has channels {', '.join(allowed)})")
            continue
        edits[f"sensors[name={sensor}].variance.{channel}"] = significant(estimate.channels[col].variance, digits)
    if problems:
        raise IdentificationError("cannot map column(s) to the vehicle's sensors: " + "; ".join(problems))
    return edits
