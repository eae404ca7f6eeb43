"""Drives and samples: determinism, IMU/frame consistency, suspension, labels vs the height field."""

from __future__ import annotations

import math
import pickle
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.geometry import attitude_from_quaternion, quaternion_to_rotation, rsrd_camera_attitude
from roadbev_lab.synth import (
    RSRD_ATTITUDE,
    DriveConfig,
    LidarConfig,
    RoadConfig,
    SynthError,
    SyntheticDrive,
    make_sample,
)
from roadbev_lab.synth.drive import _wheel_heights

SMALL = StereoCamera.rsrd_half().scaled(0.25)
GRID = GridSpec()


def _slerp(q0: np.ndarray, q1: np.ndarray, t: float) -> np.ndarray:
    """Reference slerp, written independently of the library's."""
    if q0 @ q1 < 0:
        q1 = -q1
    omega = math.acos(min(1.0, float(q0 @ q1)))
    if omega < 1e-9:
        return q0
    return (math.sin((1 - t) * omega) * q0 + math.sin(t * omega) * q1) / math.sin(omega)


@pytest.fixture(scope="module")
def drive() -> SyntheticDrive:
    road = RoadConfig(road_class="C", features=("speed_bump", "pothole", "hump"), feature_spacing_m=3.0)
    return SyntheticDrive(DriveConfig(frames=12, seed=3, camera=SMALL, road=road))


def test_frame_attitudes_equal_the_slerped_imu(drive: SyntheticDrive) -> None:
    imu = drive.imu_samples()
    stamps = np.array([s.stamp_ns for s in imu])
    assert np.all(np.diff(stamps) == 10_000_000)  # 100 Hz
    quats = np.array([s.orientation_xyzw for s in imu])
    np.testing.assert_allclose(np.linalg.norm(quats, axis=1), 1.0, atol=1e-9)
    for i in range(len(drive)):
        stamp = drive.frame_stamps_ns[i]
        k = int(np.searchsorted(stamps, stamp)) - 1
        assert k >= 0 and stamps[k] < stamp < stamps[k + 1]  # between samples, covered both sides
        t = (stamp - stamps[k]) / (stamps[k + 1] - stamps[k])
        q = _slerp(quats[k], quats[k + 1], t)
        expected = attitude_from_quaternion(*q)
        _, attitude = drive.pose(i)
        assert abs(math.degrees(attitude.roll - expected.roll)) < 0.01
        assert abs(math.degrees(attitude.pitch - expected.pitch)) < 0.01


def test_frames_come_at_5hz_with_their_attitude(drive: SyntheticDrive) -> None:
    assert len(drive) == 12
    assert np.all(np.diff(drive.frame_stamps_ns) == 200_000_000)
    sample = drive[0]
    assert sample.frame.stamp_ns == drive.frame_stamps_ns[0]
    assert sample.frame.left.shape == (SMALL.height, SMALL.width, 3) and sample.frame.left.dtype == np.uint8
    assert sample.frame.right is not None and not np.array_equal(sample.frame.left, sample.frame.right)
    assert sample.frame.attitude == drive.pose(0)[1]
    with pytest.raises(IndexError):
        drive[12]


def test_imu_rates_and_specific_force_are_physical(drive: SyntheticDrive) -> None:
    imu = drive.imu_samples()
    acc = np.array([s.linear_acceleration for s in imu])
    gyro = np.array([s.angular_velocity for s in imu])
    norm = np.linalg.norm(acc, axis=1)
    assert abs(float(np.median(norm)) - 9.80665) < 0.3 and np.all(np.abs(norm - 9.80665) < 6.0)
    assert np.median(acc[:, 2]) > 9.0  # mostly gravity on the body z (camera body pitched ~19 deg)
    assert np.abs(gyro).max() < 1.0  # rad/s: suspension motion, not tumbling
    # the gyro integrates to the orientation change (pitch about body y, small angles)
    pitch = np.array([attitude_from_quaternion(*s.orientation_xyzw).pitch for s in imu])
    integrated = np.cumsum(gyro[:-1, 1] * 0.01)
    assert np.corrcoef(integrated, pitch[1:] - pitch[0])[0, 1] > 0.9


