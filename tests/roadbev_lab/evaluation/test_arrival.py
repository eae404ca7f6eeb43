"""Preview at arrival: the metric scores what it should (truth ~0, offsets, lead time, features)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from roadbev_core.config import GridSpec, StereoCamera, VehicleConfig
from roadbev_core.fusion import MapWindow
from roadbev_core.labels import elevation_map
from roadbev_core.preview import PreviewProfiles, TrackProfile, read_profile, wheel_track_profiles
from roadbev_core.vehicle import contact_plane
from roadbev_lab.evaluation.arrival import (
    ARRIVAL_KEYS,
    REFERENCE_CONTACT_PLANE,
    REFERENCE_ROAD,
    ArrivalError,
    ArrivalSettings,
    RoadMap,
    TimedPreview,
    Trajectory,
    arrival_points,
    carried_through_car,
    feature_mask,
    map_accuracy,
    map_summary,
    map_window_rows,
    preview_at_arrival,
    wheel_paths,
)
from roadbev_lab.synth import DriveConfig, RidingConfig, RidingDrive, RoadConfig
from roadbev_lab.synth.drive import sample_points

SMALL = StereoCamera.rsrd_half().scaled(0.25)
S = 1_000_000_000


def _bump_map(height: float = 0.05) -> RoadMap:
    """A flat road with one 1 m long cosine bump across it at x = 10 m (2 cm cells)."""
    res, n_rows, n_cols = 0.02, 3000, 200  # x in [-5, 55], y in [-2, 2]
    x = 55.0 - (np.arange(n_rows) + 0.5) * res
    prof = np.where(np.abs(x - 10.0) < 0.5, 0.5 * height * (1 + np.cos(2 * math.pi * (x - 10.0))), 0.0)
    return RoadMap(np.repeat(prof[:, None], n_cols, 1).astype(np.float32), res, (25.0, 0.0))


def _straight(speed: float, seconds: float, heave: float = 0.0, pitch: float = 0.0) -> Trajectory:
    """base_link along x at ``speed``, bobbing (heave m, pitch rad at 1.3 Hz)."""
    t = np.arange(0.0, seconds, 0.01)
    phase = 2 * math.pi * 1.3 * t
    pos = np.stack([speed * t, np.zeros_like(t), heave * np.sin(phase)], 1)
    p = pitch * np.sin(phase)
    quat = np.stack([np.zeros_like(t), np.sin(p / 2), np.zeros_like(t), np.cos(p / 2)], 1)
    return Trajectory((t * S).astype(np.int64), pos, quat)


def _true_previews(traj: Trajectory, road: RoadMap, stamps: list[int], reference: str, settings: ArrivalSettings,
                   offset: float = 0.0, sigma: float = math.nan) -> list[TimedPreview]:
    """Previews of the true road along the tracks, each in its reference's frame at its stamp."""
    out = []
    pos, R = traj.interpolate(np.array(stamps))
    for k, stamp in enumerate(stamps):
        yaw = math.atan2(R[k, 1, 0], R[k, 0, 0])
        c, s = math.cos(yaw), math.sin(yaw)
        if reference == REFERENCE_ROAD:
            cam = pos[k] + R[k] @ np.array(settings.vehicle.camera_position_m)
            origin, xs, ref = cam[:2], 2.175 + 0.03 * np.arange(164), None
            z0 = cam[2] - settings.base_height
        else:
            origin, xs = pos[k, :2], 2.8 + 0.03 * np.arange(200)
            wheels = settings.vehicle.wheel_positions()
            wx = origin[0] + c * wheels[:, 0] - s * wheels[:, 1]
            wy = origin[1] + s * wheels[:, 0] + c * wheels[:, 1]
            ref = contact_plane(np.stack([wx, wy, road.footprint(wx, wy, np.full(4, yaw), 0.2, 0.03)], 1))
        tracks = []
        for name, lateral in (("left", 0.8), ("right", -0.8)):
            px, py = origin[0] + c * xs - s * lateral, origin[1] + s * xs + c * lateral
            h = road.footprint(px, py, np.full(xs.size, yaw), 0.2, 0.03)
            h = h - (z0 if ref is None else ref[0] + ref[1] * px + ref[2] * py) + offset
            tracks.append(TrackProfile(name, lateral, 0.2, h.astype(np.float32), np.full(xs.size, sigma, np.float32)))
        out.append(TimedPreview(stamp, reference, PreviewProfiles(float(xs[0]), 0.03, tuple(tracks))))
    return out


