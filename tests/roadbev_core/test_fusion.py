"""The fused road map: frames placed in odom, aligned, gated and fused; what leaves and what stays NaN."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from roadbev_core.config import GridSpec, RoadbevConfig, VehicleConfig
from roadbev_core.ego_motion import PlanarPose
from roadbev_core.fusion import (
    FusedMap,
    FusionError,
    MapSettings,
    datum_calibration_for,
    map_settings,
    place_frame,
    prepare_bilinear,
    sample_bilinear,
    sample_prepared,
)
from roadbev_core.geometry import R_BODY_FROM_OPTICAL, Attitude
from roadbev_core.map_preview import footprint_heights, map_preview

GRID = GridSpec()
CAMERA = np.array(VehicleConfig().camera_position_m)  # [3] in base_link
LEVEL_MOUNT = R_BODY_FROM_OPTICAL  # optical -> base_link of a camera looking along x, level
Road = Callable[[np.ndarray, np.ndarray], np.ndarray]


def _settings(**changes: object) -> MapSettings:
    params = {f"map.{k}": v for k, v in changes.items()}
    return map_settings(RoadbevConfig.from_params({"far_field.enabled": False, **params}))  # the grid alone


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
        fused.integrate(estimate, sigma, GRID, placement, 1 + k, base_z_prediction=fused.predicted_base_z(None))
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


def test_a_contact_the_map_never_saw_is_stood_in_from_the_body_and_widens_the_plane() -> None:
    def flat(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.zeros(np.broadcast(x, y).shape)

    step, frames = 0.6, 10
    base = PlanarPose(frames, (frames - 1) * step, 0.0, 0.0, 10.0, 0.0)
    front_left = VehicleConfig().wheel_positions()[0] + np.array([base.x, 0.0])  # [2] odom

    def never_under_front_left(k: int, estimate: np.ndarray) -> np.ndarray:
        x = GRID.x_centres()[:, None] + k * step + CAMERA[0]  # odom x of the rows
        y = GRID.y_centres()[None, :]
        return np.broadcast_to((np.abs(x - front_left[0]) < 0.3) & (np.abs(y - front_left[1]) < 0.3), estimate.shape)

    planes = []
    for hide in (None, never_under_front_left):
        fused = FusedMap(_settings())
        _drive(fused, flat, frames, step, heave=0.02, hide=hide)
        placement = place_frame(base, Attitude(0.0, 0.0), CAMERA, LEVEL_MOUNT)
        preview = map_preview(fused, placement, VehicleConfig(), tyre_width_m=0.2, spacing_m=0.03)
        plane = preview.contact_plane
        assert plane is not None and plane.source == "map"
        assert abs(plane.pitch) < math.radians(0.05) and abs(plane.roll) < math.radians(0.05)
        values = preview.tracks[1].elevation[np.isfinite(preview.tracks[1].elevation)]
        assert values.size > 100 and float(np.max(np.abs(values))) < 1e-3
        planes.append(plane)
    seen, stood_in = planes
    assert stood_in.pitch_sigma > 3 * seen.pitch_sigma and stood_in.roll_sigma > 3 * seen.roll_sigma


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
    assert set(window.layers()) == {"elevation", "uncertainty", "observations", "age", "datum_uncertainty"}
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


def test_bilinear_samples_at_and_beyond_the_edges() -> None:
    rng = np.random.default_rng(3)
    values, sigma = rng.normal(size=(5, 4)), rng.uniform(0.1, 1.0, (5, 4))
    rows = np.array([0.0, 4.0, -0.4, 4.4, -0.6, 2.5, 1.25, -3.0, 9.0])
    cols = np.array([0.0, 3.0, 1.0, 2.0, 1.0, -0.45, 2.75, 1.0, 1.0])
    z, s = sample_bilinear(values, sigma, rows, cols)
    assert z[0] == values[0, 0] and z[1] == values[4, 3] and s[0] == sigma[0, 0]
    # half a cell outside, the edge cell alone decides (its weight 0.6 >= 0.5); beyond that, nothing
    assert z[2] == pytest.approx(values[0, 1]) and z[3] == pytest.approx(values[4, 2])
    assert np.isnan(z[4]) and np.isnan(z[7]) and np.isnan(z[8]) and np.isnan(s[4])
    assert z[5] == pytest.approx(0.5 * (values[2, 0] + values[3, 0]))
    expected = (0.75 * (0.25 * values[1, 2] + 0.75 * values[1, 3]) + 0.25 * (0.25 * values[2, 2] + 0.75 * values[2, 3]))
    assert z[6] == pytest.approx(expected)
    # the prepared table of the map (every sample inside: the path without masks) agrees
    inside_rows, inside_cols = rows[[0, 5, 6]].clip(0, 3.9), cols[[0, 5, 6]].clip(0, 2.9)
    z2, s2 = sample_prepared(prepare_bilinear(values, sigma), inside_rows, inside_cols)
    z3, s3 = sample_bilinear(values, sigma, inside_rows, inside_cols)
    np.testing.assert_allclose(z2, z3)
    np.testing.assert_allclose(s2, s3)


def test_the_published_sigma_carries_the_datum_against_the_road_under_the_car() -> None:
    plain = FusedMap(_settings(datum_sigma_m=0.0, datum_drift=0.0))
    drifting = FusedMap(_settings(datum_sigma_m=0.01, datum_drift=0.004))
    for fused in (plain, drifting):
        _drive(fused, _bumpy, 12, 0.5, noise=0.004, heave=0.01)
    base = PlanarPose(0, 11 * 0.5, 0.0, 0.0)
    w0, w1 = plain.window(base, 0), drifting.window(base, 0)
    np.testing.assert_array_equal(w0.elevation, w1.elevation)  # the datum term only widens the sigma
    held = np.isfinite(w0.elevation)
    datum = np.sqrt(w1.uncertainty[held].astype(np.float64) ** 2 - w0.uncertainty[held].astype(np.float64) ** 2)
    assert datum.min() >= 0.01 - 1e-5 and datum.max() <= 0.01 + 0.004 * 5.5 + 1e-5
    # the far cells, seen only by the last frames (where the car is now), carry the least; the
    # cells under the car, fused from frames metres of driving ago, the most
    x, _ = w1.cell_centres()
    far = np.broadcast_to((x > x.max() - 0.5)[:, None], held.shape)[held]
    under = np.broadcast_to(((x > 5.5) & (x < 5.5 + 2.8))[:, None], held.shape)[held]
    assert datum[far].mean() < 0.01 + 0.004 * 0.5
    assert datum[under].mean() > datum[far].mean() + 0.004 * 1.5
    # the datum layer says how much of the sigma nearby cells share; without it, the cell's own
    assert w0.datum_uncertainty is not None and w1.datum_uncertainty is not None
    np.testing.assert_allclose(w1.datum_uncertainty[held], datum, atol=2e-4)
    np.testing.assert_allclose(w1.local_uncertainty()[held], w0.uncertainty[held], atol=2e-4)
    assert np.all(w0.datum_uncertainty[held] == 0.0)
    # the gate, the alignment and the preview use the cells' own sigma: unchanged
    px, py = np.array([6.0, 8.0]), np.array([0.1, -0.2])
    np.testing.assert_array_equal(plain.heights(px, py)[1], drifting.heights(px, py)[1])


def test_the_published_sigma_stays_bounded_over_a_long_drive() -> None:
    # 60 s at 10 m/s with a 10 Hz camera: the absolute datum's sigma grows with the 600 m driven,
    # the published sigma (against the road under the car) does not
    fused = FusedMap(_settings(datum_sigma_m=0.002, datum_drift=0.0004))
    rng = np.random.default_rng(0)
    medians = []
    for k in range(600):
        base = PlanarPose(1 + k, float(k), 0.0, 0.0, 10.0, 0.0)
        truth = _frame(_bumpy, base, 0.0)
        estimate = truth + rng.normal(0.0, 0.003, truth.shape)
        placement = place_frame(base, Attitude(0.0, 0.0), CAMERA, LEVEL_MOUNT)
        last = fused.integrate(estimate, np.full(estimate.shape, 0.003), GRID, placement, 1 + k,
                               base_z_prediction=fused.predicted_base_z(None))
        if k % 100 == 99:
            medians.append(float(np.nanmedian(fused.window(base, 1 + k).uncertainty)))
    assert last.driven_m == pytest.approx(599.0) and last.datum_sigma_m > 0.2  # odom z: unknowable
    assert max(medians) < 0.002 + 0.0004 * 10.0 + 0.003  # bounded by the corridor's length
    assert medians[-1] < 1.2 * medians[0]


def test_the_datum_is_fixed_again_when_the_map_starts_over() -> None:
    fused = FusedMap(_settings(datum_sigma_m=0.01, datum_drift=0.004))
    _drive(fused, _bumpy, 4, 0.5)
    fused.reset()
    base = PlanarPose(9, 30.0, 0.0, 0.0, 10.0, 0.0)
    est = _frame(_bumpy, base, 0.0)
    first = fused.integrate(est, np.full(est.shape, 0.003), GRID, place_frame(base, Attitude(0.0, 0.0), CAMERA,
                            LEVEL_MOUNT), 9, base_z_prediction=0.0)
    assert first.driven_m == 0.0 and first.datum_sigma_m == pytest.approx(0.01)


def test_the_datum_calibration_is_read_per_backend_and_params_override_it(tmp_path: Path) -> None:
    path = tmp_path / "datum.json"
    path.write_text(json.dumps({"backends": {"a": {"datum_sigma_m": 0.002, "datum_drift": 0.0003},
                                             "bad": {"datum_sigma_m": -1.0, "datum_drift": 0.0}}}))
    assert datum_calibration_for("a", path) == (0.002, 0.0003)
    assert datum_calibration_for("bad", path) is None and datum_calibration_for("none", path) is None
    garbage = tmp_path / "garbage.json"  # tables are read once per path
    garbage.write_text("{not json")
    assert datum_calibration_for("a", garbage) is None
    assert datum_calibration_for("a", tmp_path / "missing.json") is None
    # -1 (the default) takes the shipped calibration of the chosen backend; a value given wins
    for backend in ("bev_sweep", "bm"):
        calibrated = datum_calibration_for(backend) or (0.0, 0.0)
        settings = map_settings(RoadbevConfig.from_params({"backend": backend}))
        assert (settings.datum_sigma_m, settings.datum_drift) == calibrated
    settings = map_settings(RoadbevConfig.from_params({"map.datum_drift": 0.001, "map.datum_sigma_m": 0.0}))
    assert (settings.datum_sigma_m, settings.datum_drift) == (0.0, 0.001)
    with pytest.raises(FusionError):
        MapSettings(resolution=0.03, behind_m=1.0, ahead_m=8.0, y_min=-1.0, y_max=1.0, base_height=1.1,
                    datum_drift=-0.1)


def test_settings_refuse_an_empty_or_costly_corridor() -> None:
    with pytest.raises(FusionError):
        MapSettings(resolution=0.03, behind_m=1.0, ahead_m=-2.0, y_min=-1.0, y_max=1.0, base_height=1.1)
    with pytest.raises(FusionError):
        MapSettings(resolution=0.001, behind_m=10.0, ahead_m=100.0, y_min=-10.0, y_max=10.0, base_height=1.1)


def test_map_settings_lay_the_corridor_around_the_camera_on_base_link() -> None:
    config = RoadbevConfig.from_params({"map.behind_m": 2.0, "map.slope_prior_deg": 0.5, "far_field.enabled": False})
    g = config.grid
    settings = map_settings(config)  # the camera at vehicle.camera_position_m
    assert settings.ahead_m == pytest.approx(config.vehicle.camera_position_m[0] + g.x_max)
    assert (settings.behind_m, settings.resolution, settings.base_height) == (2.0, g.resolution, g.base_height)
    assert settings.slope_prior_rad == pytest.approx(math.radians(0.5))
    moved = map_settings(config, np.array([2.0, 0.5, 1.2]))  # from /tf_static
    assert moved.ahead_m == pytest.approx(2.0 + g.x_max)
    assert (moved.y_min, moved.y_max) == pytest.approx((0.5 + g.y_min, 0.5 + g.y_max))


def test_a_window_crops_to_the_cells_around_a_position() -> None:
    from roadbev_core.fusion import MapWindow

    n_rows, n_cols, r = 10, 6, 0.5  # cell centres x 12.25 down to 7.75, y 2.25 down to -0.25
    elevation = np.arange(n_rows * n_cols, dtype=np.float32).reshape(n_rows, n_cols)
    window = MapWindow(elevation, elevation + 100, np.ones_like(elevation), np.zeros_like(elevation), r,
                       (10.0, 1.0), 7, elevation + 200)
    x, y = window.cell_centres()
    sub = window.crop((11.0, 1.0), (2.0, 1.0))
    assert sub is not None and sub.elevation.shape == (4, 2) and sub.stamp_ns == 7
    sx, sy = sub.cell_centres()
    assert np.all(np.abs(sx - 11.0) <= 1.0) and np.all(np.abs(sy - 1.0) <= 0.5)
    rows = [int(np.flatnonzero(np.isclose(x, v))[0]) for v in sx]
    cols = [int(np.flatnonzero(np.isclose(y, v))[0]) for v in sy]
    np.testing.assert_array_equal(sub.elevation, elevation[np.ix_(rows, cols)])  # the same cells, same order
    assert sub.datum_uncertainty is not None and sub.datum_uncertainty[0, 0] == sub.elevation[0, 0] + 200
    whole = window.crop((0.0, 0.0), (0.0, 0.0))  # no length: the whole map
    assert whole is not None and whole.elevation.shape == (n_rows, n_cols)
    assert whole.centre == pytest.approx((10.0, 1.0))
    assert window.crop((50.0, 1.0), (1.0, 1.0)) is None  # outside the map


# --- the far field in the map -------------------------------------------------------------------
FAR_CONFIG = RoadbevConfig.from_params({"far_field.enabled": True})
FAR_GRID = FAR_CONFIG.far_field.grid(GRID)


def test_with_the_far_field_on_the_corridor_reaches_its_far_edge_and_nothing_else_changes() -> None:
    off, on = map_settings(RoadbevConfig.from_params({"far_field.enabled": False})), map_settings(FAR_CONFIG)
    assert off.ahead_m == pytest.approx(CAMERA[0] + GRID.x_max)
    assert on.ahead_m == pytest.approx(CAMERA[0] + FAR_GRID.x_max) and FAR_GRID.x_max == 15.0
    assert replace(on, ahead_m=off.ahead_m) == off  # one resolution, the grid's; the same width
    assert on.resolution == GRID.resolution


def _far_frame(fused: FusedMap, far: np.ndarray, far_sigma: float, stamp: int, *, near_sigma: float = 0.004
               ) -> None:
    """Fuse a level frame at the origin: a flat near estimate (0) and the far estimate ``far`` [R, C]."""
    base = PlanarPose(stamp, 0.0, 0.0, 0.0, 0.0, 0.0)
    placement = place_frame(base, Attitude(0.0, 0.0), CAMERA, LEVEL_MOUNT)
    fused.integrate(np.zeros(GRID.shape), np.full(GRID.shape, near_sigma), GRID, placement, stamp,
                    base_z_prediction=0.0)
    fused.integrate_far(far, np.full(FAR_GRID.shape, far_sigma), FAR_GRID, placement, stamp)


def _far_cell_centres() -> tuple[np.ndarray, np.ndarray]:
    """[R, C] odom x, y of the far-field cells' centres for the level frame at the origin."""
    u, v = np.meshgrid(FAR_GRID.x_centres(), FAR_GRID.y_centres(), indexing="ij")
    return CAMERA[0] + u, CAMERA[1] + v


