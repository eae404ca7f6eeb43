"""Road hazards on analytic maps and on the true road map of a drive: detection, heights, no false alarms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from roadbev_core.hazards import HazardError, HazardSettings, band, detect_hazards, road_residual, severity_cost
from roadbev_lab.synth import DriveConfig, RidingConfig, RidingDrive, RoadConfig

RES = 0.02


def _plane(n_rows: int = 1500, n_cols: int = 150, grade: float = 0.01, cross: float = 0.02) -> np.ndarray:
    """[R, C] a tilted plane, grid_map order, centre (0, 0): x from +15 m down, y from +1.5 m down."""
    x = 0.5 * n_rows * RES - (np.arange(n_rows) + 0.5) * RES
    y = 0.5 * n_cols * RES - (np.arange(n_cols) + 0.5) * RES
    return (grade * x[:, None] + cross * y[None, :]).astype(np.float32)


def _index(x: float, y: float, shape: tuple[int, int]) -> tuple[int, int]:
    return int(0.5 * shape[0] - x / RES), int(0.5 * shape[1] - y / RES)


def test_bump_and_pothole_on_a_tilted_plane() -> None:
    e = _plane()
    r0, c0 = _index(4.0, 0.3, e.shape)
    e[r0 - 15: r0 + 15, :] += 0.06  # a 6 cm, 0.6 m long bump across the map at x = 4 m
    r1, c1 = _index(-6.0, -0.4, e.shape)
    yy, xx = np.mgrid[-12:13, -12:13]
    e[r1 - 12: r1 + 13, c1 - 12: c1 + 13] -= np.where(xx**2 + yy**2 <= 144, 0.05, 0.0).astype(np.float32)
    sigma = np.full(e.shape, 0.004, np.float32)
    found = detect_hazards(e, sigma, RES, (0.0, 0.0))
    assert [h.kind for h in found] == ["bump", "pothole"]
    bump, hole = found
    assert bump.x == pytest.approx(4.0, abs=0.05) and bump.height_m == pytest.approx(0.06, rel=0.05)
    assert bump.length_m == pytest.approx(0.6, abs=0.05) and bump.width_m == pytest.approx(3.0, abs=0.05)
    assert (hole.x, hole.y) == pytest.approx((-6.0, -0.4), abs=0.05)
    assert hole.height_m == pytest.approx(-0.05, rel=0.05)
    assert bump.height_sigma_m == pytest.approx(0.004, abs=0.001) and bump.confidence == 1.0
    cost = severity_cost(road_residual(e, RES)[0])
    assert cost.dtype == np.int8 and 58 <= cost[r0, c0] <= 62 and cost[r0 + 100, c0] <= 2


def test_a_bump_the_map_is_unsure_of_is_no_hazard() -> None:
    e = _plane()
    r0, _ = _index(4.0, 0.3, e.shape)
    e[r0 - 15: r0 + 15, :] += 0.04  # a 4 cm bump
    sure = np.full(e.shape, 0.005, np.float32)
    unsure = sure.copy()
    unsure[r0 - 40: r0 + 40, :] = 0.03  # far-field cells: 3 cm sigma there
    assert [h.kind for h in detect_hazards(e, sure, RES, (0.0, 0.0))] == ["bump"]
    assert detect_hazards(e, unsure, RES, (0.0, 0.0)) == []
    assert detect_hazards(e, unsure, RES, (0.0, 0.0), HazardSettings(min_significance=1.0))[0].confidence == 0.0
    # a calibrated sigma grows with the estimate's relief, so it is large on the bump itself: the
    # road around it says whether the bump is there
    on_bump = sure.copy()
    on_bump[r0 - 15: r0 + 15, :] = 0.03
    (bump,) = detect_hazards(e, on_bump, RES, (0.0, 0.0))
    assert bump.height_sigma_m == pytest.approx(0.005, abs=0.001) and bump.confidence > 0.8
    with pytest.raises(HazardError):
        HazardSettings(min_significance=-1.0)


def test_smooth_rough_plane_has_no_hazard_and_unknown_cells_stay_unknown() -> None:
    rng = np.random.default_rng(0)
    e = _plane() + rng.normal(0.0, 0.003, (1500, 150)).astype(np.float32)
    e[:200] = np.nan  # unseen
    assert detect_hazards(e, None, RES, (0.0, 0.0)) == []
    cost = severity_cost(road_residual(e, RES)[0])
    assert np.all(cost[:200] == -1) and cost[200:].max() < 20


def test_true_road_map_of_a_drive() -> None:
    road = RoadConfig(road_class="B", features=("speed_bump", "pothole", "hump"), feature_spacing_m=8.0)
    drive = RidingDrive(RidingConfig(drive=DriveConfig(frames=40, speed_mps=10.0, frame_rate_hz=10.0, seed=3,
                                                       road=road)))
    rm = drive.road_map()
    n_rows = rm.elevation.shape[0]
    xs = rm.centre[0] + 0.5 * n_rows * rm.resolution - (np.arange(n_rows) + 0.5) * rm.resolution
    path = drive.ground_truth_poses().position
    y_lo, y_hi = path[:, 1].min() - 1.0, path[:, 1].max() + 1.0  # the corridor a fused map covers
    lane, centre = band(rm.elevation, rm.resolution, rm.centre, y_lo, y_hi)
    found = detect_hazards(lane, None, rm.resolution, centre)
    x_lo, x_hi = xs[-1] + 1.0, path[-1, 0] + 1.0
    truth = [f for f in drive.features_in_odom() if x_lo < f[1] < x_hi and y_lo < f[2] < y_hi]
    assert len(truth) >= 5
    for name, fx, fy, height in truth:
        match = [h for h in found if abs(h.x - fx) < 0.5 and (name != "pothole" or abs(h.y - fy) < 0.5)]
        assert match, f"{name} at ({fx:.1f}, {fy:.1f}) missed"
        assert match[0].kind == ("pothole" if height < 0 else "bump")
        assert abs(match[0].height_m - height) <= 0.15 * abs(height)
    # everything found is one of the features (none on the road between them)
    assert all(any(abs(h.x - f[1]) < 0.5 for f in drive.features_in_odom()) for h in found)


def test_bad_input() -> None:
    with pytest.raises(HazardError):
        detect_hazards(np.full((10, 10), math.nan), None, RES, (0.0, 0.0))
    with pytest.raises(HazardError):
        detect_hazards(np.zeros(10), None, RES, (0.0, 0.0))
    with pytest.raises(HazardError):
        detect_hazards(np.zeros((10, 10)), np.zeros((5, 5)), RES, (0.0, 0.0))
    with pytest.raises(HazardError):
        HazardSettings(min_height_m=0.0)
    with pytest.raises(HazardError):
        severity_cost(np.zeros((2, 2)), 0.0)
