"""Shared pieces of the identification tools: errors, least squares with standard errors, filters.

Standard errors come from the usual asymptotic covariance of a least-squares estimate,
cov = s^2 (J^T J)^-1 with s^2 = RSS / (n - p) (Ljung 1999, sec. 9.2); they assume independent
residuals and so are optimistic when the residuals are correlated (model error).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np


class IdentificationError(ValueError):
    """The data cannot support the requested fit; the message says what is missing."""


@dataclass(frozen=True, eq=False)
class LinearFit:
    """y ~ A c: estimates, their standard errors and covariance, residuals y - A c."""

    names: tuple[str, ...]
    coef: np.ndarray
    stderr: np.ndarray
    covariance: np.ndarray
    residuals: np.ndarray
    rms: float
    dof: int  # n - p

    def as_dict(self) -> dict[str, float]:
        return {n: float(c) for n, c in zip(self.names, self.coef)}

    def stderr_dict(self) -> dict[str, float]:
        return {n: float(s) for n, s in zip(self.names, self.stderr)}


def covariance_from_jacobian(J: np.ndarray, residuals: np.ndarray) -> np.ndarray:
    """s^2 (J^T J)^-1 for a least-squares solution with Jacobian J (n x p)."""
    n, p = J.shape
    if n <= p:
        return np.full((p, p), np.nan)
    s2 = float(residuals @ residuals) / (n - p)
    JtJ = J.T @ J
    try:
        return s2 * np.linalg.inv(JtJ)
    except np.linalg.LinAlgError:
        return s2 * np.linalg.pinv(JtJ)


def linear_lsq(A: np.ndarray, y: np.ndarray, names: Sequence[str], *, what: str = "fit") -> LinearFit:
    """Ordinary least squares with standard errors; refuses an under-determined problem."""
    A = np.asarray(A, dtype=float)
    y = np.asarray(y, dtype=float)
    n, p = A.shape
    if n <= p:
        raise IdentificationError(f"{what}: {n} data point(s) for {p} unknown(s) ({', '.join(names)}); "
                                  f"need at least {p + 1}")
    if np.linalg.matrix_rank(A) < p:
        raise IdentificationError(f"{what}: the data cannot separate {', '.join(names)} "
                                  "(the regressors are linearly dependent; use more distinct points)")
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    res = y - A @ coef
    cov = covariance_from_jacobian(A, res)
    return LinearFit(tuple(names), coef, np.sqrt(np.diag(cov)), cov, res,
                     float(np.sqrt(np.mean(res**2))), n - p)


def sample_rate(t: np.ndarray, *, what: str = "time_s") -> float:
    """Sampling rate [Hz] from the median step; refuses non-increasing or irregular time."""
    t = np.asarray(t, dtype=float)
    if t.size < 3:
        raise IdentificationError(f"{what}: {t.size} sample(s); need a time series")
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.flatnonzero(dt <= 0)[0]) + 1
        raise IdentificationError(f"{what}: time does not increase at sample {i} ({t[i - 1]:g} -> {t[i]:g})")
    h = float(np.median(dt))
    if np.max(dt) > 5 * h:
        i = int(np.argmax(dt))
        raise IdentificationError(f"{what}: gap of {dt[i]:g} s at t = {t[i]:g} s (median step {h:g} s); "
                                  "split the log at the gap")
    return 1.0 / h


def lowpass(x: np.ndarray, fs: float, cutoff_hz: float, order: int = 2) -> np.ndarray:
    """Zero-phase Butterworth low-pass (scipy.signal.butter + filtfilt, second-order sections)."""
    from scipy.signal import butter, sosfiltfilt

    if not 0 < cutoff_hz < fs / 2:
        raise IdentificationError(f"filter cut-off {cutoff_hz:g} Hz must be between 0 and the Nyquist "
                                  f"frequency {fs / 2:g} Hz")
    sos = butter(order, cutoff_hz, btype="low", fs=fs, output="sos")
    x = np.asarray(x, dtype=float)
    padlen = min(3 * (2 * len(sos) + 1), x.size - 1)  # scipy's default, shortened for tiny series
    return sosfiltfilt(sos, x, padlen=padlen)


def significant(x: float, digits: int = 4) -> float:
    """x rounded to a number of significant digits (for writing estimates to files)."""
    if x == 0 or not np.isfinite(x):
        return float(x)
    return float(f"{x:.{digits}g}")


def rounded(values: Mapping[str, float], digits: int = 4) -> dict[str, float]:
    return {k: significant(v, digits) for k, v in values.items()}


# Damping model shared by the towing and yaw tools ---------------------------------------------

DAMPING_TERMS = ("linear", "quadratic", "cubic")


def damping_regressors(speed: np.ndarray, terms: Sequence[str]) -> np.ndarray:
    """Columns v, |v| v, v^3 for the chosen terms (SNAME damping force X = X_u v + X_|u|u |v| v + X_uuu v^3)."""
    speed = np.asarray(speed, dtype=float)
    cols = {"linear": speed, "quadratic": np.abs(speed) * speed, "cubic": speed**3}
    return np.column_stack([cols[t] for t in terms])


def check_terms(terms: Sequence[str], allowed: Sequence[str] = DAMPING_TERMS) -> tuple[str, ...]:
    terms = tuple(dict.fromkeys(terms))
    bad = [t for t in terms if t not in allowed]
    if bad or not terms:
        raise IdentificationError(f"damping terms must be a non-empty selection of {', '.join(allowed)}; "
                                  f"got {', '.join(terms) or 'none'}")
    return tuple(t for t in allowed if t in terms)


def fit_damping(speed: np.ndarray, applied: np.ndarray, terms: Sequence[str], *, what: str) -> LinearFit:
    """SNAME damping coefficients from steady points where an applied force balances the damping.

    At a steady speed v, applied + D(v) = 0 with D(v) = sum_j c_j phi_j(v), so
    -applied = sum_j c_j phi_j(v): the coefficients c_j come out negative for a dissipative body.
    """
    terms = check_terms(terms)
    return linear_lsq(damping_regressors(speed, terms), -np.asarray(applied, dtype=float), terms, what=what)
