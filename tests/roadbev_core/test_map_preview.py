"""The contact plane and the wheel-track preview read off the fused map."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from roadbev_core.config import GridSpec, RoadbevConfig, VehicleConfig
from roadbev_core.ego_motion import PlanarPose
from roadbev_core.fusion import FusedMap, map_settings, place_frame
from roadbev_core.geometry import R_BODY_FROM_OPTICAL, Attitude
from roadbev_core.map_preview import BODY_PLANE_SIGMA, contact_plane_fit, map_preview
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


def _road_frame_truth(grid: GridSpec, road_x: Callable[[np.ndarray], np.ndarray], camera: np.ndarray,
                      base_x: float) -> np.ndarray:
    """[R, C] a road whose height depends on odom x only, in the road frame of a level camera on a
    body at (base_x, 0) with base_link on the road at z 0."""
    x = base_x + camera[0] + grid.x_centres()[:, None] + 0.0 * grid.y_centres()[None, :]
    return np.asarray(road_x(x) - (camera[2] - grid.base_height), np.float64)


def test_with_the_far_field_the_map_preview_reaches_15_m_ahead_of_the_camera_with_times_and_sigma() -> None:
    config = RoadbevConfig.from_params({"far_field.enabled": True})
    grid, far_grid, vehicle = config.grid, config.far_grid, config.vehicle
    assert far_grid is not None
    camera = np.array(vehicle.camera_position_m)

    def bump(x: np.ndarray) -> np.ndarray:  # a 6 cm bump 13 m ahead of the camera at the last frame
        return np.asarray(0.06 * np.exp(-(((x - (camera[0] + 13.0 + 0.5)) / 0.5) ** 2)), np.float64)

    fused = FusedMap(map_settings(config))
    for k in range(6):  # 0.1 m per frame along x
        base = PlanarPose(1 + k, 0.1 * k, 0.0, 0.0, 10.0, 0.0)
        placement = place_frame(base, Attitude(0.0, 0.0), camera, R_BODY_FROM_OPTICAL)
        fused.integrate(_road_frame_truth(grid, bump, camera, base.x), np.full(grid.shape, 0.004), grid, placement,
                        1 + k, base_z_prediction=0.0)
        fused.integrate_far(_road_frame_truth(far_grid, bump, camera, base.x), np.full(far_grid.shape, 0.01),
                            far_grid, placement, 1 + k)
    p = config.preview
    profiles = map_preview(fused, placement, vehicle, tyre_width_m=p.tyre_width_m, spacing_m=p.spacing_m,
                           vehicle_speed=10.0, max_gap_m=p.max_gap_m)
    x = profiles.distances()  # base_link x
    arrival = profiles.time_of_arrival()
    assert arrival is not None
    for track in profiles.tracks:
        known = np.isfinite(track.elevation)
        farthest = float(x[known].max()) - camera[0]
        assert farthest >= far_grid.x_max - p.spacing_m - 1e-9 and farthest >= 14.9  # to the far edge
        assert np.isfinite(track.uncertainty[known]).all() and np.isfinite(arrival[known]).all()
        at = int(np.argmax(np.where(known, track.elevation, -np.inf)))
        assert x[at] - camera[0] == pytest.approx(13.0, abs=0.15)  # the bump, where it is (base_link x)
        assert track.elevation[at] == pytest.approx(0.06, abs=0.01)
        assert arrival[at] == pytest.approx((x[at] - vehicle.wheelbase_m) / 10.0, rel=1e-5)
    off = FusedMap(map_settings(RoadbevConfig.from_params({"far_field.enabled": False})))
    assert off.settings.ahead_m == pytest.approx(camera[0] + grid.x_max)  # the far field off: the grid's edge
