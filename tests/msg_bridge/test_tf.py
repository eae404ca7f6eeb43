"""TF and Odometry conversions and the static transform tree (msg_bridge.tf)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from msg_bridge import bag_factory
from msg_bridge._common import MessageError
from msg_bridge.bag import deserialize, serialize
from msg_bridge.point_cloud import array_point_cloud, point_cloud_xyz
from msg_bridge.tf import (
    StaticTransform,
    TransformError,
    TransformTree,
    camera_mount,
    odometry_message,
    odometry_pose,
    odometry_tf,
    stamped_transforms_from_tf,
    tf_message,
    transforms_from_tf,
)
from roadbev_core.attitude import quaternion_from_rotation
from roadbev_core.geometry import rotation_from_rpy


def test_tree_chains_through_the_common_parent() -> None:
    R_cam = rotation_from_rpy(-math.pi / 2, 0.0, -math.pi / 2)
    R_lidar = rotation_from_rpy(0.0, 0.05, 0.1)
    tree = TransformTree(
        [
            StaticTransform("base_link", "camera", R_cam, np.array([1.6, 0.1, 1.1])),
            StaticTransform("base_link", "lidar", R_lidar, np.array([1.0, 0.0, 1.8])),
        ]
    )
    R, t = tree.lookup("camera", "lidar")
    p_lidar = np.array([5.0, -1.0, -1.5])
    p_base = R_lidar @ p_lidar + np.array([1.0, 0.0, 1.8])
    expected = R_cam.T @ (p_base - np.array([1.6, 0.1, 1.1]))
    np.testing.assert_allclose(R @ p_lidar + t, expected, atol=1e-12)
    with pytest.raises(TransformError, match="no transform from 'radar'"):
        tree.lookup("camera", "radar")


def test_tf_and_odometry_messages_round_trip_through_cdr() -> None:
    factory = bag_factory()
    tf = StaticTransform("a", "b", rotation_from_rpy(0.1, -0.2, 0.3), np.array([1.0, 2.0, 3.0]))
    msg = deserialize(serialize(tf_message([tf], factory, stamp_ns=5)), "tf2_msgs/msg/TFMessage")
    (back,) = transforms_from_tf(msg)
    assert (back.parent, back.child) == ("a", "b")
    np.testing.assert_allclose(back.rotation, tf.rotation, atol=1e-9)
    odom = odometry_message(factory, stamp_ns=7, position=(3.0, -1.0, 0.0),
                            orientation_xyzw=(0.0, 0.0, math.sin(1.25), math.cos(1.25)))
    pose = odometry_pose(deserialize(serialize(odom), "nav_msgs/msg/Odometry"))
    assert (pose.stamp_ns, pose.x, pose.y, pose.frame_id, pose.child_frame_id) == (7, 3.0, -1.0, "odom", "base_link")
    assert pose.yaw == pytest.approx(2.5)


def test_tf_transforms_come_with_their_stamps_for_the_buffer() -> None:
    factory = bag_factory()
    tfs = [StaticTransform("odom", "base_link", rotation_from_rpy(0.0, 0.0, 0.3), np.array([1.0, 2.0, 0.0])),
           StaticTransform("/base_link", "bracket", np.eye(3), np.zeros(3))]
    msg = deserialize(serialize(tf_message(tfs, factory, stamp_ns=1_500_000_007)), "tf2_msgs/msg/TFMessage")
    (s0, first), (s1, second) = stamped_transforms_from_tf(msg)
    assert s0 == s1 == 1_500_000_007 and (second.parent, second.child) == ("base_link", "bracket")
    np.testing.assert_allclose(first.rotation, tfs[0].rotation, atol=1e-9)
    msg.transforms[1].header.stamp.nanosec = 2_000_000_000
    with pytest.raises(MessageError, match="nanosec"):
        stamped_transforms_from_tf(msg)
    assert len(transforms_from_tf(msg)) == 2  # /tf_static's transforms are read without their stamps


def test_point_cloud_xyz_reads_clouds_with_other_fields() -> None:
    factory = bag_factory()
    pts = np.array([[1.0, 2.0, 3.0, 9.0], [0.0, np.nan, 0.0, 1.0], [4.0, 5.0, 6.0, 2.0]])
    msg = array_point_cloud(pts, ("intensity", "x", "y", "z"), factory, stamp_ns=0, frame_id="l")
    # fields in another order; the NaN row is dropped
    np.testing.assert_allclose(point_cloud_xyz(msg), [[2.0, 3.0, 9.0], [5.0, 6.0, 2.0]])
    no_z = array_point_cloud(pts[:, :2], ("x", "y"), factory, stamp_ns=0, frame_id="l")
    with pytest.raises(ValueError, match="no z field"):
        point_cloud_xyz(no_z)


def test_the_camera_mount_is_joined_through_a_chain_of_frames() -> None:
    optical = rotation_from_rpy(-math.pi / 2, 0.0, -math.pi / 2)  # optical axes in camera_link's
    tilt = rotation_from_rpy(0.0, 0.08, 0.0)  # camera_link pitched down on its bracket
    chain = [StaticTransform("base_link", "camera_link", tilt, np.array([1.6, 0.0, 1.1])),
             StaticTransform("camera_link", "stereo_left_optical_frame", optical, np.array([0.0, 0.06, 0.0]))]
    mount = camera_mount(chain, "base_link", "stereo_left_optical_frame")
    assert mount is not None
    translation, rotation = mount
    assert translation == pytest.approx(np.array([1.6, 0.0, 1.1]) + tilt @ np.array([0.0, 0.06, 0.0]))
    assert rotation == pytest.approx(tilt @ optical)
    direct = camera_mount([StaticTransform("base_link", "stereo_left_optical_frame", tilt @ optical,
                                           translation)], "base_link", "stereo_left_optical_frame")
    assert direct is not None and direct[0] == pytest.approx(translation) and direct[1] == pytest.approx(rotation)
    # a later transform to the same child replaces the earlier one, as on /tf_static
    moved = [*chain, StaticTransform("base_link", "camera_link", tilt, np.array([1.7, 0.0, 1.1]))]
    later = camera_mount(moved, "base_link", "stereo_left_optical_frame")
    assert later is not None and later[0][0] == pytest.approx(translation[0] + 0.1)
    assert camera_mount(chain[1:], "base_link", "stereo_left_optical_frame") is None  # not joined
    loop = [StaticTransform("a", "b", np.eye(3), np.zeros(3)), StaticTransform("b", "a", np.eye(3), np.zeros(3))]
    assert camera_mount(loop, "base_link", "a") is None


def test_odometry_becomes_its_tf_in_three_dimensions() -> None:
    factory = bag_factory()
    attitude = rotation_from_rpy(0.02, -0.03, 1.1)
    odom = odometry_message(factory, stamp_ns=9, position=(3.0, -1.0, 0.2),
                            orientation_xyzw=quaternion_from_rotation(attitude))
    msg = deserialize(serialize(odometry_tf(odom, factory)), "tf2_msgs/msg/TFMessage")
    (tf,) = transforms_from_tf(msg)
    assert (tf.parent, tf.child) == ("odom", "base_link")
    assert msg.transforms[0].header.stamp.nanosec == 9
    np.testing.assert_allclose(tf.translation, [3.0, -1.0, 0.2])
    np.testing.assert_allclose(tf.rotation, attitude, atol=1e-9)
    odom.child_frame_id = ""
    with pytest.raises(MessageError, match="child_frame_id"):
        odometry_tf(odom, factory)
