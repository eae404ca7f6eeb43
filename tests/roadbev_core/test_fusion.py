"""The fused road map: frames placed in odom, aligned, gated and fused; what leaves and what stays NaN."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from roadbev_core.config import GridSpec, RoadbevConfig, VehicleConfig
from roadbev_core.ego_motion import PlanarPose
from roadbev_core.fusion import FusedMap, FusionError, MapSettings, place_frame, sample_bilinear
from roadbev_core.geometry import R_BODY_FROM_OPTICAL, Attitude
from roadbev_core.map_preview import map_preview

GRID = GridSpec()
CAMERA = np.array(VehicleConfig().camera_position_m)  # [3] in base_link
LEVEL_MOUNT = R_BODY_FROM_OPTICAL  # optical -> base_link of a camera looking along x, level
Road = Callable[[np.ndarray, np.ndarray], np.ndarray]


def _settings(**changes: object) -> MapSettings:
    return RoadbevConfig.from_params({f"map.{k}": v for k, v in changes.items()}).map_settings()


def _frame(road: Road, base: PlanarPose, base_z: float, pitch: float = 0.0) -> np.ndarray:
    """[R, C] the true road in the road frame of a camera on a body at (base, base_z, pitch)."""
    att = Attitude(0.0, pitch)
    placement = place_frame(base, att, CAMERA, LEVEL_MOUNT)
    u, v = GRID.x_centres()[:, None], GRID.y_centres()[None, :]
    c, s = math.cos(placement.heading), math.sin(placement.heading)
    x = placement.origin[0] + c * u - s * v
    y = placement.origin[1] + s * u + c * v
    camera_z = base_z + placement.camera_height_over_base
    return (road(x, y) - (camera_z - GRID.base_height)).astype(np.float64)


def _drive(fused: FusedMap, road: Road, frames: int, step_m: float, *, noise: float = 0.0, heave: float = 0.0,
           pitch: float = 0.0, hide: Callable[[int, np.ndarray], np.ndarray] | None = None,
           seed: int = 0) -> list[np.ndarray]:
    """Drive straight along x, fusing one estimate per frame; returns each frame's error [R, C]."""
    rng = np.random.default_rng(seed)
    errors = []
    for k in range(frames):
        base = PlanarPose(1 + k, k * step_m, 0.0, 0.0, 10.0, 0.0)
        z_body = heave * math.sin(1.3 * k) if k else 0.0
        p = pitch * math.cos(0.9 * k) if k else 0.0
        truth = _frame(road, base, z_body, p)
        estimate = truth + rng.normal(0.0, noise, truth.shape) if noise else truth.copy()
        if hide is not None:
            estimate[hide(k, estimate)] = np.nan
        sigma = np.full(truth.shape, max(noise, 0.002))
        placement = place_frame(base, Attitude(0.0, p), CAMERA, LEVEL_MOUNT)
        fused.integrate(estimate, sigma, GRID, placement, 1 + k, base_z_prediction=fused.predicted_base_z(base, None))
        errors.append(estimate - truth)
    return errors


