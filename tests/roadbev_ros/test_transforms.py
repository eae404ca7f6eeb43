"""The node's transforms without ROS: /tf_static and /tf into the buffer, bad transforms named,
the node's own TF left out, and the odometry taken from /tf (odom_from_tf)."""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import numpy as np
import pytest

from msg_bridge import bag_factory
from msg_bridge.tf import StaticTransform, tf_message
from roadbev_core.config import ParamError, RoadbevConfig
from roadbev_core.ego_motion import PlanarPose
from roadbev_core.geometry import rotation_from_rpy
from roadbev_ros.transforms import MAX_PENDING_STAMPS, NodeTransforms, planar_pose

S = 1_000_000_000
MS = 1_000_000
T0 = 1_700_000_000 * S
FACTORY = bag_factory()


class Taker:
    def __init__(self) -> None:
        self.mounts: list[np.ndarray] = []

    def set_camera_mount(self, position: Iterable[float], R_base_optical: np.ndarray) -> None:
        self.mounts.append(np.asarray(list(position)))


class Node:
    """What NodeTransforms is given by the node."""

    def __init__(self, **params: Any) -> None:
        self.config = RoadbevConfig.from_params(params)
        self.taker = Taker()
        self.poses: list[PlanarPose] = []
        self.problems: list[tuple[str, str]] = []
        self.tf = NodeTransforms(self.taker, lambda: self.config, lambda line: None,
                                 lambda kind, reason: self.problems.append((kind, reason)), self.poses.append)


def msg(*transforms: StaticTransform, stamp_ns: int = 0) -> Any:
    return tf_message(transforms, FACTORY, stamp_ns=stamp_ns)


def odom(x: float, yaw: float = 0.0, parent: str = "odom", child: str = "base_link") -> StaticTransform:
    return StaticTransform(parent, child, rotation_from_rpy(0.0, 0.0, yaw), np.array([x, 0.0, 0.0]))


def test_odom_from_tf_needs_odom_topic_empty() -> None:
    with pytest.raises(ParamError, match="odom_from_tf takes the odometry from /tf instead of odom_topic"):
        RoadbevConfig.from_params({"odom_from_tf": True})
    config = RoadbevConfig.from_params({"odom_from_tf": True, "odom_topic": ""})
    assert config.topics.odom_from_tf and config.topics.tf_cache_time_s == 10.0
    assert Node().tf.odometry is None  # off by default


def test_bad_transforms_are_named_and_the_nodes_own_tf_is_left_out() -> None:
    node = Node()
    bad = msg(odom(0.0))
    bad.transforms[0].transform.rotation.w = 0.0  # not a rotation
    node.tf.on_static(bad)
    assert node.problems[-1][0] == "bad tf" and "not unit length" in node.problems[-1][1]
    node.tf.on_tf(msg(odom(0.0), stamp_ns=T0 + 20 * S))
    node.tf.on_tf(msg(odom(0.0), odom(1.0, child="base_footprint"), stamp_ns=T0))  # 20 s older than the cache
    assert node.problems[-1] == ("bad tf", "ignoring data from the past for frame base_link at time "
                                 "1700000000.000000: older than its newest, 1700000020.000000, by more than the cache "
                                 "time (10 s)")
    node.tf.on_tf(msg(StaticTransform("left", "roadbev_road", np.eye(3), np.zeros(3)), stamp_ns=T0))
    assert node.tf.buffer.frames == {"odom", "base_link", "base_footprint"}  # no roadbev_road
    node.tf.time_jumped()
    assert node.tf.buffer.frames == set()