def test_each_map_cell_takes_the_value_and_sigma_of_the_far_field_cell_it_lies_in() -> None:
    fused = FusedMap(map_settings(FAR_CONFIG))
    far = np.random.default_rng(3).uniform(-0.05, 0.05, FAR_GRID.shape)  # a different height per coarse cell
    _far_frame(fused, far, 0.01, 1)
    datum = CAMERA[2] - GRID.base_height  # the road plane's z of a level frame at base_z 0
    x, y = _far_cell_centres()
    quarter = 0.25 * FAR_GRID.resolution  # inside the coarse cell, more than a map cell from its edges
    for dx, dy in ((0.0, 0.0), (quarter, -quarter), (-quarter, quarter)):
        z, s = fused.heights(x + dx, y + dy)
        np.testing.assert_allclose(z, far + datum, atol=1e-9)  # the coarse cell's value, not a blend
        np.testing.assert_allclose(s, 0.01, rtol=1e-6)  # and its sigma, as it is
    window = fused.window(PlanarPose(1, 0.0, 0.0, 0.0, 0.0, 0.0), 1)
    wx, wy = window.cell_centres()
    ahead, left = wx - CAMERA[0], wy - CAMERA[1]
    assert ahead.max() > FAR_GRID.x_max - GRID.resolution  # the window reaches the far edge
    rows = (ahead > FAR_GRID.x_min) & (ahead < FAR_GRID.x_max)
    cols = (left > FAR_GRID.y_min) & (left < FAR_GRID.y_max)
    assert np.isfinite(window.elevation[np.ix_(rows, cols)]).all()  # every map cell of the far field