def _bumpy(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return 0.03 * np.exp(-((x - 12.0) / 0.4) ** 2) + 0.01 * np.sin(0.7 * x) + 0.004 * np.cos(2.1 * y)


def _map_error(fused: FusedMap, road: Road, base: PlanarPose) -> np.ndarray:
    window = fused.window(base, 0)
    x, y = window.cell_centres()
    gx, gy = np.meshgrid(x, y, indexing="ij")
    held = np.isfinite(window.elevation)
    return np.asarray(window.elevation[held] - road(gx, gy)[held])


def test_the_map_of_noisy_frames_beats_each_frame() -> None:
    fused = FusedMap(_settings(error_correlation=0.0, range_exponent=0.0))
    errors = _drive(fused, _bumpy, 12, 0.5, noise=0.006, heave=0.02)
    per_frame = min(float(np.nanmean(np.abs(e))) for e in errors)
    err = _map_error(fused, _bumpy, PlanarPose(0, 11 * 0.5, 0.0, 0.0))
    assert err.size > 0.5 * GRID.n_rows * GRID.n_cols
    # body heave of 2 cm never reaches the map: each frame is aligned with it
    assert float(np.mean(np.abs(err))) < 0.6 * per_frame


def test_an_occluded_strip_is_filled_by_a_later_frame_and_never_guessed() -> None:
    fused = FusedMap(_settings())

    def hidden_behind_crest(k: int, estimate: np.ndarray) -> np.ndarray:
        mask = np.zeros(estimate.shape, bool)
        u = GRID.x_centres()[:, None] + k * 0.5 + CAMERA[0]  # odom x of the rows
        if k < 3:
            mask |= np.broadcast_to((u > 8.0) & (u < 8.6), estimate.shape)  # seen only from frame 3 on
        mask |= np.broadcast_to((u > 9.5) & (u < 9.8), estimate.shape)  # never seen
        return mask

    _drive(fused, _bumpy, 3, 0.5, hide=hidden_behind_crest)
    before, _ = fused.heights(np.array([8.3]), np.array([0.0]))
    assert np.isnan(before[0])
    fused.reset()  # the same road again from the start, now far enough to see the strip
    _drive(fused, _bumpy, 5, 0.5, hide=hidden_behind_crest)
    filled, _ = fused.heights(np.array([8.3]), np.array([0.0]))
    never, _ = fused.heights(np.array([9.65]), np.array([0.0]))
    assert abs(filled[0] - _bumpy(np.array([8.3]), np.array([0.0]))[0]) < 1e-3
    assert np.isnan(never[0])  # a strip no frame saw stays NaN, never a neighbour's height


def test_a_heave_and_pitch_only_drive_over_a_flat_road_previews_flat() -> None:
    def flat(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.zeros(np.broadcast(x, y).shape)

    fused = FusedMap(_settings())
    _drive(fused, flat, 10, 0.6, heave=0.03, pitch=math.radians(1.5))
    base = PlanarPose(10, 9 * 0.6, 0.0, 0.0, 10.0, 0.0)
    placement = place_frame(base, Attitude(0.0, math.radians(1.5) * math.cos(8.1)), CAMERA, LEVEL_MOUNT)
    preview = map_preview(fused, placement, VehicleConfig(), tyre_width_m=0.2, spacing_m=0.03)
    assert preview.contact_plane is not None and preview.contact_plane.source == "map"
    for track in preview.tracks:
        values = track.elevation[np.isfinite(track.elevation)]
        assert values.size > 100
        assert float(np.max(np.abs(values))) < 1e-3  # body heave and pitch never appear as road
    assert abs(preview.contact_plane.pitch) < math.radians(0.05)


def test_cells_behind_the_car_leave_the_map() -> None:
    settings = _settings(behind_m=1.0)
    fused = FusedMap(settings)
    _drive(fused, _bumpy, 20, 1.0)
    z, _ = fused.heights(np.array([5.0, 19.0 + 3.0]), np.array([0.0, 0.0]))  # 14 m behind / under the car
    assert np.isnan(z[0]) and np.isfinite(z[1])
    window = fused.window(PlanarPose(0, 19.0, 0.0, 0.0), 0)
    x, _ = window.cell_centres()
    assert x.min() > 19.0 - settings.behind_m - 0.05 and x.max() < 19.0 + settings.ahead_m + 0.05


def test_an_inconsistent_observation_is_rejected_then_restarts_the_cell_when_it_persists() -> None:
    fused = FusedMap(_settings(reset_after=2))
    _drive(fused, _bumpy, 3, 0.0)  # the car stands: the same cells, three times
    good, _ = fused.heights(np.array([6.0]), np.array([0.0]))
    base = PlanarPose(9, 0.0, 0.0, 0.0)
    placement = place_frame(base, Attitude(0.0, 0.0), CAMERA, LEVEL_MOUNT)
    truth = _frame(_bumpy, base, 0.0)
    moved = truth.copy()
    rows = (GRID.x_centres() + CAMERA[0] > 5.8) & (GRID.x_centres() + CAMERA[0] < 6.2)
    moved[rows] += 0.10  # something 10 cm high appeared there
    sigma = np.full(truth.shape, 0.002)
    first = fused.integrate(moved, sigma, GRID, placement, 10, base_z_prediction=0.0)
    after_one, _ = fused.heights(np.array([6.0]), np.array([0.0]))
    assert first.rejected > 0 and abs(after_one[0] - good[0]) < 1e-3
    fused.integrate(moved, sigma, GRID, placement, 11, base_z_prediction=0.0)
    after_two, _ = fused.heights(np.array([6.0]), np.array([0.0]))
    assert abs(after_two[0] - good[0] - 0.10) < 5e-3  # the road really changed: the cell restarted


def test_window_layers_and_grid_map_order() -> None:
    fused = FusedMap(_settings())
    _drive(fused, _bumpy, 2, 0.5)
    window = fused.window(PlanarPose(0, 0.5, 0.0, 0.0), 5)
    assert set(window.layers()) == {"elevation", "uncertainty", "observations", "age"}
    x, y = window.cell_centres()
    assert x[0] > x[-1] and y[0] > y[-1]  # row 0 at +x, column 0 at +y
    held = np.isfinite(window.elevation)
    assert np.all(window.observations[held] >= 1) and np.all(window.observations[~held] == 0)
    assert np.all(window.uncertainty[held] > 0) and np.all(np.isnan(window.age[~held]))
    assert np.nanmax(window.age) == pytest.approx(4e-9)  # stamps 1 and 2 ns, window at 5 ns


def test_sample_bilinear_keeps_holes() -> None:
    values = np.array([[0.0, 1.0], [2.0, np.nan]])
    z, _ = sample_bilinear(values, None, np.array([0.0, 0.5, 1.0]), np.array([0.5, 0.5, 1.0]))
    assert z[0] == pytest.approx(0.5) and z[1] == pytest.approx(1.0) and np.isnan(z[2])


def test_settings_refuse_an_empty_or_costly_corridor() -> None:
    with pytest.raises(FusionError):
        MapSettings(resolution=0.03, behind_m=1.0, ahead_m=-2.0, y_min=-1.0, y_max=1.0, base_height=1.1)
    with pytest.raises(FusionError):
        MapSettings(resolution=0.001, behind_m=10.0, ahead_m=100.0, y_min=-10.0, y_max=10.0, base_height=1.1)
