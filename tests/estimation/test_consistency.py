"""NEES/NIS helpers and a Monte Carlo consistency check of the filter on its own model."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from rovlab.estimation.consistency import check, chi2_interval, nees, nis, wrap_errors
from rovlab.estimation.filtering import DepthHeadingFilter
from rovlab.estimation.model import build_filter_model
from rovlab.params.design import load_design_config
from rovlab.params.vehicle import load_vehicle


def test_chi2_interval_and_statistics():
    # Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4.2: N runs of an n-dof statistic
    lo, hi = chi2_interval(6, 50, 0.95)
    assert lo == pytest.approx(chi2.ppf(0.025, 300) / 50) and hi == pytest.approx(chi2.ppf(0.975, 300) / 50)
    assert lo < 6 < hi
    P = np.diag([4.0, 9.0])
    assert nees(np.array([2.0, 3.0]), P) == pytest.approx(2.0)
    assert nis(np.array([1.0, 2.0]), np.array([1.0, 4.0])).tolist() == [1.0, 1.0]
    e = wrap_errors(np.array([[0.0, 2 * np.pi - 0.1], [0.0, -np.pi]]))
    np.testing.assert_allclose(e[:, 1], [-0.1, np.pi])
    with pytest.raises(ValueError):
        chi2_interval(0)


def test_filter_is_consistent_on_its_own_model():
    # NEES against chi-square bounds over Monte Carlo runs (Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4);
    # the thesis has no consistency test, so requiring one is decided here.
    model = build_filter_model(load_vehicle("udrone"), load_design_config("thesis"))
    filt = DepthHeadingFilter(model)
    runs, n = 40, 150
    rng = np.random.default_rng(2016)
    L = np.linalg.cholesky(model.Q)
    P0 = np.diag([1e-4, 1e-3, 1e-4, 1e-4, 1e-2, 1e-4])
    stats = np.empty((runs, n))
    nis_z = np.empty((runs, n))
    for i in range(runs):
        x = model.x0 + np.linalg.cholesky(P0) @ rng.standard_normal(6)
        X = np.empty((n, 6))
        u = np.zeros((n, 2))
        for k in range(n):
            X[k] = x
            x = model.Phi @ x + L @ rng.standard_normal(6)
        y = X @ model.H.T + rng.standard_normal((n, 3)) * np.sqrt(np.diag(model.R))
        y += np.array([c.offset for c in model.channels])
        run = filt.run(np.arange(n) * model.h, u, y, belief=filt.initial_belief(P0=P0))
        # the full covariance is in the online reports; the run gives the corrected estimates
        b = filt.initial_belief(P0=P0)
        for k in range(n):
            b, rep = filt.step(b, k * model.h, u[k], y[k])
            stats[i, k] = nees(wrap_errors(X[k] - rep.x), rep.P)
        nis_z[i] = run.innovation[:, 0] ** 2 / run.innovation_variance[:, 0]
    res = check(stats, dof=6)
    assert res.consistent() and abs(res.mean - 6.0) < 0.6
    assert check(nis_z, dof=1).consistent()


def test_steps_with_fewer_runs_use_the_wider_interval():
    # 50 runs of a 1-dof statistic; at step 1 only 2 runs have a value. Their average (3.0) is
    # well inside the 2-run interval [0.025, 5.6] but outside the 50-run one [0.64, 1.43]:
    # the check must judge each step by the runs that contributed (as its docstring says).
    s = np.ones((50, 2))
    s[:, 1] = np.nan
    s[:2, 1] = [2.5, 3.5]
    res = check(s, dof=1)
    assert res.average[1] == pytest.approx(3.0)
    lo, hi = res.bounds()
    assert (lo[1], hi[1]) == pytest.approx(chi2_interval(1, 2))
    assert (lo[0], hi[0]) == pytest.approx(chi2_interval(1, 50))
    assert (res.lower, res.upper) == pytest.approx(chi2_interval(1, 50))
    assert res.fraction_inside == 1.0