def test_fusing_a_far_frame_twice_counts_its_coarse_cell_as_one_measurement_not_many() -> None:
    sigma = 0.01
    x, y = _far_cell_centres()
    for rho in (1.0, 0.0):
        fused = FusedMap(_far_settings(error_correlation=rho))
        for stamp in (1, 2):  # the same far frame twice
            _far_frame(fused, np.zeros(FAR_GRID.shape), sigma, stamp, near_sigma=sigma)
        _, far_sigma = fused.heights(x, y)
        # what a near cell measured by these two frames with the same sigma gets: one measurement's
        # sigma with the default (frames correlated), sigma / sqrt(2) with independent frames; a
        # coarse cell counted once per map cell it covers would give sigma / sqrt(2 * 16)
        floor = sigma if rho == 1.0 else sigma / math.sqrt(2.0)
        _, near_sigma = fused.heights(np.array([CAMERA[0] + 4.0]), np.array([CAMERA[1]]))
        assert near_sigma[0] >= floor - 1e-9
        assert np.all(far_sigma >= floor - 1e-9)
        assert np.all(far_sigma < 1.5 * sigma)  # not inflated by sqrt(16) either
        # a tyre footprint over the 16 map cells of one coarse cell is as uncertain as that one cell
        _, footprint = footprint_heights(fused, x[10:11, 5], y[10:11, 5], 0.0, 0.9 * FAR_GRID.resolution,
                                         0.9 * FAR_GRID.resolution)
        assert footprint[0] == pytest.approx(far_sigma[10, 5], rel=1e-6)


