"""Riding drives: the suspension model, base_link, the camera on the body, odometry, road map."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from roadbev_core.config import StereoCamera, VehicleConfig
from roadbev_core.geometry import R_BODY_FROM_OPTICAL, attitude_from_quaternion, quaternion_to_rotation
from roadbev_lab.synth import DriveConfig, OdometryNoise, RidingConfig, RidingDrive, RoadConfig, SynthError
from roadbev_lab.synth.riding import SuspensionSpec, simulate_suspension

SMALL = StereoCamera.rsrd_half().scaled(0.25)
VEHICLE = VehicleConfig()


def test_default_suspension_modes_are_a_passenger_cars() -> None:
    modes = SuspensionSpec().modes(VEHICLE)
    for name, (freq, zeta) in modes.items():
        assert 1.0 <= freq <= 1.5, name
        assert 0.25 <= zeta <= 0.4, name


def test_body_settles_on_the_grade_and_rings_at_its_heave_frequency() -> None:
    dt, n = 0.001, 6000
    wheels = VEHICLE.wheel_positions()
    grade = 0.01
    road = np.tile(grade * wheels[:, 0], (n, 1))  # a 1 % grade under all four wheels
    road[1000:] += 0.02  # the whole road steps up 2 cm at t = 1 s
    q = simulate_suspension(SuspensionSpec(), VEHICLE, road, dt, np.zeros(n), np.zeros(n))
    assert q[999, 1] == pytest.approx(-grade, abs=1e-6)  # nose up on the climb, static
    assert q[-1, 0] - q[999, 0] == pytest.approx(0.02, abs=2e-4)  # settles 2 cm higher
    heave = q[1000:, 0] - q[-1, 0]
    peaks = [i for i in range(1, heave.size - 1) if heave[i] > heave[i - 1] and heave[i] >= heave[i + 1]]
    f, zeta = SuspensionSpec().modes(VEHICLE)["heave"]
    period = (peaks[1] - peaks[0]) * dt
    assert period == pytest.approx(1.0 / (f * math.sqrt(1 - zeta**2)), rel=0.1)


def test_braking_dives_the_nose_and_cornering_rolls_outward() -> None:
    n = 3000
    road = np.zeros((n, 4))
    brake = simulate_suspension(SuspensionSpec(), VEHICLE, road, 0.001, np.full(n, -3.0), np.zeros(n))
    left_turn = simulate_suspension(SuspensionSpec(), VEHICLE, road, 0.001, np.zeros(n), np.full(n, 2.0))
    assert brake[-1, 1] > 0.005  # pitch > 0: nose down
    assert left_turn[-1, 2] > 0.005  # roll > 0: left side up, the body leans right (outward)


@pytest.fixture(scope="module")
def drive() -> RidingDrive:
    road = RoadConfig(features=("speed_bump", "hump"), feature_spacing_m=3.0, cross_slope=0.02, grade=0.005)
    return RidingDrive(RidingConfig(drive=DriveConfig(frames=6, speed_mps=8.0, seed=11, camera=SMALL, road=road)))


def test_base_link_rides_on_the_road_and_odom_starts_at_it(drive: RidingDrive) -> None:
    gt = drive.ground_truth_poses()
    np.testing.assert_allclose(gt.position[0], 0.0, atol=1e-9)  # odom = base_link at the first stamp
    assert abs(float(np.arctan2(*quaternion_to_rotation(*gt.orientation_xyzw[0])[[1, 0], 0]))) < 1e-9
    road = drive.road_map()
    # the rear-axle centre stays within a few cm of the road under it (it is on the road at rest)
    from roadbev_lab.evaluation.arrival import Trajectory

    planar = Trajectory(gt.stamp_ns, gt.position, gt.orientation_xyzw).planar(gt.stamp_ns)
    under = road.height(planar[:, 0], planar[:, 1])
    gap = np.abs(gt.position[:, 2] - under)
    assert np.mean(gap) < 0.03 and np.max(gap) < 0.12  # humps every 3 m at 29 km/h: the body works
    # the body pitches and rolls over the features, with the cross slope's mean roll
    att = np.array([attitude_from_quaternion(*q).degrees for q in gt.orientation_xyzw])
    assert att[:, 1].std() > 0.05
    assert np.mean(att[:, 0]) == pytest.approx(math.degrees(math.atan(0.02)), abs=0.6)
    speed = np.hypot(gt.linear_velocity[:, 0], gt.linear_velocity[:, 1])
    assert 0.85 < speed.mean() / 8.0 < 1.15


def test_the_camera_is_fixed_to_the_body_and_the_imu_measures_it(drive: RidingDrive) -> None:
    cam_pos, R_base_optical = drive.base_to_camera
    np.testing.assert_allclose(cam_pos, VEHICLE.camera_position_m)
    imu = drive.imu_samples()
    stamps = np.array([s.stamp_ns for s in imu])
    quats = np.array([s.orientation_xyzw for s in imu])
    gt = drive.ground_truth_poses()
    np.testing.assert_array_equal(gt.stamp_ns, stamps)
    R_base_body = R_base_optical @ R_BODY_FROM_OPTICAL.T
    for k in (0, len(imu) // 2, len(imu) - 1):  # IMU attitude = body attitude composed with the mount
        R_cam = quaternion_to_rotation(*gt.orientation_xyzw[k]) @ R_base_body
        expected = attitude_from_quaternion(*quats[k])
        from roadbev_core.geometry import attitude_from_rotation

        got = attitude_from_rotation(R_cam)
        assert got.roll == pytest.approx(expected.roll, abs=1e-6)
        assert got.pitch == pytest.approx(expected.pitch, abs=1e-6)
    pose, attitude = drive.pose(2)  # the camera pose at a frame = base_link there + the extrinsic
    assert pose.attitude == attitude
    # specific force = R^T (camera acceleration + g): turned back to the road's axes it is the
    # second derivative of the camera's path plus gravity
    path = drive.trajectory()
    dt = 1.0 / drive.config.imu_rate_hz
    heading = float(path["heading"])
    c, s = math.cos(heading), math.sin(heading)
    to_road = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    force = np.array([to_road @ quaternion_to_rotation(*q) @ np.array(f.linear_acceleration)
                      for q, f in zip(quats, imu, strict=True)])
    for axis, key in enumerate("xyz"):
        second = np.gradient(np.gradient(path[key], dt), dt) + (9.80665 if key == "z" else 0.0)
        assert np.mean(np.abs(force[2:-2, axis] - second[2:-2])) < 0.05, key


def test_odometry_drifts_as_configured(drive: RidingDrive) -> None:
    gt = drive.ground_truth_poses()
    exact = drive.odometry(OdometryNoise(50.0, 0.0, 0.0, 0.0, 0.0))
    noisy = drive.odometry(OdometryNoise(50.0, 0.02, 0.05, 0.002, 0.002), seed=1)
    for odom, lo, hi in ((exact, 0.0, 0.01), (noisy, 0.05, 1.0), (drive.odometry(), 0.0, 0.3)):
        assert np.all(np.diff(odom.stamp_ns) == 20_000_000)  # 50 Hz
        idx = np.searchsorted(gt.stamp_ns, odom.stamp_ns)
        err = np.hypot(*(odom.position[:, :2] - gt.position[idx, :2]).T)
        assert err[0] == 0.0 and lo <= err[-1] <= hi
        assert np.all(odom.position[:, 2] == 0.0)  # planar


def test_drives_are_deterministic_and_hidden_cells_are_nan(drive: RidingDrive) -> None:
    again = RidingDrive(drive.riding)
    np.testing.assert_array_equal(again.ground_truth_poses().position, drive.ground_truth_poses().position)
    sa, sb = drive[1], again[1]
    np.testing.assert_array_equal(sa.frame.left, sb.frame.left)
    np.testing.assert_array_equal(sa.truth.elevation, sb.truth.elevation)
    hidden = [np.isnan(drive[i].truth.elevation).mean() for i in (3, 5)] + [np.isnan(sa.truth.elevation).mean()]
    assert 0 < max(hidden) < 0.3  # the far side of a hump or bump is out of sight in some frames


def test_road_map_is_the_scene_in_odom(drive: RidingDrive) -> None:
    road = drive.road_map()
    gt = drive.ground_truth_poses()
    assert road.resolution == 0.02
    n_rows = road.elevation.shape[0]
    assert n_rows * road.resolution > gt.position[-1, 0] - gt.position[0, 0] + 6.0  # wheels and windows
    # odom's origin is base_link at the first stamp: the road there is at about z = 0
    assert abs(float(road.height(np.array([0.0]), np.array([0.0]))[0])) < 0.03


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"curve_amplitude_m": 3.0}, "curve_amplitude"), ({"tail_s": -1.0}, "tail_s"),
     ({"road_map_resolution_m": 0.0}, "road_map_resolution")],
)
def test_bad_riding_config(kwargs: dict[str, Any], match: str) -> None:
    with pytest.raises(SynthError, match=match):
        RidingConfig(**kwargs)
