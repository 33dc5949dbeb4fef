"""Gauss-Markov discretisation and correlated sampling (Sandøy 2016, sec. 3.2.2 and 3.2.4); linear models (sec. 5.1.1
and 5.2.1)."""

from __future__ import annotations

import numpy as np
import pytest

from rovlab.models.linear import HeaveYawParams, control_model, observer_model
from rovlab.models.noise import (
    correlated_samples,
    gauss_markov_coefficients,
    gauss_markov_from_psd,
    gauss_markov_step,
    psd_factor,
)


def test_gauss_markov_statistics_do_not_depend_on_step(rng):
    sigma2, beta = 0.04, 0.5
    for h in (0.01, 0.1, 1.0):
        phi, std = gauss_markov_coefficients(sigma2, beta, h)
        b = np.zeros(4000)
        b[:] = rng.normal(0.0, np.sqrt(sigma2), 4000)  # start stationary
        for _ in range(50):
            b = gauss_markov_step(b, phi, std, rng)
        assert np.var(b) == pytest.approx(sigma2, rel=0.08)
        # lag-h autocorrelation exp(-beta h) of a first-order Gauss-Markov process (Brown & Hwang 2012, ch. 2)
        b2 = gauss_markov_step(b, phi, std, rng)
        assert np.corrcoef(b, b2)[0, 1] == pytest.approx(np.exp(-beta * h), abs=0.04)


def test_gauss_markov_from_psd_stationary_variance():
    phi, std = gauss_markov_from_psd(0.2, 10.0, 0.1)
    assert std**2 / (1 - phi**2) == pytest.approx(0.2 * 10.0 / 2)


def test_psd_factor_handles_semidefinite(rng):
    A = rng.normal(size=(4, 2))
    Q = A @ A.T  # rank 2
    L = psd_factor(Q)
    np.testing.assert_allclose(L @ L.T, Q, atol=1e-12)
    with pytest.raises(ValueError, match="positive semi-definite"):
        psd_factor(np.diag([1.0, -1.0]))
    samples = correlated_samples(np.array([[2.0, 0.6], [0.6, 1.0]]), 200_000, rng)
    np.testing.assert_allclose(np.cov(samples.T), [[2.0, 0.6], [0.6, 1.0]], atol=0.02)


def test_observer_model_structure():
    # thesis design values (Sandøy 2016, appendix A.3)
    p = HeaveYawParams.from_values(m=7.31, I_zz=0.16, Z_wdot=-11.13, N_rdot=-0.1, Z_w=-5.18, N_r=-0.06656)
    assert p.M_w == pytest.approx(18.44) and p.M_r == pytest.approx(0.26)
    A, B, E = observer_model(p, 100 * p.M_w, 100 * p.M_r)
    assert A.shape == (6, 6) and B.shape == (6, 2) and E.shape == (6, 6)
    assert A[2, 2] == pytest.approx(-5.18 / 18.44) and A[2, 4] == pytest.approx(1 / 18.44)
    assert A[4, 4] == pytest.approx(-1 / 1844.0) and A[5, 5] == pytest.approx(-1 / 26.0)
    assert B[3, 1] == pytest.approx(1 / 0.26) and E[4, 4] == 1.0 and E[2, 2] == pytest.approx(1 / 18.44)
    Ac, Bc, Cc = control_model(p)
    np.testing.assert_array_equal(Ac, A[:4, :4])
    np.testing.assert_array_equal(Bc, B[:4])
    np.testing.assert_array_equal(Cc, np.hstack([np.eye(2), np.zeros((2, 2))]))
    with pytest.raises(ValueError):
        observer_model(p, 0.0, 1.0)
