"""The LiDAR labeller's geometry and road-surface test (roadbev_lab.data.lidar_labels)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from roadbev_core.config import GridSpec
from roadbev_core.geometry import Attitude, road_to_camera
from roadbev_core.labels import elevation_map
from roadbev_lab.data.lidar_labels import (
    LabelConfig,
    LabelError,
    accumulate_label,
    fit_road_plane,
    planar_transform,
    road_points,
    scan_to_road,
    vertical_offset,
)

GRID = GridSpec(x_min=4.0, x_max=10.0, y_min=-2.0, y_max=2.0, resolution=0.1, base_height=1.6)


def _road(rng: np.random.Generator, n: int = 40_000, noise: float = 0.005) -> np.ndarray:
    """Points on a slightly tilted road with a 6 cm speed bump across x = 7 m."""
    x = rng.uniform(GRID.x_min - 1, GRID.x_max + 1, n)
    y = rng.uniform(GRID.y_min - 1, GRID.y_max + 1, n)
    z = 0.02 + 0.004 * x - 0.01 * y + 0.06 * np.exp(-0.5 * ((x - 7.0) / 0.15) ** 2) + rng.normal(0, noise, n)
    return np.stack([x, y, z], axis=1)


def test_plane_fit_ignores_a_car() -> None:
    rng = np.random.default_rng(0)
    road = _road(rng)
    car = np.stack([rng.uniform(5, 8, 5000), rng.uniform(0.5, 2.0, 5000), rng.uniform(0.1, 1.4, 5000)], axis=1)
    plane = fit_road_plane(np.concatenate([road, car]), LabelConfig())
    assert plane.offset == pytest.approx(0.02, abs=0.004)
    assert plane.slope_x == pytest.approx(0.004, abs=0.001)
    assert plane.slope_y == pytest.approx(-0.01, abs=0.002)


def test_road_test_rejects_obstacles_and_rough_tiles_but_keeps_a_bump() -> None:
    rng = np.random.default_rng(1)
    road = _road(rng)
    # A car standing on the road: its sides from the ground up, plus tyre contact points at z ~ 0.
    car = np.stack([rng.uniform(5, 7, 4000), rng.uniform(-2.0, -1.0, 4000), rng.uniform(0.0, 1.4, 4000)], axis=1)
    # Grass on a kerb top: a rough tile patch within the height band.
    grass = np.stack([rng.uniform(8.0, 9.0, 3000), rng.uniform(1.4, 2.0, 3000), rng.uniform(0.0, 0.18, 3000)], axis=1)
    pts = np.concatenate([road, car, grass])
    sel = road_points(pts, GRID, LabelConfig())
    n_road = road.shape[0]
    kept_car, kept_grass = sel.keep[n_road : n_road + 4000], sel.keep[n_road + 4000 :]
    assert not kept_car.any()
    assert kept_grass.mean() < 0.05
    assert sel.rejected["obstacle"] > 0 and sel.rejected["rough_tile"] > 0
    # The bump is road: its crest (x = 7 m, away from the car and the grass) survives.
    crest = (np.abs(road[:, 0] - 7.0) < 0.05) & (road[:, 1] > -0.5) & (road[:, 1] < 1.0)
    assert sel.keep[:n_road][crest].mean() > 0.95
    label = elevation_map(pts[sel.keep], GRID)
    assert np.nanmax(label.elevation) > 0.07  # 2 cm offset + 6 cm bump, minus the tilt


def test_road_test_errors_are_clear() -> None:
    with pytest.raises(LabelError, match="no LiDAR point"):
        road_points(np.zeros((0, 3)), GRID, LabelConfig())
    far = np.array([[50.0, 0.0, 0.0]] * 100)
    with pytest.raises(LabelError, match="no LiDAR point"):
        road_points(far, GRID, LabelConfig())
    high = np.stack([np.linspace(5, 9, 100), np.zeros(100), np.full(100, 1.0)], axis=1)
    with pytest.raises(LabelError, match="base_height"):
        road_points(high, GRID, LabelConfig())


def test_scan_to_road_goes_through_the_extrinsic_and_attitude() -> None:
    att = Attitude.from_degrees(1.0, 3.0)
    road = np.array([[6.0, 0.5, 0.01], [8.0, -1.0, -0.02]])
    cam = road_to_camera(road, att, GRID.base_height)
    R = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # LiDAR (x fwd, z up) -> optical
    t = np.array([0.05, -0.3, 0.1])
    lidar = (cam - t) @ R  # inverse of p_cam = R p + t
    back = scan_to_road(
        np.concatenate([lidar, [[np.nan, 0, 0], [500.0, 0, 0]]]), R, t, att, GRID.base_height, max_range_m=100.0
    )
    np.testing.assert_allclose(back, road, atol=1e-9)


def test_planar_transform_moves_points_with_the_vehicle() -> None:
    p = np.array([[10.0, 0.0, 0.03], [7.0, 1.0, -0.01]])
    # The frame 2 m further along, turned 90 degrees to the left.
    moved = planar_transform((0.0, 0.0, 0.0), (2.0, 0.0, math.pi / 2), p)
    np.testing.assert_allclose(moved, [[0.0, -8.0, 0.03], [1.0, -5.0, -0.01]], atol=1e-12)
    back = planar_transform((2.0, 0.0, math.pi / 2), (0.0, 0.0, 0.0), moved)
    np.testing.assert_allclose(back, p, atol=1e-12)


def test_accumulation_aligns_moved_scans_vertically() -> None:
    rng = np.random.default_rng(2)
    own = _road(rng, 6000)
    other = _road(rng, 20_000)
    other[:, 2] += 0.015  # the body heaved 1.5 cm between the two scans (odometry is planar)
    single = accumulate_label(own, [], GRID, LabelConfig())
    both = accumulate_label(own, [other], GRID, LabelConfig())
    assert both.scans_used == 2
    assert both.offsets_m[0] == pytest.approx(0.015, abs=0.002)
    assert both.label.mask.sum() > single.label.mask.sum()
    common = single.label.mask & both.label.mask
    bias = np.mean(both.label.elevation[common] - single.label.elevation[common])
    assert abs(bias) < 0.002
    assert vertical_offset(single.label, single.label, 10) == 0.0
    assert vertical_offset(single.label, elevation_map(np.zeros((0, 3)), GRID), 10) is None


def test_config_from_params() -> None:
    cfg = LabelConfig.from_params({"label.window_s": 0.5, "label.obstacle_min_points": 4, "base_height": 1.2})
    assert cfg.window_s == 0.5 and cfg.obstacle_min_points == 4
    with pytest.raises(LabelError, match=r"unknown parameter 'label\.windw_s'"):
        LabelConfig.from_params({"label.windw_s": 0.5})
    with pytest.raises(LabelError, match="must be >= 0"):
        LabelConfig(window_s=-1.0)
    with pytest.raises(LabelError, match="obstacle_top_m"):
        LabelConfig(obstacle_height_m=3.0)