def test_attitudes_and_camera_height_are_realistic() -> None:
    road = RoadConfig(road_class="C", features=("speed_bump", "hump", "pothole"), feature_spacing_m=6.0)
    drive = SyntheticDrive(DriveConfig(frames=40, seed=5, camera=SMALL, road=road))  # no frame rendered
    imu = drive.imu_samples()
    att = np.degrees([attitude_from_quaternion(*s.orientation_xyzw).pitch for s in imu])
    roll = np.degrees([attitude_from_quaternion(*s.orientation_xyzw).roll for s in imu])
    a = RSRD_ATTITUDE
    # humps and bumps tip the car by a few degrees beyond the spread of the real (mostly
    # bump-free) RSRD drives, not more
    assert a["pitch_min"] - 2.5 < att.min() and att.max() < a["pitch_max"] + 2.5
    assert a["roll_min"] - 1.0 < roll.min() and roll.max() < a["roll_max"] + 1.0
    assert 0.1 < att.std() < 1.5 and 0.1 < roll.std() < 1.2  # moves on the suspension
    # on a road with no discrete features the attitude stays in the real range
    plain = SyntheticDrive(DriveConfig(frames=40, seed=5, camera=SMALL, road=RoadConfig(road_class="C", features=())))
    pitch = np.degrees([attitude_from_quaternion(*s.orientation_xyzw).pitch for s in plain.imu_samples()])
    assert a["pitch_min"] - 0.5 < pitch.min() and pitch.max() < a["pitch_max"] + 0.5
    deflection = []
    for i in range(len(drive)):
        pose, _ = drive.pose(i)
        front, rear, _, _ = _wheel_heights(drive.scene, np.array([pose.x]), np.array([pose.y]), np.array([pose.yaw]))
        deflection.append(pose.z - GRID.base_height - float(front[0] + rear[0]) / 2)
    # the camera rides on the suspension: centimetres around its mount height above the wheels
    assert np.abs(deflection).max() < 0.06 and 0.002 < np.std(deflection) < 0.02


def test_drives_are_deterministic_and_seeded() -> None:
    cfg = DriveConfig(frames=2, seed=9, camera=SMALL.scaled(0.5), road=RoadConfig(features=("crack",)))
    a, b = SyntheticDrive(cfg), SyntheticDrive(cfg)
    other = SyntheticDrive(
        DriveConfig(frames=2, seed=10, camera=SMALL.scaled(0.5), road=RoadConfig(features=("crack",)))
    )
    assert a.imu_samples() == b.imu_samples()
    sa, sb, so = a[1], b[1], other[1]
    np.testing.assert_array_equal(sa.frame.left, sb.frame.left)
    np.testing.assert_array_equal(sa.frame.right, sb.frame.right)
    np.testing.assert_array_equal(sa.truth.elevation, sb.truth.elevation)
    assert not np.array_equal(sa.frame.left, so.frame.left)
    assert a.imu_samples() != other.imu_samples()


def _truth_vs_surface(drive: SyntheticDrive, index: int) -> tuple[np.ndarray, np.ndarray]:
    sample = drive[index]
    pose, _ = drive.pose(index)
    x, y = np.meshgrid(GRID.x_centres(), GRID.y_centres(), indexing="ij")
    centres = np.stack([x, y, np.zeros_like(x)], axis=-1).reshape(-1, 3)
    world = pose.road_to_world(centres, GRID.base_height)
    surface = drive.scene.height(world[:, 0], world[:, 1]) - (pose.z - GRID.base_height)
    return sample.truth.elevation.ravel().astype(np.float64), surface