def _far_settings(**changes: object) -> MapSettings:
    return map_settings(FAR_CONFIG.with_params({f"map.{k}": v for k, v in changes.items()}))


def test_the_far_field_is_fused_only_after_its_frame() -> None:
    fused = FusedMap(map_settings(FAR_CONFIG))
    placement = place_frame(PlanarPose(1, 0.0, 0.0, 0.0, 0.0, 0.0), Attitude(0.0, 0.0), CAMERA, LEVEL_MOUNT)
    with pytest.raises(FusionError, match="the frame integrate just fused"):
        fused.integrate_far(np.zeros(FAR_GRID.shape), np.full(FAR_GRID.shape, 0.01), FAR_GRID, placement, 1)
    fused.integrate(np.zeros(GRID.shape), np.full(GRID.shape, 0.01), GRID, placement, 1, base_z_prediction=0.0)
    with pytest.raises(FusionError, match="not on the far-field grid"):
        fused.integrate_far(np.zeros(GRID.shape), np.full(GRID.shape, 0.01), FAR_GRID, placement, 1)


def test_a_frame_is_aligned_on_cells_the_grid_saw_never_on_cells_only_the_far_field_saw() -> None:
    fused = FusedMap(map_settings(FAR_CONFIG))
    _far_frame(fused, np.full(FAR_GRID.shape, 0.05), 0.004, 1)  # a far field 5 cm off the grid's road
    # 7 m on, the grid lies where only that far field was fused: nothing to align on, the prediction holds
    base = PlanarPose(2, 7.0, 0.0, 0.0, 0.0, 0.0)
    placement = place_frame(base, Attitude(0.0, 0.0), CAMERA, LEVEL_MOUNT)
    fusion = fused.integrate(np.zeros(GRID.shape), np.full(GRID.shape, 0.004), GRID, placement, 2,
                             base_z_prediction=0.0)
    assert not fusion.aligned and fusion.overlap_cells == 0 and fusion.offset_m == 0.0