@pytest.mark.parametrize("reference", [REFERENCE_ROAD, REFERENCE_CONTACT_PLANE])
def test_true_previews_score_zero_and_full_coverage_while_the_body_pitches(reference: str) -> None:
    traj = _straight(5.0, 4.0, heave=0.01, pitch=math.radians(0.5))
    road, settings = _bump_map(), ArrivalSettings()
    stamps = [int((0.4 + 0.2 * k) * S) for k in range(13)]  # 5 Hz over the bump at 10 m
    result = preview_at_arrival(_true_previews(traj, road, stamps, reference, settings), traj, road, settings)
    assert set(ARRIVAL_KEYS) <= set(result)
    assert result["points"] == pytest.approx(2 * 5.0 * 2.4 / 0.03, abs=4)  # both wheels, every 3 cm
    assert result["abs_err_cm"] < 0.02 and result["p95_abs_err_cm"] < 0.05
    assert result["coverage_pct"] > 95.0
    assert result["features_points"] > 0 and result["features_abs_err_cm"] < 0.05
    if reference == REFERENCE_CONTACT_PLANE:
        assert result["contact_plane_abs_err_cm"] == pytest.approx(result["abs_err_cm"], abs=1e-9)
    else:  # the camera-hung plane moves with the body: against the contact plane it is off
        assert result["contact_plane_abs_err_cm"] > 0.3