def test_noise_free_labels_match_the_height_field_at_cell_centres() -> None:
    road = RoadConfig(road_class="B", features=("hump", "rut"), feature_spacing_m=2.0)
    drive = SyntheticDrive(DriveConfig(frames=2, seed=4, camera=SMALL.scaled(0.5), road=road))
    truth, surface = _truth_vs_surface(drive, 1)
    assert np.isfinite(truth).all()  # dense LiDAR-like points label every cell
    assert np.abs(truth - surface).max() < 0.002
    assert truth.max() - truth.min() > 0.02  # the features are in view, not a flat road
    # with sharp features (pothole walls, steps) the cell mean differs at edges only
    road = RoadConfig(road_class="C", features=("pothole", "speed_bump", "step", "crack"), feature_spacing_m=2.0)
    drive = SyntheticDrive(DriveConfig(frames=2, seed=4, camera=SMALL.scaled(0.5), road=road))
    truth, surface = _truth_vs_surface(drive, 1)
    assert np.percentile(np.abs(truth - surface), 95) < 0.002


def test_labels_stay_in_the_grid_range_and_lidar_options_work() -> None:
    road = RoadConfig(road_class="D", features=("kerb", "speed_bump", "pothole"), cross_slope=0.03)
    for seed in (1, 2):
        sample = make_sample(seed, camera=SMALL.scaled(0.5), road=road)
        elev = sample.truth.elevation
        assert np.nanmin(elev) >= GRID.z_min and np.nanmax(elev) <= GRID.z_max
    sparse = make_sample(
        1, camera=SMALL.scaled(0.5), road=road, lidar=LidarConfig(spacing_m=0.03, dropout=0.5, range_falloff=2.0)
    )
    dense = make_sample(1, camera=SMALL.scaled(0.5), road=road)
    assert sparse.points_road.shape[0] < dense.points_road.shape[0] / 10
    assert 0.1 < sparse.truth.mask.mean() < 0.9  # some cells get no point
    far, near = sparse.truth.mask[:40].mean(), sparse.truth.mask[-40:].mean()
    assert far < near  # density falls with range
    noisy = make_sample(1, camera=SMALL.scaled(0.5), road=road, lidar=LidarConfig(noise_m=0.01))
    diff = noisy.truth.elevation - dense.truth.elevation
    assert 0.001 < float(np.nanstd(diff)) < 0.01  # ~1 cm point noise averaged over ~9 points


def test_make_sample_places_features_in_the_grid_with_their_signs() -> None:
    cam = SMALL.scaled(0.5)
    pothole = make_sample(21, camera=cam, road=RoadConfig(road_class="A", features=("pothole",)))
    bump = make_sample(21, camera=cam, road=RoadConfig(road_class="A", features=("speed_bump",)))
    base = np.nanmedian(pothole.truth.elevation)
    assert np.nanmin(pothole.truth.elevation) < base - 0.025
    assert np.nanmax(bump.truth.elevation) > np.nanmedian(bump.truth.elevation) + 0.03
    again = make_sample(21, camera=cam, road=RoadConfig(road_class="A", features=("pothole",)))
    np.testing.assert_array_equal(again.frame.left, pothole.frame.left)
    roll, pitch = pothole.frame.attitude.degrees
    assert RSRD_ATTITUDE["pitch_min"] <= pitch <= RSRD_ATTITUDE["pitch_max"]
    assert RSRD_ATTITUDE["roll_min"] <= roll <= RSRD_ATTITUDE["roll_max"]


def test_random_samples_differ_and_use_the_default_rig() -> None:
    a = make_sample(100, camera=SMALL)
    b = make_sample(101, camera=SMALL)
    assert a.frame.camera == SMALL
    assert not np.array_equal(a.frame.left, b.frame.left)
    assert not np.array_equal(a.truth.elevation, b.truth.elevation)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"road_class": "Z"}, "road_class"),
        ({"features": ("volcano",)}, "volcano"),
        ({"surface": "gravel"}, "surface"),
        ({"grade": 0.05}, "grade"),
        ({"jpeg_quality": 0}, "jpeg"),
        ({"row_offset_px": 2.5}, "row_offset_px"),
        ({"row_offset_px": float("nan")}, "row_offset_px"),
    ],
)
def test_road_config_rejects_bad_values(kwargs: dict[str, Any], match: str) -> None:
    with pytest.raises(SynthError, match=match):
        RoadConfig(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"frames": 0}, "frame"),
        ({"speed_mps": -1.0}, "speed"),
        ({"imu_rate_hz": 4.0}, "IMU"),
        ({"frames": 1000, "speed_mps": 10.0}, "split it"),
    ],
)
def test_drive_config_rejects_bad_values(kwargs: dict[str, Any], match: str) -> None:
    with pytest.raises(SynthError, match=match):
        DriveConfig(**kwargs)
    with pytest.raises(SynthError):
        LidarConfig(spacing_m=0.0)