def test_the_grids_observation_supersedes_the_far_fields() -> None:
    fused = FusedMap(map_settings(FAR_CONFIG))
    _far_frame(fused, np.full(FAR_GRID.shape, 0.05), 0.02, 1)  # a far field 5 cm off the road
    x, y = _far_cell_centres()
    datum = CAMERA[2] - GRID.base_height
    # 7 m on, the grid sees a flat road where only that far field was fused: the cells take the
    # grid's observation alone (no blend, no rejection); the next far field leaves them alone
    base = PlanarPose(2, 7.0, 0.0, 0.0, 0.0, 0.0)
    placement = place_frame(base, Attitude(0.0, 0.0), CAMERA, LEVEL_MOUNT)
    fusion = fused.integrate(np.zeros(GRID.shape), np.full(GRID.shape, 0.004), GRID, placement, 2,
                             base_z_prediction=0.0)
    assert fusion.rejected == 0 and fusion.restarted == 0
    fused.integrate_far(np.full(FAR_GRID.shape, -0.05), np.full(FAR_GRID.shape, 0.02), FAR_GRID, placement, 2)
    ahead = x - CAMERA[0] - 7.0
    seen = (ahead > GRID.x_min + 0.1) & (ahead < GRID.x_max - 0.1)
    z, _ = fused.heights(x[seen], y[seen])
    np.testing.assert_allclose(z, datum, atol=1e-9)
    beyond = ahead > GRID.x_max + 0.2  # only the far field has seen these: both far frames fused
    z, _ = fused.heights(x[beyond], y[beyond])
    assert np.all(np.abs(z - datum) < 0.05)