def test_a_known_offset_scores_that_offset_and_the_features_are_the_bump() -> None:
    traj = _straight(5.0, 4.0)
    road, settings = _bump_map(), ArrivalSettings()
    stamps = [int((0.4 + 0.2 * k) * S) for k in range(13)]
    shifted = preview_at_arrival(_true_previews(traj, road, stamps, REFERENCE_ROAD, settings, offset=0.012),
                                 traj, road, settings)
    for key in ("abs_err_cm", "rmse_cm", "p95_abs_err_cm", "features_abs_err_cm", "smooth_abs_err_cm"):
        assert shifted[key] == pytest.approx(1.2, abs=0.02), key
    # the features are the bump (its 5 cm crest is > 1.5 cm off the 2 m median), dilated by 0.3 m
    paths = wheel_paths(traj, road, settings, stamps[0] + S // 10, stamps[-1] + S // 10)
    x = paths[0].xy[:, 0]
    assert np.all(np.abs(x[paths[0].feature] - 10.0) < 0.5 + 0.3 + 0.03)
    assert np.any(paths[0].feature)


def test_each_point_carries_the_sigma_of_the_message_that_scored_it() -> None:
    traj = _straight(5.0, 4.0)
    road, settings = _bump_map(), ArrivalSettings()
    stamps = [int((0.4 + 0.2 * k) * S) for k in range(13)]
    # message k is off by 1 cm * (k + 1) and says so in its sigma: a point's error tells which
    # message it was read from (the true profiles read off by < 1 mm on the bump), and its sigma
    # must be that message's
    previews = [_true_previews(traj, road, [t], REFERENCE_ROAD, settings, offset=0.01 * (k + 1),
                               sigma=0.01 * (k + 1))[0] for k, t in enumerate(stamps)]
    for points in arrival_points(previews, traj, road, settings):
        covered = points.covered
        assert covered.sum() > 100
        assert np.all(np.isnan(points.preview_sigma[~np.isfinite(points.error)]))
        np.testing.assert_allclose(points.preview_sigma[covered], points.error[covered], atol=1e-3)
        assert np.unique(np.round(points.preview_sigma[covered], 3)).size >= 8  # many messages were read


@pytest.mark.parametrize(("sigma", "within_1", "within_2", "wrong"), [(0.024, 100.0, 100.0, 0.0),
                                                                      (0.008, 0.0, 100.0, 0.0),
                                                                      (0.003, 0.0, 0.0, 100.0)])
def test_the_sigma_is_scored_against_the_error_at_arrival(sigma: float, within_1: float, within_2: float,
                                                          wrong: float) -> None:
    traj = _straight(5.0, 4.0)
    road, settings = _bump_map(), ArrivalSettings()
    stamps = [int((0.4 + 0.2 * k) * S) for k in range(13)]
    # every point 1.2 cm off: within 1 sigma only for the wide sigma, beyond 3 sigma and 1 cm for the narrow one
    result = preview_at_arrival(_true_previews(traj, road, stamps, REFERENCE_ROAD, settings, offset=0.012,
                                               sigma=sigma), traj, road, settings)
    assert result["sigma_points"] == round(result["points"] * result["coverage_pct"] / 100.0)
    assert result["within_1sigma_pct"] == within_1 and result["within_2sigma_pct"] == within_2
    assert result["confident_wrong_pct"] == wrong
    assert result["mean_sigma_cm"] == pytest.approx(100.0 * sigma, rel=1e-5)


def test_lead_time_beyond_the_preview_horizon_leaves_points_uncovered() -> None:
    traj = _straight(10.0, 5.0)
    road = _bump_map()
    stamps = [int((0.4 + 0.2 * k) * S) for k in range(15)]
    previews = _true_previews(traj, road, stamps, REFERENCE_ROAD, ArrivalSettings())
    # the window reaches 5.9 m ahead of the front wheel: 0.59 s at 10 m/s
    short = preview_at_arrival(previews, traj, road, ArrivalSettings(lead_time_s=0.1))
    long = preview_at_arrival(previews, traj, road, ArrivalSettings(lead_time_s=0.8))
    assert short["coverage_pct"] > 95.0
    assert long["coverage_pct"] == 0.0 and math.isnan(long["abs_err_cm"])
    assert long["points"] == pytest.approx(short["points"], abs=4)


def test_an_older_message_still_counts_where_the_newer_one_has_no_value() -> None:
    traj = _straight(5.0, 4.0)
    road, settings = _bump_map(), ArrivalSettings()
    stamps = [int((0.4 + 0.2 * k) * S) for k in range(13)]
    previews = _true_previews(traj, road, stamps, REFERENCE_ROAD, settings)
    holey = []
    for k, p in enumerate(previews):  # every other message only sees its first metre
        if k % 2:
            tracks = tuple(TrackProfile(t.name, t.lateral_offset, t.width,
                                        np.where(np.arange(t.elevation.size) < 33, t.elevation, np.nan).astype(
                                            np.float32), t.uncertainty) for t in p.profiles.tracks)
            p = TimedPreview(p.stamp_ns, p.reference, PreviewProfiles(p.profiles.start_distance, 0.03, tracks))
        holey.append(p)
    full = preview_at_arrival(previews, traj, road, settings)
    held = preview_at_arrival(holey, traj, road, settings)
    assert held["coverage_pct"] == pytest.approx(full["coverage_pct"], abs=0.5)
    assert held["abs_err_cm"] < 0.02


def test_read_profile_interpolates_and_never_guesses_across_holes() -> None:
    elev = np.array([0.0, 0.01, np.nan, 0.03, 0.04], np.float32)
    track = TrackProfile("left", 0.8, 0.2, elev, np.full(5, np.nan, np.float32))
    prof = PreviewProfiles(1.0, 0.1, (track,))
    got = read_profile(prof, "left", np.array([1.05, 1.12, 1.16, 1.24, 1.35, 1.45, 0.96, 1.46]))
    np.testing.assert_allclose(got[:2], [0.005, 0.01], atol=1e-7)  # between samples; near a hole: nearest
    assert np.isnan(got[2]) and np.isnan(got[3])  # no finite sample within half a spacing / a hole
    np.testing.assert_allclose(got[4:7], [0.035, 0.04, 0.0], atol=1e-6)
    assert np.isnan(got[7])  # beyond the last sample's half spacing


def test_feature_mask_finds_short_features_and_dilates() -> None:
    h = np.zeros(400)
    h[200:220] = 0.03  # a 3 cm plateau 0.6 m long (a speed table's top, a patch)
    idx = np.flatnonzero(feature_mask(h, 0.03))
    assert idx.min() == 200 - 10 and idx.max() == 219 + 10  # dilated by 0.3 m = 10 points
    assert not feature_mask(np.linspace(0.0, 0.2, 400), 0.03).any()  # a grade is no feature
    # a long step follows the running median (docs/interface/evaluation.md's definition): only its edge zone
    # within a window could count, and there the median jumps with it
    step = np.where(np.arange(400) >= 200, 0.03, 0.0)
    assert not feature_mask(step, 0.03).any()


def test_bad_inputs_raise() -> None:
    traj, road = _straight(5.0, 2.0), _bump_map()
    with pytest.raises(ArrivalError, match="no preview"):
        preview_at_arrival([], traj, road)
    with pytest.raises(ArrivalError, match="lead time"):
        ArrivalSettings(lead_time_s=-1.0)
    with pytest.raises(ArrivalError, match="reference"):
        TimedPreview(0, "map", PreviewProfiles(1.0, 0.1, ()))
    late = _true_previews(traj, road, [int(5 * S)], REFERENCE_ROAD, ArrivalSettings())
    with pytest.raises(ArrivalError, match="do not cover"):
        preview_at_arrival(late, traj, road)


def test_per_frame_truth_previews_on_a_riding_drive_in_both_conventions() -> None:
    """The real per-frame path (labels -> wheel_track_profiles, roadbev_road) and contact-plane
    previews on a drive where the car rides on its road: ~0 error, ~100 % coverage."""
    road = RoadConfig(features=("speed_bump", "pothole"), feature_spacing_m=3.0)
    drive = RidingDrive(RidingConfig(drive=DriveConfig(frames=8, speed_mps=5.0, seed=4, camera=SMALL, road=road),
                                     curve_amplitude_m=0.0))
    gt = drive.ground_truth_poses()
    traj = Trajectory(gt.stamp_ns, gt.position, gt.orientation_xyzw)
    road_map = drive.road_map()
    grid: GridSpec = drive.config.grid
    settings = ArrivalSettings(camera_in_base=drive.base_to_camera, vehicle=VehicleConfig())
    previews = []
    for i in range(len(drive)):
        pose, _ = drive.pose(i)
        labels = elevation_map(sample_points(drive.scene, pose, grid, drive.config.lidar, np.random.default_rng(i)),
                               grid)
        previews.append(TimedPreview(drive.frame_stamps_ns[i], REFERENCE_ROAD,
                                     wheel_track_profiles(labels.elevation, None, grid)))
    # arrivals from 0.3 s after the first frame: the first window starts 0.96 m ahead of the wheel
    frames = [drive.frame_stamps_ns[0] + 3 * S // 10, *drive.frame_stamps_ns[1:]]
    per_frame = preview_at_arrival(previews, traj, road_map, settings, frame_stamps_ns=frames)
    assert per_frame["coverage_pct"] == 100.0
    assert per_frame["abs_err_cm"] < 0.05 and per_frame["p95_abs_err_cm"] < 0.15
    assert per_frame["contact_plane_abs_err_cm"] > 0.2  # body heave/pitch/roll and cross slope
    planar = _true_previews(traj, road_map, drive.frame_stamps_ns, REFERENCE_CONTACT_PLANE, settings)
    contact = preview_at_arrival(planar, traj, road_map, settings, frame_stamps_ns=frames)
    assert contact["coverage_pct"] == 100.0 and contact["abs_err_cm"] < 0.05


# --- the fused map against the truth ----------------------------------------------------------------
def _drifted(traj: Trajectory, dx: float, dyaw: float) -> Trajectory:
    """``traj`` as a drifting odometry sees it: rotated by ``dyaw`` about the origin, then moved ``dx`` along x."""
    c, s = math.cos(dyaw), math.sin(dyaw)
    pos = traj.position.copy()
    pos[:, 0], pos[:, 1] = c * traj.position[:, 0] - s * traj.position[:, 1] + dx, \
        s * traj.position[:, 0] + c * traj.position[:, 1]
    turn = np.array([0.0, 0.0, math.sin(dyaw / 2), math.cos(dyaw / 2)])  # xyzw
    quats = np.array([_quat_product(turn, q) for q in traj.orientation_xyzw])
    return Trajectory(traj.stamp_ns, pos, quats)


def _quat_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz])


