"""Steady windows of constant-speed runs (towing carriage, constant-moment yaw runs).

A run ramps up, holds a speed (or yaw rate) and ramps down. Its steady window is the longest
stretch where a smoothed speed stays within a tolerance of the plateau value, trimmed at both
ends (load-cell lag, flow settling). Means over the window get a standard error that accounts
for the serial correlation of the samples (effective sample size from the lag-1 correlation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rovlab.ident.fitting import IdentificationError


@dataclass(frozen=True)
class Window:
    start: int  # first index (inclusive)
    stop: int  # last index (exclusive)
    level: float  # plateau value of the signal the window was found on
    tolerance: float


def smooth(x: np.ndarray, n: int) -> np.ndarray:
    """Centred moving average over n samples (shorter at the ends)."""
    x = np.asarray(x, dtype=float)
    n = max(1, min(int(n), x.size))
    if n == 1:
        return x.copy()
    c = np.cumsum(np.concatenate([[0.0], x]))
    half = n // 2
    lo = np.clip(np.arange(x.size) - half, 0, x.size)
    hi = np.clip(np.arange(x.size) - half + n, 0, x.size)
    return (c[hi] - c[lo]) / (hi - lo)


def noise_level(x: np.ndarray) -> float:
    """Robust white-noise standard deviation from first differences (MAD / 0.6745 / sqrt 2)."""
    d = np.diff(np.asarray(x, dtype=float))
    if d.size == 0:
        return 0.0
    return float(np.median(np.abs(d - np.median(d))) / 0.6745 / np.sqrt(2.0))


def plateau_window(t: np.ndarray, x: np.ndarray, *, what: str, min_s: float = 2.0, trim_s: float = 1.0,
                   rel_tol: float = 0.03, smooth_s: float = 0.5) -> Window:
    """Longest stretch of a run where x stays at its plateau (the largest |x| it holds)."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    if t.size < 5:
        raise IdentificationError(f"{what}: {t.size} sample(s); a run needs a time series")
    h = float(np.median(np.diff(t)))
    xs = smooth(x, round(smooth_s / h) if h > 0 else 1)
    amp = float(np.percentile(np.abs(xs), 95))
    sigma = noise_level(x)
    if amp <= 5 * sigma / np.sqrt(max(1, round(smooth_s / h))) or amp == 0:
        raise IdentificationError(f"{what}: the run never leaves rest (95th percentile of |speed| is {amp:.3g})")
    big = np.abs(xs) >= 0.8 * amp
    sign = np.sign(np.median(xs[big]))
    level = float(np.median(xs[big & (np.sign(xs) == sign)]))
    tol = max(rel_tol * abs(level), 4 * sigma / np.sqrt(max(1, round(smooth_s / h))))
    ok = np.abs(xs - level) <= tol
    best = (0, 0)
    i = 0
    n = ok.size
    while i < n:
        if ok[i]:
            j = i
            while j < n and ok[j]:
                j += 1
            if j - i > best[1] - best[0]:
                best = (i, j)
            i = j
        else:
            i += 1
    k = int(round(trim_s / h))
    a, b = best[0] + k, best[1] - k
    if (b - a) * h < min_s:
        raise IdentificationError(
            f"{what}: the steady part at {level:.3g} lasts only {max(0, b - a) * h:.3g} s after trimming "
            f"{trim_s:g} s at each end; need at least {min_s:g} s at constant speed")
    return Window(a, b, level, tol)


def rest_samples(t: np.ndarray, x: np.ndarray, window: Window, *, margin_s: float = 0.5,
                 min_s: float = 1.0) -> np.ndarray:
    """Indices at rest before the motion begins and after it ends (for the load-cell tare).

    Each stretch must last at least ``min_s`` after a ``margin_s`` guard next to the motion;
    an empty array means the run has no usable rest.
    """
    x = np.asarray(x, dtype=float)
    h = float(np.median(np.diff(t)))
    moving = np.flatnonzero(np.abs(smooth(x, max(1, round(0.5 / h)))) > 0.1 * abs(window.level))
    if moving.size == 0:
        return np.zeros(0, dtype=int)
    guard = int(round(margin_s / h))
    need = int(round(min_s / h))
    parts = []
    end = int(moving[0]) - guard
    if end >= need and end <= window.start:
        parts.append(np.arange(0, end))
    begin = int(moving[-1]) + 1 + guard
    if x.size - begin >= need and begin >= window.stop:
        parts.append(np.arange(begin, x.size))
    return np.concatenate(parts) if parts else np.zeros(0, dtype=int)


def mean_with_stderr(x: np.ndarray) -> tuple[float, float]:
    """Mean and its standard error, with the sample count reduced for lag-1 correlation."""
    x = np.asarray(x, dtype=float)
    n = x.size
    m = float(np.mean(x))
    if n < 3:
        return m, float("nan")
    d = x - m
    var = float(d @ d) / (n - 1)
    rho = float(d[:-1] @ d[1:]) / float(d @ d) if var > 0 else 0.0
    rho = min(max(rho, 0.0), 0.99)
    n_eff = n * (1 - rho) / (1 + rho)
    return m, float(np.sqrt(var / max(n_eff, 1.0)))