def test_with_the_far_field_the_cells_the_grid_saw_hold_what_they_hold_without_it() -> None:
    rng = np.random.default_rng(11)
    plain, with_far = FusedMap(map_settings(RoadbevConfig())), FusedMap(map_settings(FAR_CONFIG))
    x, y, yaw = 0.0, 0.0, 0.0
    for k in range(40):  # 40 frames 1.5 m apart on a bend, noisy grid and far-field estimates
        base = PlanarPose(k + 1, x, y, yaw, 0.0, 0.0)
        x, y, yaw = x + 1.5 * math.cos(yaw), y + 1.5 * math.sin(yaw), yaw + 0.02
        placement = place_frame(base, Attitude(0.0, 0.0), CAMERA, LEVEL_MOUNT)
        near = rng.normal(0.0, 0.004, GRID.shape)
        for fused in (plain, with_far):
            fused.integrate(near, np.full(GRID.shape, 0.004), GRID, placement, k + 1, base_z_prediction=0.0)
        with_far.integrate_far(rng.normal(0.02, 0.02, FAR_GRID.shape), np.full(FAR_GRID.shape, 0.02), FAR_GRID,
                               placement, k + 1)
    r = GRID.resolution  # read at the map cells' centres: between them, a read blends neighbours
    xs, ys = np.meshgrid((np.arange(1000, 3000) + 0.5) * r, (np.arange(-150, 1000) + 0.5) * r, indexing="ij")
    z0, s0 = plain.heights(xs.ravel(), ys.ravel())
    z1, s1 = with_far.heights(xs.ravel(), ys.ravel())
    seen = np.isfinite(z0)
    assert seen.sum() > 1000 and np.isfinite(z1).sum() > seen.sum()  # the far field reaches farther
    np.testing.assert_allclose(z1[seen], z0[seen], atol=1e-9)
    np.testing.assert_allclose(s1[seen], s0[seen], atol=1e-9)