def _window_in(frame: Trajectory, truth: Trajectory, road: RoadMap, stamp: int) -> MapWindow:
    """A perfect map window around the car at ``stamp``, kept in the frame of ``frame`` (the
    vehicle's odometry): each cell holds the true height of the place it lies at relative to the car."""
    res, n = 0.05, 120
    held = frame.planar(np.array([stamp]))[0]
    centre = (float(held[0]), float(held[1]))
    window = MapWindow(np.zeros((n, n), np.float32), np.full((n, n), 0.005, np.float32), np.ones((n, n), np.float32),
                       np.zeros((n, n), np.float32), res, centre, stamp)
    x, y = window.cell_centres()
    gx, gy = np.meshgrid(x, y, indexing="ij")
    tx, ty = carried_through_car(gx, gy, held, truth.planar(np.array([stamp]))[0])
    return window._replace(elevation=road.height(tx, ty).astype(np.float32))


def test_a_point_carried_through_the_car_keeps_its_place_relative_to_the_car() -> None:
    held, true = np.array([10.0, 2.0, 0.5]), np.array([9.7, 2.1, 0.49])
    ahead = np.array([10.0 + 3.0 * math.cos(0.5)]), np.array([2.0 + 3.0 * math.sin(0.5)])  # 3 m ahead of the car
    x, y = carried_through_car(*ahead, held, true)
    np.testing.assert_allclose([x[0], y[0]], [9.7 + 3.0 * math.cos(0.49), 2.1 + 3.0 * math.sin(0.49)], atol=1e-12)
    x, y = carried_through_car(np.array([10.0]), np.array([2.0]), held, true)
    np.testing.assert_allclose([x[0], y[0]], true[:2], atol=1e-12)


