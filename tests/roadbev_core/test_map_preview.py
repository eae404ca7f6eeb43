"""The contact plane and the wheel-track preview read off the fused map."""

from __future__ import annotations

import numpy as np

from roadbev_core.config import VehicleConfig
from roadbev_core.map_preview import BODY_PLANE_SIGMA, contact_plane_fit
from roadbev_core.vehicle import contact_plane


def _contacts(front_left_height: float) -> np.ndarray:
    """[4, 3] the four tyre contacts in base_link (x, y) on a road with a 1 % grade, one front
    wheel raised by ``front_left_height`` (a kerb)."""
    wheels = VehicleConfig().wheel_positions()  # [4, 2] front left, front right, rear left, rear right
    z = 0.01 * wheels[:, 0]
    z[0] += front_left_height
    return np.column_stack([wheels, z])


def test_the_contact_plane_is_the_contracts_whatever_the_sigmas() -> None:
    # One wheel on a 12 cm kerb, its cell far less certain than the others': a sigma-weighted fit
    # would all but drop it and tilt the plane by degrees; the interface's plane counts every contact.
    points = _contacts(0.12)
    sigmas = np.array([0.05, 0.004, 0.004, 0.004])
    coeffs, _ = contact_plane_fit(points, sigmas)
    np.testing.assert_allclose(coeffs, contact_plane(points), atol=1e-12)
    weighted = np.linalg.lstsq(np.column_stack([np.ones(4), points[:, :2]]) / sigmas[:, None],
                               points[:, 2] / sigmas, rcond=None)[0]
    assert abs(weighted[1] - coeffs[1]) > 0.01  # the weighted plane's grade is a degree off


def test_the_contact_planes_covariance_is_propagated_from_the_contacts_sigmas() -> None:
    points = _contacts(0.0)
    sigmas = np.array([0.02, 0.004, 0.004, 0.008])
    coeffs, cov = contact_plane_fit(points, sigmas)
    rng = np.random.default_rng(3)
    draws = np.array([contact_plane_fit(np.column_stack([points[:, :2], points[:, 2] + rng.normal(0.0, sigmas)]),
                                        sigmas)[0] for _ in range(4000)])  # [4000, 3]
    np.testing.assert_allclose(draws.mean(axis=0), coeffs, atol=3e-4)
    np.testing.assert_allclose(np.cov(draws.T), cov, rtol=0.1, atol=1e-9)


def test_with_fewer_than_three_contacts_the_prior_decides_what_they_leave_open() -> None:
    points = _contacts(0.0)[:2]  # the front axle only: its roll is known, its pitch is not
    prior_mean = np.array([0.0, 0.02, 0.0])
    h, ang = BODY_PLANE_SIGMA
    coeffs, cov = contact_plane_fit(points, np.full(2, 0.004), (prior_mean, np.diag([h * h, ang * ang, ang * ang])))
    assert np.all(np.isfinite(coeffs)) and np.all(np.linalg.eigvalsh(cov) > 0)
    np.testing.assert_allclose(coeffs[0] + coeffs[1] * points[:, 0] + coeffs[2] * points[:, 1], points[:, 2],
                               atol=1e-3)  # through the two contacts it has
    assert np.sqrt(cov[1, 1]) > 0.5 * ang  # the pitch stays about as uncertain as its prior
