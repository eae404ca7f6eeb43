"""Drive bags: the extra topics are written in time order and read back as the drive's truth."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from msg_bridge.bag import BagError, BagWriter, bag_topics, read_messages, typestore
from roadbev_core.config import RoadbevConfig, StereoCamera, TopicsConfig
from roadbev_core.preview import wheel_track_profiles
from roadbev_lab.evaluation.arrival import REFERENCE_ROAD, TimedPreview
from roadbev_lab.evaluation.drivebag import (
    GROUND_TRUTH_ODOM_TOPIC,
    ROAD_MAP_TOPIC,
    evaluate_drive_previews,
    is_drive_bag,
    read_drive_truth,
    write_drive_bag,
)
from roadbev_lab.evaluation.evalbag import LEFT_FRAME, TF_STATIC_TOPIC, read_eval_bag
from roadbev_lab.synth import DriveConfig, RidingConfig, RidingDrive, RoadConfig


@pytest.fixture(scope="module")
def drive() -> RidingDrive:
    road = RoadConfig(features=("speed_bump",), feature_spacing_m=3.0)
    cfg = DriveConfig(frames=2, speed_mps=6.0, seed=21, camera=StereoCamera.rsrd_half().scaled(0.25), road=road)
    return RidingDrive(RidingConfig(drive=cfg, tail_s=0.5, road_map_resolution_m=0.04))


@pytest.fixture(scope="module")
def bag(drive: RidingDrive, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("drive") / "drive.mcap"
    write_drive_bag(path, drive)
    return path


def test_topics_types_counts_and_time_order(drive: RidingDrive, bag: Path) -> None:
    topics = bag_topics(bag)
    odom_topic = TopicsConfig().odom  # the node's default
    assert topics[odom_topic].msgtype == "nav_msgs/msg/Odometry"
    assert topics[GROUND_TRUTH_ODOM_TOPIC].count == len(drive.imu_samples())
    assert topics[odom_topic].count == drive.odometry().stamp_ns.size
    assert topics[TF_STATIC_TOPIC].msgtype == "tf2_msgs/msg/TFMessage"
    assert topics[TF_STATIC_TOPIC].count == 1
    assert topics[ROAD_MAP_TOPIC].count == 1
    assert topics["/ground_truth/elevation"].count == 2
    assert is_drive_bag(bag)
    items = list(read_messages(bag, [odom_topic, GROUND_TRUTH_ODOM_TOPIC, TF_STATIC_TOPIC, ROAD_MAP_TOPIC]))
    assert items[0].topic in (TF_STATIC_TOPIC, ROAD_MAP_TOPIC)
    odom = [i.msg for i in items if i.topic == odom_topic]
    assert odom[0].header.frame_id == "odom" and odom[0].child_frame_id == "base_link"
    tf = next(i.msg for i in items if i.topic == TF_STATIC_TOPIC).transforms[0]
    assert (tf.header.frame_id, tf.child_frame_id) == ("base_link", LEFT_FRAME)
    assert tf.transform.translation.z == pytest.approx(1.10)


def test_truth_reads_back_exactly(drive: RidingDrive, bag: Path) -> None:
    truth = read_drive_truth(bag)
    gt = drive.ground_truth_poses()
    np.testing.assert_array_equal(truth.trajectory.stamp_ns, gt.stamp_ns)
    np.testing.assert_allclose(truth.trajectory.position, gt.position, atol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(truth.trajectory.orientation_xyzw * gt.orientation_xyzw, 1)), 1.0,
                               atol=1e-12)
    road = drive.road_map()
    np.testing.assert_array_equal(truth.road_map.elevation, road.elevation)
    assert truth.road_map.centre == pytest.approx(road.centre) and truth.road_map.resolution == road.resolution
    assert truth.camera_in_base is not None
    np.testing.assert_allclose(truth.camera_in_base[1], drive.base_to_camera[1], atol=1e-9)
    assert truth.notes == []
    assert len(read_eval_bag(bag)) == 2  # still an evaluation bag
    # the vehicle's own odometry, the frame the node keeps its map in
    odometry = drive.odometry()
    assert truth.odometry is not None
    np.testing.assert_array_equal(truth.odometry.stamp_ns, odometry.stamp_ns)
    np.testing.assert_allclose(truth.odometry.position, odometry.position, atol=1e-9)
    assert read_drive_truth(bag, odom_topic="/no_such_odom").odometry is None


def test_writing_is_deterministic(drive: RidingDrive, bag: Path, tmp_path: Path) -> None:
    again = tmp_path / "drive.mcap"
    write_drive_bag(again, drive)  # (the drive itself is a function of its seed: tests/roadbev_core)
    assert hashlib.sha256(again.read_bytes()).digest() == hashlib.sha256(bag.read_bytes()).digest()


def test_evaluate_drive_previews_on_the_bags_own_truth(drive: RidingDrive, bag: Path) -> None:
    samples = list(read_eval_bag(bag))
    grid = read_eval_bag(bag).grid
    truths = [s.truth for s in samples]
    assert all(t is not None for t in truths)
    previews = [TimedPreview(s.inputs.stamp_ns, REFERENCE_ROAD, wheel_track_profiles(t, None, grid))
                for s, t in zip(samples, truths, strict=True) if t is not None]
    stamps = [s.inputs.stamp_ns for s in samples]
    out = evaluate_drive_previews(bag, previews, stamps, RoadbevConfig.from_params(grid.to_dict()))
    # the labels themselves, read at arrival: millimetres; coverage misses the start (the first window
    # begins 0.96 m ahead of the wheel, arrivals 0.6 m ahead) and the cells hidden from the camera
    assert 60.0 < out["coverage_pct"] < 100.0 and out["abs_err_cm"] < 0.3  # 3 cm cells, S-curves


def test_bags_without_truth_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "empty.mcap"
    with BagWriter(path) as writer:
        writer.add_topic(GROUND_TRUTH_ODOM_TOPIC, "nav_msgs/msg/Odometry")
        writer.write(GROUND_TRUTH_ODOM_TOPIC, _odom(), 1)
    assert not is_drive_bag(path)
    with pytest.raises(BagError, match="usable pose"):
        read_drive_truth(path)


def _odom() -> object:
    from msg_bridge._common import TypestoreFactory
    from msg_bridge.tf import odometry_message

    return odometry_message(TypestoreFactory(typestore()), stamp_ns=1, position=np.zeros(3),
                            orientation_xyzw=np.array([0.0, 0.0, 0.0, 1.0]), linear_velocity=np.zeros(3),
                            angular_velocity=np.zeros(3))