@pytest.mark.parametrize("frames", [1, 3])
def test_short_drives_stay_realistic(frames: int) -> None:
    """The random motion of a short drive keeps its real amplitude (not the spread of a long one)."""
    for seed in (0, frames + 4):
        drive = SyntheticDrive(DriveConfig(frames=frames, seed=seed, camera=SMALL))  # nothing rendered
        for i in range(frames):
            pose, attitude = drive.pose(i)
            roll, pitch = attitude.degrees
            assert RSRD_ATTITUDE["pitch_min"] - 1.0 < pitch < RSRD_ATTITUDE["pitch_max"] + 1.0
            assert RSRD_ATTITUDE["roll_min"] - 1.0 < roll < RSRD_ATTITUDE["roll_max"] + 1.0
            assert abs(pose.y) < 0.8 and abs(pose.yaw) < 0.02  # in the lane, heading along it
            assert abs(pose.z - GRID.base_height) < 0.05


def test_embedded_attitude_statistics_match_the_real_rsrd_poses(rsrd_dir: Path) -> None:
    """RSRD_ATTITUDE (the library never loads the pickles) equals the stats of the real poses."""
    calibs: dict[str, dict[str, Any]] = {}
    per_seq: dict[str, list[tuple[float, float]]] = {}
    for f in sorted((rsrd_dir / "sample_info").glob("*/*.pkl")):
        with f.open("rb") as fh:
            samples = pickle.load(fh)  # trusted: the pinned copies of the rsrd_dir fixture
        for s in samples:
            day = s["time"][:8]
            if day not in calibs:
                with (rsrd_dir / f"calib_{day}_half.pkl").open("rb") as fh:
                    calibs[day] = pickle.load(fh)
            roll, pitch = rsrd_camera_attitude(s["roll"], s["pitch"], np.asarray(calibs[day]["R"])).degrees
            per_seq.setdefault(s["path"], []).append((roll, pitch))
    rp = np.array([v for seq in per_seq.values() for v in seq])
    a = RSRD_ATTITUDE
    assert rp.shape[0] == 1581
    for i, name in ((0, "roll"), (1, "pitch")):
        assert rp[:, i].mean() == pytest.approx(a[f"{name}_mean"], abs=0.002)
        assert rp[:, i].std() == pytest.approx(a[f"{name}_std"], abs=0.002)
        assert rp[:, i].min() == pytest.approx(a[f"{name}_min"], abs=0.002)
        assert rp[:, i].max() == pytest.approx(a[f"{name}_max"], abs=0.002)
        in_drive = np.mean([np.std([v[i] for v in seq]) for seq in per_seq.values() if len(seq) > 5])
        assert in_drive == pytest.approx(a[f"{name}_std_in_drive"], abs=0.002)


def test_mono_rig_other_grid_and_standing_vehicle() -> None:
    mono = StereoCamera(fx=250.0, fy=250.0, cx=119.5, cy=65.5, baseline=0.0, width=240, height=132)
    sample = make_sample(3, camera=mono)
    assert sample.frame.right is None and sample.frame.left.shape == (132, 240, 3)
    grid = GridSpec(x_min=3.0, x_max=12.0, base_height=1.5, z_min=-0.3, z_max=0.3)
    sample = make_sample(4, camera=SMALL.scaled(0.5), grid=grid)
    assert sample.truth.elevation.shape == grid.shape and sample.truth.mask.all()
    drive = SyntheticDrive(DriveConfig(frames=2, speed_mps=0.0, camera=SMALL.scaled(0.5)))
    assert drive.pose(0)[0].x == drive.pose(1)[0].x
    assert drive[1].truth.mask.all()


