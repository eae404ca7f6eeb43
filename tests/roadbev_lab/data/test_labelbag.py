"""Label bags from a synthetic drive seen by a simulated LiDAR (rays cast against the height field).

The drive (roadbev_lab.synth) gives the true road, the camera's path and the IMU; a 32-ring
LiDAR 0.3 m above the left camera scans it at 10 Hz with 1 cm range noise; ``/odom`` is the exact
planar pose of base_link (the body's heave is not in it, as on a real car). The labels that
:func:`roadbev_lab.data.labelbag.label_bag` writes are compared with the true height field.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from msg_bridge.bag import BagError, bag_topics
from msg_bridge.tf import StaticTransform
from roadbev_core.geometry import R_BODY_FROM_OPTICAL, attitude_from_rotation, quaternion_to_rotation, rotation_from_rpy
from roadbev_lab.data.labelbag import RecordedFrame, label_bag, write_recording
from roadbev_lab.data.lidar_labels import LabelConfig, LabelError
from roadbev_lab.evaluation.evalbag import read_eval_bag
from roadbev_lab.synth import DriveConfig, RoadConfig, SyntheticDrive
from roadbev_lab.synth.lidar import LidarPattern, lidar_scan

CAMERA_IN_BASE = np.array([1.6, 0.0, 1.1])
LIDAR_ABOVE_CAMERA = 0.3


@pytest.fixture(scope="module")
def drive_bag(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, SyntheticDrive]:
    config = DriveConfig(frames=3, speed_mps=5.0, seed=3, road=RoadConfig(features=("speed_bump", "pothole")))
    config = replace(config, camera=config.camera.scaled(0.25))
    drive = SyntheticDrive(config)
    w, h = config.camera.size
    grey = np.full((h, w, 3), 110, np.uint8)  # the labeller never reads the pixels
    frames = [RecordedFrame(s, grey, grey) for s in drive.frame_stamps_ns]
    traj, imu = drive.trajectory(), drive.imu_samples()
    rng = np.random.default_rng(0)
    scans, odom = [], []
    for k in range(len(imu)):
        yaw = float(traj["yaw"][k])
        camera = np.array([traj["x"][k], traj["y"][k], traj["z"][k]])
        base = camera[:2] - CAMERA_IN_BASE[0] * np.array([np.cos(yaw), np.sin(yaw)])
        odom.append((int(traj["stamp_ns"][k]), float(base[0]), float(base[1]), 0.0, yaw))
        if k % 10 == 0:  # a 10 Hz LiDAR next to the 100 Hz IMU
            att = attitude_from_rotation(quaternion_to_rotation(*imu[k].orientation_xyzw))
            R = rotation_from_rpy(att.roll, att.pitch, yaw)
            position = camera + R @ np.array([0.0, 0.0, LIDAR_ABOVE_CAMERA])
            scans.append((int(traj["stamp_ns"][k]), "lidar", lidar_scan(drive.scene, position, R, LidarPattern(), rng)))
    transforms = [
        StaticTransform("base_link", "stereo_left_optical_frame", R_BODY_FROM_OPTICAL, CAMERA_IN_BASE),
        StaticTransform(
            "stereo_left_optical_frame",
            "lidar",
            R_BODY_FROM_OPTICAL.T,
            R_BODY_FROM_OPTICAL.T @ np.array([0.0, 0.0, LIDAR_ABOVE_CAMERA]),
        ),
    ]
    path = tmp_path_factory.mktemp("drive") / "drive.mcap"
    write_recording(
        path,
        config.camera,
        frames,
        imu=[(s.stamp_ns, s.orientation_xyzw) for s in imu],
        scans=scans,
        odometry=odom,
        static_transforms=transforms,
    )
    return path, drive


def _errors(path: Path, drive: SyntheticDrive) -> tuple[np.ndarray, np.ndarray]:
    """Labelled share of the cells and mean |label - true height| (m) per frame."""
    bag = read_eval_bag(path)
    grid = bag.grid
    x, y = np.meshgrid(grid.x_centres(), grid.y_centres(), indexing="ij")
    share, err = [], []
    for i, sample in enumerate(bag):
        pose, _ = drive.pose(i)
        world = pose.road_to_world(np.stack([x, y, np.zeros_like(x)], axis=-1), grid.base_height)
        truth = drive.scene.height(world[..., 0], world[..., 1]) - (pose.z - grid.base_height)
        assert sample.truth is not None
        labelled = np.isfinite(sample.truth)
        share.append(labelled.mean())
        err.append(np.abs(sample.truth[labelled] - truth[labelled]).mean())
    return np.array(share), np.array(err)


def test_labels_from_a_simulated_lidar_match_the_height_field(drive_bag: Any, tmp_path: Path) -> None:
    src, drive = drive_bag
    grid = drive.config.grid
    single, accumulated = tmp_path / "single.mcap", tmp_path / "acc.mcap"
    one = label_bag(src, single, grid=grid, config=LabelConfig())
    many = label_bag(src, accumulated, grid=grid, config=LabelConfig(window_s=0.6))
    assert one.labelled_frames == many.labelled_frames == 3
    assert one.mean_scans_per_frame == 1.0 and many.mean_scans_per_frame > 3
    assert "/lidar/points" not in bag_topics(accumulated)  # an evaluation bag: no LiDAR copied
    assert {"/odom", "/tf_static", "/imu/data", "/ground_truth/elevation"} <= set(bag_topics(accumulated))
    share_one, err_one = _errors(single, drive)
    share_many, err_many = _errors(accumulated, drive)
    # One scan of 32 rings labels stripes; accumulating with the odometry fills the grid in.
    assert share_many.mean() > 2.5 * share_one.mean()
    # Against the true surface: a few millimetres (1 cm range noise, a few points per 3 cm cell).
    assert err_one.max() < 0.006
    assert err_many.max() < 0.006


def test_label_bag_errors(drive_bag: Any, tmp_path: Path) -> None:
    src, drive = drive_bag
    grid = drive.config.grid
    with pytest.raises(BagError, match="no LiDAR topic /velodyne_points"):
        label_bag(src, tmp_path / "a.mcap", grid=grid, config=LabelConfig(), lidar_topic="/velodyne_points")
    with pytest.raises(BagError, match="exists already"):
        label_bag(src, src, grid=grid, config=LabelConfig())
    # A grid far above the road (base_height 3 m on a 1.1 m camera): no road plane in any scan.
    high = replace(grid, base_height=3.0)
    with pytest.raises(LabelError, match="no frame got a label"):
        label_bag(src, tmp_path / "b.mcap", grid=high, config=LabelConfig())
    assert not (tmp_path / "b.mcap").exists()