def test_planar_pose_gives_the_speed_along_the_heading_and_the_yaw_rate() -> None:
    first = planar_pose(T0, rotation_from_rpy(0.0, 0.0, math.pi - 0.05), np.array([0.0, 0.0, 0.0]))
    assert (first.speed, first.yaw_rate) == (0.0, 0.0)
    R = rotation_from_rpy(0.0, 0.0, -math.pi + 0.05)  # across +-pi: a turn of 0.1 rad, not -2 pi + 0.1
    second = planar_pose(T0 + S // 10, R, np.array([-1.0, 0.0, 0.3]), first)
    assert second.yaw_rate == pytest.approx(1.0) and second.speed == pytest.approx(10.0)
    assert (second.x, second.y) == (-1.0, 0.0) and second.yaw == pytest.approx(-math.pi + 0.05)
    backwards = planar_pose(T0 + S // 5, R, np.array([0.0, 0.0, 0.0]), second)
    assert backwards.speed == pytest.approx(-10.0 * math.cos(0.05))  # reversing (the heading is 0.05 rad off x)


def test_the_odometry_comes_from_tf_through_a_chain_once_every_link_has_data() -> None:
    node = Node(odom_from_tf=True, odom_topic="")
    node.tf.on_static(msg(StaticTransform("base_footprint", "base_link", np.eye(3), np.array([0.0, 0.0, 0.3]))))
    node.tf.see_frame("left", T0)  # no odometry yet: named, with tf2's reason
    assert node.problems[-1][0] == "tf missing"
    assert node.problems[-1][1].startswith("no odometry odom -> base_link from /tf within 0.2 s of the frame at "
                                           "1700000000.000 s (odom_from_tf): \"odom\" passed to lookupTransform "
                                           "argument target_frame does not exist")
    for k in range(3):  # 10 m/s, 50 Hz
        node.tf.on_tf(msg(odom(0.2 * k, child="base_footprint"), stamp_ns=T0 + k * 20 * MS))
    assert [p.stamp_ns for p in node.poses] == [T0, T0 + 20 * MS, T0 + 40 * MS]
    assert node.poses[-1].x == pytest.approx(0.4) and node.poses[-1].speed == pytest.approx(10.0)
    problems = len(node.problems)
    node.tf.see_frame("left", T0 + 100 * MS)  # the newest sample is 60 ms older: within map.odom_max_age_s
    assert len(node.problems) == problems
    node.tf.see_frame("left", T0 + S)
    assert "within 0.2 s of the frame at 1700000001.000 s" in node.problems[-1][1]
    assert "Lookup would require extrapolation into the future" in node.problems[-1][1]
    assert node.problems[-1][1].endswith("its preview comes from the frame alone")
    node.tf.on_tf(msg(odom(0.2, child="base_footprint"), stamp_ns=T0 + 20 * MS))  # an older stamp: no sample
    assert len(node.poses) == 3


def test_odometry_stamps_wait_for_the_other_links_on_the_way() -> None:
    node = Node(odom_from_tf=True, odom_topic="", tf_tolerance_s=0.0)
    node.tf.on_tf(msg(odom(0.0, child="base_footprint"), stamp_ns=T0))
    node.tf.on_tf(msg(StaticTransform("base_footprint", "base_link", np.eye(3), np.zeros(3)), stamp_ns=T0))
    assert [p.stamp_ns for p in node.poses] == [T0]
    for k in (1, 2):  # the odom link runs ahead of the suspension link
        node.tf.on_tf(msg(odom(0.1 * k, child="base_footprint"), stamp_ns=T0 + k * 10 * MS))
    assert len(node.poses) == 1
    node.tf.on_tf(msg(StaticTransform("base_footprint", "base_link", np.eye(3), np.zeros(3)), stamp_ns=T0 + 20 * MS))
    assert [p.stamp_ns for p in node.poses] == [T0, T0 + 10 * MS, T0 + 20 * MS]
    assert node.poses[-1].x == pytest.approx(0.2)
    for k in range(MAX_PENDING_STAMPS + 10):  # the other link stopped: the pending stamps stay bounded
        node.tf.on_tf(msg(odom(0.3, child="base_footprint"), stamp_ns=T0 + (30 + k) * MS))
    assert node.tf.odometry is not None and len(node.tf.odometry._pending) == MAX_PENDING_STAMPS
    node.tf.time_jumped()
    assert node.tf.odometry.newest is None and node.tf.odometry._pending == []