def test_accelerometer_reports_the_trajectory_plus_gravity() -> None:
    drive = SyntheticDrive(DriveConfig(frames=30, seed=3, camera=SMALL, accel_noise=0.0, gyro_noise=0.0))
    path = drive.trajectory()
    dt = 0.01
    heading = float(path["heading"])
    c, s = math.cos(heading), math.sin(heading)
    rows = []
    for sample in drive.imu_samples():  # body specific force -> ENU -> road axes
        f = quaternion_to_rotation(*sample.orientation_xyzw) @ np.array(sample.linear_acceleration)
        rows.append([c * f[0] + s * f[1], -s * f[0] + c * f[1], f[2]])
    force = np.array(rows)[5:-5]
    ax = np.gradient(np.gradient(path["x"], dt), dt)[5:-5]
    az = np.gradient(np.gradient(path["z"], dt), dt)[5:-5]
    np.testing.assert_allclose(force[:, 0], ax, atol=1e-3)
    np.testing.assert_allclose(force[:, 2], az + 9.80665, atol=1e-3)
    assert 0.9 < path["speed"].mean() / 5.0 < 1.1 and path["speed"].std() > 0.01  # speed drifts


def test_a_seed_renders_the_scene_the_caches_hold() -> None:
    """A fingerprint of one seed. When the generator changes on purpose, bump
    ``roadbev_lab.training.datasets.SCENE_VERSION`` (scene caches of the old generator are then not read)
    and put the new values here."""
    sample = make_sample(100_000, camera=SMALL)
    elevation = sample.truth.elevation
    assert sample.frame.right is not None
    assert int(np.isfinite(elevation).sum()) == 10_496
    fingerprint = (float(np.nanmean(elevation)), float(np.nanstd(elevation)),
                   float(sample.frame.left.mean()), float(sample.frame.right.mean()),
                   sample.frame.attitude.roll, sample.frame.attitude.pitch)
    expected = (-0.0245085, 0.0615136, 124.565015, 121.496591, -0.00138201, 0.32167007)  # version 2
    assert fingerprint == pytest.approx(expected, rel=1e-5, abs=1e-7), "the generator changed: bump SCENE_VERSION"


def test_a_far_field_grid_is_labelled_after_everything_else_a_frame_draws() -> None:
    far = GridSpec(x_min=7.08, x_max=15.0, resolution=0.12, z_min=-0.5, z_max=0.5)
    road = RoadConfig(road_class="B", features=("speed_bump",), feature_spacing_m=3.0)
    config = DriveConfig(frames=2, seed=4, camera=SMALL.scaled(0.5), road=road)
    plain = SyntheticDrive(config)[1]
    drive = SyntheticDrive(replace(config, far_grid=far))
    with_far = drive[1]
    # the frame and the grid's truth are those of the drive without a far field
    np.testing.assert_array_equal(with_far.frame.left, plain.frame.left)
    np.testing.assert_array_equal(with_far.truth.elevation, plain.truth.elevation)
    assert plain.far_truth is None and with_far.far_truth is not None
    # the far-field truth is the height field at its cells, every cell labelled
    pose, _ = drive.pose(1)
    x, y = np.meshgrid(far.x_centres(), far.y_centres(), indexing="ij")
    world = pose.road_to_world(np.stack([x, y, np.zeros_like(x)], axis=-1).reshape(-1, 3), far.base_height)
    surface = drive.scene.height(world[:, 0], world[:, 1]) - (pose.z - far.base_height)
    labels = with_far.far_truth.elevation.ravel()
    # (a 12 cm cell's mean differs from its centre's height on a bump's flanks only)
    assert np.isfinite(labels).all() and np.median(np.abs(labels - surface)) < 0.001
    # a single sample places the features in the far window too
    sample = make_sample(21, camera=SMALL, road=RoadConfig(road_class="A", features=("speed_bump",)), far_grid=far)
    assert sample.far_truth is not None
    far_heights = sample.far_truth.elevation
    assert np.nanmax(far_heights) > np.nanmedian(far_heights) + 0.03
    with pytest.raises(SynthError, match="beyond the 30 m of road"):
        DriveConfig(far_grid=GridSpec(x_min=7.08, x_max=31.08, resolution=0.12, z_min=-0.5, z_max=0.5))