def test_a_cell_the_grid_looks_at_and_declines_holds_no_far_field_value() -> None:
    fused = FusedMap(map_settings(FAR_CONFIG))
    _far_frame(fused, np.full(FAR_GRID.shape, 0.05), 0.02, 1)
    x, y = _far_cell_centres()
    ahead = x - CAMERA[0] - 7.0
    looked = (ahead > GRID.x_min + 0.1) & (ahead < GRID.x_max - 0.1)
    assert np.isfinite(fused.heights(x[looked], y[looked])[0]).all()
    # 7 m on, the grid looks at those cells and declines all of them (hidden, unmatched)
    placement = place_frame(PlanarPose(2, 7.0, 0.0, 0.0, 0.0, 0.0), Attitude(0.0, 0.0), CAMERA, LEVEL_MOUNT)
    fused.integrate(np.full(GRID.shape, np.nan), np.full(GRID.shape, np.nan), GRID, placement, 2,
                    base_z_prediction=0.0)
    assert np.isnan(fused.heights(x[looked], y[looked])[0]).all()
    beyond = ahead > GRID.x_max + 0.2  # never looked at by the grid: the far field's value stays
    assert np.isfinite(fused.heights(x[beyond], y[beyond])[0]).all()


class _LeadlessMap(FusedMap):
    LEAD_M = 0.0


def test_the_buffer_moves_about_every_lead_driven_and_holds_what_a_leadless_one_holds() -> None:
    rng = np.random.default_rng(5)
    lead, leadless = FusedMap(_settings()), _LeadlessMap(_settings())
    moves = {id(lead): 0, id(leadless): 0}
    x, y, yaw = 0.0, 0.0, 0.3
    for k in range(60):  # 60 frames 0.5 m apart on a bend, heading north-east and turning
        base = PlanarPose(k + 1, x, y, yaw, 10.0, 0.0)
        x, y, yaw = x + 0.5 * math.cos(yaw), y + 0.5 * math.sin(yaw), yaw + 0.01
        placement = place_frame(base, Attitude(0.0, 0.0), CAMERA, LEVEL_MOUNT)
        estimate = rng.normal(0.0, 0.004, GRID.shape)
        for fused in (lead, leadless):
            origin = (fused._i0, fused._j0)
            fused.integrate(estimate, np.full(GRID.shape, 0.004), GRID, placement, k + 1,
                            base_z_prediction=fused.predicted_base_z(None))
            moves[id(fused)] += origin != (fused._i0, fused._j0)
    # 30 m driven: the leadless buffer moves about every MARGIN_M, the one with the lead about every LEAD_M
    assert moves[id(leadless)] >= 20 and moves[id(lead)] <= 30 / FusedMap.LEAD_M + 3
    lead_i, lead_j = lead._n.shape
    reach = math.ceil(FusedMap.LEAD_M / GRID.resolution)  # the lead adds at most this many cells per axis
    assert lead_i <= leadless._n.shape[0] + reach + 2 and lead_j <= leadless._n.shape[1] + reach + 2
    window, reference = lead.window(base, 0), leadless.window(base, 0)  # the same map either way, cell by cell
    np.testing.assert_array_equal(window.elevation, reference.elevation)
    np.testing.assert_array_equal(window.uncertainty, reference.uncertainty)
    r = GRID.resolution
    xs, ys = np.meshgrid((np.arange(0, 1200) + 0.5) * r, (np.arange(-100, 700) + 0.5) * r, indexing="ij")
    z0, s0 = leadless.heights(xs.ravel(), ys.ravel())
    z1, s1 = lead.heights(xs.ravel(), ys.ravel())
    assert np.isfinite(z0).sum() > 1000
    np.testing.assert_array_equal(z1, z0)
    np.testing.assert_array_equal(s1, s0)
