"""Exact discretisation and Van Loan's method against closed forms and the thesis's Q."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rovlab.estimation.model import build_filter_model
from rovlab.models.discretise import discretise, van_loan, zoh
from rovlab.params.design import load_design_config
from rovlab.params.vehicle import load_vehicle


def test_van_loan_double_integrator_closed_form():
    # x1' = x2, x2' = w with E[w(t)w(s)] = q delta(t - s): the discrete noise covariance is
    # Q = q [[h^3/3, h^2/2], [h^2/2, h]]: integrate e^{As} E q E^T e^{A^T s} = q [[s^2, s], [s, 1]]
    # over [0, h] (e^{As} = [[1, s], [0, 1]]); the "continuous white noise acceleration" model of
    # Bar-Shalom, Li & Kirubarajan 2001, ch. 6.
    q, h = 0.37, 0.25
    A = np.array([[0.0, 1.0], [0.0, 0.0]])
    E = np.array([[0.0], [1.0]])
    Phi, Q = van_loan(A, E, np.array([[q]]), h)
    np.testing.assert_allclose(Phi, [[1.0, h], [0.0, 1.0]], rtol=0, atol=1e-15)
    np.testing.assert_allclose(Q, q * np.array([[h**3 / 3, h**2 / 2], [h**2 / 2, h]]), rtol=1e-12)


def test_van_loan_gauss_markov_closed_form():
    # x' = -beta x + w, PSD q: Q = int_0^h q e^{-2 beta s} ds = q (1 - e^{-2 beta h}) / (2 beta),
    # Phi = e^{-beta h}; rovlab.models.noise discretises the same Gauss-Markov process.
    from rovlab.models.noise import gauss_markov_from_psd

    q, beta, h = 2e-1, 1.0 / 1844.0, 0.1
    Phi, Q = van_loan(np.array([[-beta]]), np.eye(1), np.array([[q]]), h)
    assert Phi[0, 0] == pytest.approx(math.exp(-beta * h), rel=1e-14)
    assert Q[0, 0] == pytest.approx(q * (1 - math.exp(-2 * beta * h)) / (2 * beta), rel=1e-12)
    phi, std = gauss_markov_from_psd(q, 1.0 / beta, h)
    assert Q[0, 0] == pytest.approx(float(std) ** 2, rel=1e-9)


def test_zoh_first_order_closed_form():
    # x' = -a x + b u with u held: Phi = e^{-a h}, Delta = b (1 - e^{-a h}) / a
    a, b, h = 0.28, 0.054, 0.1
    Phi, Delta = zoh(np.array([[-a]]), np.array([[b]]), h)
    assert Phi[0, 0] == pytest.approx(math.exp(-a * h), rel=1e-14)
    assert Delta[0, 0] == pytest.approx(b * (1 - math.exp(-a * h)) / a, rel=1e-12)


def _thesis_model():
    return build_filter_model(load_vehicle("udrone"), load_design_config("thesis"))


# Thesis eq. 5.31 (Sandøy 2016, sec. 5.3.1), printed to 2 digits.
Q_THESIS = [
    ["9.9e-09", "0", "1.5e-07", "0", "1.8e-06", "0"],
    ["0", "7.3e-09", "0", "1.8e-07", "0", "6.3e-07"],
    ["1.5e-07", "0", "3.1e-06", "0", "5.4e-05", "0"],
    ["0", "1.8e-07", "0", "4.8e-06", "0", "1.9e-05"],
    ["1.8e-06", "0", "5.4e-05", "0", "0.02", "0"],
    ["0", "6.3e-07", "0", "1.9e-05", "0", "1.0e-04"],
]


def _half_unit_in_last_digit(text: str) -> float:
    mantissa = text.lower().split("e")[0].lstrip("0.").replace(".", "") or "0"
    value = float(text)
    return 0.5 * 10 ** (math.floor(math.log10(abs(value))) - (len(mantissa) - 1))


def test_thesis_Q_eq_5_31_reproduced():
    Q = _thesis_model().Q
    for i in range(6):
        for j in range(6):
            printed = Q_THESIS[i][j]
            if float(printed) == 0.0:
                assert Q[i, j] == 0.0, (i, j)
            else:
                assert abs(Q[i, j] - float(printed)) <= _half_unit_in_last_digit(printed), (i, j, Q[i, j], printed)
    assert np.array_equal(Q, Q.T)
    assert np.min(np.linalg.eigvalsh(Q)) > 0  # the thesis drew noise with chol(Q): positive definite


def test_thesis_model_matrices_are_consistent():
    m = _thesis_model()
    # the two routes to Phi (augmented ZOH exponential and Van Loan) agree
    Phi_vl, _ = van_loan(m.A, m.E, m.W, m.h)
    np.testing.assert_allclose(Phi_vl, m.Phi, rtol=0, atol=1e-14)
    # Gamma = int e^{As} ds E (MATLAB c2d(A, E)); the velocity noise enters like the input
    np.testing.assert_allclose(m.Gamma[:, 2:4], m.Delta, rtol=1e-12, atol=1e-18)
    # T = 100 M (thesis appendix A.3): T_w = 100 (7.31 + 11.13), T_r = 100 (0.16 + 0.1)
    assert m.T_w == pytest.approx(1844.0) and m.T_r == pytest.approx(26.0)


def test_discretise_rejects_bad_input():
    A = np.zeros((2, 2))
    with pytest.raises(ValueError, match="sample time"):
        discretise(A, np.ones((2, 1)), np.eye(2), np.eye(2), 0.0)
    with pytest.raises(ValueError, match="symmetric"):
        van_loan(A, np.eye(2), np.array([[1.0, 2.0], [0.0, 1.0]]), 0.1)
    with pytest.raises(ValueError, match="square"):
        zoh(np.zeros((2, 3)), np.ones((2, 1)), 0.1)
