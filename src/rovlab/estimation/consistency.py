"""Filter consistency: normalised estimation error and innovation squared with chi-square bounds.

For a consistent filter (Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4):

* NEES  eps_k = e_k^T P_k^-1 e_k, e_k = x_k - x_hat_k, is chi-square with n degrees of freedom;
* NIS   eps_k = nu_k^T S_k^-1 nu_k (innovation nu_k, its covariance S_k) is chi-square with the
  measurement dimension.

Over N independent Monte Carlo runs the average (1/N) sum eps_k^i is chi-square with N n degrees
of freedom divided by N, so a two-sided probability-p acceptance interval for it is
[chi2.ppf((1-p)/2, N n) / N, chi2.ppf((1+p)/2, N n) / N]. A consistent filter keeps the average
inside that interval at about a fraction p of the time steps; far above means over-confident
(P too small), far below means pessimistic. These helpers are what the simulator's Monte Carlo
uses; angle errors must be wrapped before calling them (see ``wrap_errors``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rovlab.core.angles import wrap


def wrap_errors(error: np.ndarray, angle_columns: tuple[int, ...] = (1,)) -> np.ndarray:
    """A copy of error (..., n) with the given state columns wrapped to (-pi, pi] (psi is 1)."""
    e = np.array(error, dtype=float)
    for c in angle_columns:
        e[..., c] = wrap(e[..., c])
    return e


def nees(error: np.ndarray, P: np.ndarray) -> np.ndarray:
    """e^T P^-1 e for errors (..., n) and covariances (..., n, n); shape (...)."""
    e = np.asarray(error, dtype=float)
    P = np.asarray(P, dtype=float)
    if P.shape[-2:] != (e.shape[-1], e.shape[-1]):
        raise ValueError(f"errors have {e.shape[-1]} states but P is {P.shape[-2:]}")
    sol = np.linalg.solve(P, e[..., None])[..., 0]
    return np.einsum("...i,...i->...", e, sol)


def nis(innovation: np.ndarray, S: np.ndarray) -> np.ndarray:
    """nu^T S^-1 nu. Scalar channels: innovation (...,) with variances S (...,) give nu^2 / S;
    vectors: innovation (..., m) with S (..., m, m)."""
    nu = np.asarray(innovation, dtype=float)
    S = np.asarray(S, dtype=float)
    if S.shape == nu.shape:
        return nu * nu / S
    return nees(nu, S)


def chi2_interval(dof: int, runs: int = 1, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided acceptance interval for the average of ``runs`` chi-square(dof) statistics."""
    if dof < 1 or runs < 1 or not 0.0 < probability < 1.0:
        raise ValueError("need dof >= 1, runs >= 1 and 0 < probability < 1")
    a = (1.0 - probability) / 2.0
    k = dof * runs
    return float(chi2_ppf(a, k) / runs), float(chi2_ppf(1.0 - a, k) / runs)


def chi2_ppf(q: float, dof: Any) -> Any:
    """scipy.stats.chi2.ppf(q, dof) for 0 < q < 1 and dof >= 1 (an int or an int array), by the
    special function scipy.stats computes it with (2 gammaincinv(dof/2, q), the inverse of the
    regularised lower incomplete gamma function), without importing scipy.stats (~0.5 s); each
    value is computed once per process."""
    d = np.asarray(dof)
    if d.ndim == 0:
        out: Any = _quantiles(float(q), [d.item()])[0]
        return out
    uniq, inverse = np.unique(d, return_inverse=True)
    return np.asarray(_quantiles(float(q), uniq.tolist()), dtype=float)[inverse].reshape(d.shape)


_QUANTILES: dict[str, float] = {}  # "q dof" -> chi2.ppf(q, dof), computed once per process


def _quantiles(q: float, dofs: list[Any]) -> list[float]:
    out = []
    for dof in dofs:
        key = f"{q!r} {dof!r}"
        value = _QUANTILES.get(key)
        if value is None:
            from scipy.special import gammaincinv

            value = _QUANTILES[key] = float(2.0 * gammaincinv(float(dof) / 2.0, q))
        out.append(value)
    return out


@dataclass(frozen=True)
class ConsistencyCheck:
    """Average statistic per time step against its chi-square interval.

    ``lower``/``upper`` are the interval for all ``runs``; a step where only some runs have a
    value (``count``) is judged against the wider interval of that many runs.
    """

    average: np.ndarray  # (T,) Monte Carlo average of the statistic
    lower: float
    upper: float
    dof: int
    runs: int
    probability: float
    count: np.ndarray | None = None  # (T,) runs that contributed at each step (None: all)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-step (lower, upper) for the number of runs that contributed (NaN where none did)."""
        T = self.average.shape[0]
        count = np.full(T, self.runs) if self.count is None else np.asarray(self.count)
        lo = np.full(T, np.nan)
        hi = np.full(T, np.nan)
        ok = count > 0
        a = (1.0 - self.probability) / 2.0
        k = self.dof * count[ok]
        lo[ok] = chi2_ppf(a, k) / count[ok]
        hi[ok] = chi2_ppf(1.0 - a, k) / count[ok]
        return lo, hi

    @property
    def fraction_inside(self) -> float:
        ok = np.isfinite(self.average)
        if not ok.any():
            return float("nan")
        lo, hi = self.bounds()
        a = self.average[ok]
        return float(np.mean((a >= lo[ok]) & (a <= hi[ok])))

    @property
    def mean(self) -> float:
        """Time average of the average statistic (about dof for a consistent filter)."""
        return float(np.nanmean(self.average))

    def consistent(self, slack: float = 0.1) -> bool:
        """True when at least (probability - slack) of the steps are inside the interval."""
        return self.fraction_inside >= self.probability - slack


def check(statistic: np.ndarray, dof: int, probability: float = 0.95) -> ConsistencyCheck:
    """Average a (runs, T) array of NEES or NIS values over runs (NaN = not available) and
    compare it with the chi-square interval for the number of runs that contributed."""
    s = np.atleast_2d(np.asarray(statistic, dtype=float))
    runs = int(s.shape[0])
    count = np.sum(~np.isnan(s), axis=0)
    total = np.nansum(s, axis=0)
    average = np.full(s.shape[1], np.nan)
    np.divide(total, count, out=average, where=count > 0)
    lo, hi = chi2_interval(dof, runs, probability)
    return ConsistencyCheck(average=average, lower=lo, upper=hi, dof=dof, runs=runs, probability=probability,
                            count=count)