def test_a_map_kept_in_a_drifting_odometry_is_scored_where_the_car_has_it() -> None:
    road = _bump_map(0.08)
    truth = _straight(10.0, 3.0)
    odometry = _drifted(truth, 0.3, 0.01)  # 30 cm and 0.6 degrees off after a drive
    stamps = [int(1.0 * S), int(1.2 * S)]  # the bump 10 m ahead... then 8 m: in the window
    windows = [_window_in(odometry, truth, road, s) for s in stamps]
    carried = map_accuracy(windows, road, truth, VehicleConfig(), odometry)
    assert carried["abs_err_cm"] < 0.05 and carried["confident_wrong_pct"] == 0.0
    # scored where its cells lie, the same map seems to misplace the bump by the drift
    in_place = map_accuracy(windows, road, truth, VehicleConfig())
    assert in_place["abs_err_cm"] > 5 * carried["abs_err_cm"] + 0.05
    assert in_place["confident_wrong_pct"] > 1.0
    # with the odometry the truth's own, carrying changes nothing
    own = [_window_in(truth, truth, road, s) for s in stamps]
    assert map_accuracy(own, road, truth, VehicleConfig(), truth) == map_accuracy(own, road, truth, VehicleConfig())


def test_the_map_is_also_scored_per_metre_ahead_of_the_car() -> None:
    road = _bump_map(0.08)
    truth = _straight(10.0, 3.0)
    stamps = [int(1.0 * S), int(1.2 * S)]
    windows = []
    for stamp in stamps:
        window = _window_in(truth, truth, road, stamp)  # 6 m square around base_link, 5 cm cells
        x, _ = window.cell_centres()
        ahead = x - truth.planar(np.array([stamp]))[0, 0]  # [n_rows]: the car drives along x
        wrong = (ahead >= 2.0) & (ahead < 3.0)  # 1 cm too high 2-3 m ahead, sigma 0.5 cm: outside 1 sigma
        windows.append(window._replace(elevation=window.elevation + np.where(wrong, 0.01, 0.0)[:, None]))
    bands = {b["x_from_m"]: b for b in map_accuracy(windows, road, truth, VehicleConfig())["bands"]}
    assert sorted(bands) == [-3.0, -2.0, -1.0, 0.0, 1.0, 2.0]
    assert all(b["x_to_m"] == b["x_from_m"] + 1.0 and b["windows"] == 2 and b["cells"] > 0 for b in bands.values())
    assert bands[2.0]["abs_err_cm"] == pytest.approx(1.0, abs=1e-3) and bands[2.0]["within_1sigma_pct"] == 0.0
    assert all(b["abs_err_cm"] < 1e-3 and b["within_1sigma_pct"] == 100.0 for x, b in bands.items() if x != 2.0)
    # a drive's window rows pool with another's: the bands of both are the means over all their windows
    rows = map_window_rows(windows[:1], road, truth, VehicleConfig())
    more = map_window_rows(windows[1:], road, truth, VehicleConfig())
    pooled = map_summary({k: [*rows.get(k, []), *more.get(k, [])] for k in {**rows, **more}}, 2)
    assert pooled == map_accuracy(windows, road, truth, VehicleConfig())
    # without the car's true poses there is nothing to measure "ahead" from
    assert map_accuracy(windows, road)["bands"] == []
