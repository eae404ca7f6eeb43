"""Exact discretisation and the Riccati solver."""

from __future__ import annotations

import math

import numpy as np
import pytest

from roadbev_core.ride.lti import LtiError, discretise, expm_integral, solve_dare


def test_discretise_a_first_order_lag() -> None:
    a, dt = -3.0, 0.1
    Phi, Gamma = discretise(np.array([[a]]), np.array([[2.0]]), dt)
    assert Phi[0, 0] == pytest.approx(math.exp(a * dt))
    assert Gamma[0, 0] == pytest.approx(2.0 * (math.exp(a * dt) - 1) / a)


def test_expm_of_a_rotation() -> None:
    E, _ = expm_integral(np.array([[0.0, -1.0], [1.0, 0.0]]) * 2.0)
    expected = np.array([[math.cos(2), -math.sin(2)], [math.sin(2), math.cos(2)]])
    assert np.abs(E - expected).max() < 1e-10


def test_dare_solution_satisfies_the_equation() -> None:
    rng = np.random.default_rng(0)
    A = np.array([[1.0, 0.01], [-0.2, 0.98]])
    B = np.array([[0.0], [0.01]])
    Q = np.diag([1.0, 0.1])
    R = np.array([[0.01]])
    N = rng.normal(0, 0.001, (2, 1))
    P = solve_dare(A, B, Q, R, N)
    S = R + B.T @ P @ B
    residual = A.T @ P @ A - (A.T @ P @ B + N) @ np.linalg.solve(S, B.T @ P @ A + N.T) + Q - P
    assert np.abs(residual).max() < 1e-8 * np.abs(P).max()
    K = np.linalg.solve(S, B.T @ P @ A + N.T)
    assert np.abs(np.linalg.eigvals(A - B @ K)).max() < 1.0  # stabilising


def test_bad_inputs() -> None:
    with pytest.raises(LtiError):
        discretise(np.eye(2), np.ones((2, 1)), 0.0)
    with pytest.raises(LtiError):
        expm_integral(np.full((2, 2), math.nan))
