"""The tf2 buffer without ROS (msg_bridge.tf_buffer): chains through /tf_static and /tf, time
interpolation, extrapolation refused, cache expiry, loops and unconnected trees."""

from __future__ import annotations

import math

import numpy as np
import pytest

from msg_bridge.tf import StaticTransform, TransformError, TransformTree
from msg_bridge.tf_buffer import Extrapolation, FrameNotFound, Link, NotConnected, TransformBuffer
from roadbev_core.geometry import rotation_from_rpy

S = 1_000_000_000
T0 = 1_700_000_000 * S
OPTICAL = rotation_from_rpy(-math.pi / 2, 0.0, -math.pi / 2)


def tf(parent: str, child: str, xyz: tuple[float, float, float] = (0.0, 0.0, 0.0), yaw: float = 0.0,
       rotation: np.ndarray | None = None) -> StaticTransform:
    R = rotation_from_rpy(0.0, 0.0, yaw) if rotation is None else rotation
    return StaticTransform(parent, child, R, np.array(xyz, np.float64))


def apply(Rt: tuple[np.ndarray, np.ndarray], p: np.ndarray) -> np.ndarray:
    return np.asarray(Rt[0] @ p + Rt[1])


def test_a_static_chain_joins_any_two_frames_as_the_offline_tree_does() -> None:
    chain = [tf("base_link", "camera_link", (1.6, 0.0, 1.2), rotation=rotation_from_rpy(0.0, 0.05, 0.0)),
             tf("camera_link", "left_optical", (0.0, 0.06, 0.0), rotation=OPTICAL),
             tf("base_link", "lidar", (1.0, 0.0, 1.8), yaw=0.1)]
    buffer = TransformBuffer()
    for link in chain:
        buffer.add(link, static=True)
    tree = TransformTree(chain)
    for target, source in [("base_link", "left_optical"), ("left_optical", "lidar"), ("lidar", "camera_link")]:
        R, t = buffer.lookup(target, source, T0)  # a static chain holds at every stamp
        R_tree, t_tree = tree.lookup(target, source)
        np.testing.assert_allclose(R, R_tree, atol=1e-12)
        np.testing.assert_allclose(t, t_tree, atol=1e-12)
    # with base_link as the root the numbers are the offline tree's, to the last bit
    assert all(np.array_equal(a, b) for a, b in zip(buffer.lookup("base_link", "left_optical"),
                                                    tree.lookup("base_link", "left_optical"), strict=True))
    p = np.array([0.3, -0.2, 5.0])
    there = buffer.lookup("lidar", "left_optical")
    back = buffer.lookup("left_optical", "lidar")
    np.testing.assert_allclose(apply(back, apply(there, p)), p, atol=1e-12)
    assert buffer.links("base_link", "left_optical") == [Link("camera_link", "left_optical", True),
                                                         Link("base_link", "camera_link", True)]
    assert buffer.parent("left_optical") == "camera_link" and buffer.parent("base_link") is None


def test_a_tf_link_is_interpolated_linearly_and_by_slerp_between_its_samples() -> None:
    buffer = TransformBuffer()
    buffer.add(tf("base_link", "bracket", (1.5, 0.0, 1.0)), static=True)
    buffer.add(tf("bracket", "camera", (0.0, 0.0, 0.0), yaw=0.0), T0)
    buffer.add(tf("bracket", "camera", (0.2, 0.0, 0.1), yaw=0.4), T0 + S // 10)
    R, t = buffer.lookup("base_link", "camera", T0 + S // 40)  # a quarter of the way
    np.testing.assert_allclose(t, [1.55, 0.0, 1.025], atol=1e-12)
    np.testing.assert_allclose(R, rotation_from_rpy(0.0, 0.0, 0.1), atol=1e-12)
    R, t = buffer.lookup("base_link", "camera", T0 + S // 10)  # a sample's own stamp: that sample
    np.testing.assert_allclose(t, [1.7, 0.0, 1.1], atol=1e-12)
    assert buffer.links("base_link", "camera") == [Link("bracket", "camera", False), Link("base_link", "bracket", True)]


def test_extrapolation_is_refused_beyond_the_tolerance_and_the_nearest_sample_is_held_within_it() -> None:
    buffer = TransformBuffer(tolerance_s=0.02)
    buffer.add(tf("odom", "base_link", (0.0, 0.0, 0.0)), T0)
    with pytest.raises(Extrapolation, match=r"extrapolation at time .* but only time 1700000000\.000000 is in the "
                                            r"buffer") as single:
        buffer.lookup("odom", "base_link", T0 + S)
    assert single.value.future
    buffer.add(tf("odom", "base_link", (1.0, 0.0, 0.0)), T0 + S // 10)
    # 10 ms beyond the newest: held at it, not extrapolated (which would give x = 1.1)
    np.testing.assert_allclose(buffer.lookup("odom", "base_link", T0 + S // 10 + S // 100)[1], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(buffer.lookup("odom", "base_link", T0 - S // 100)[1], [0.0, 0.0, 0.0])
    with pytest.raises(Extrapolation) as future:
        buffer.lookup("odom", "base_link", T0 + S // 2)
    assert future.value.future
    assert str(future.value) == (
        "Lookup would require extrapolation into the future. Requested time 1700000000.500000 but the latest data "
        "is at time 1700000000.100000, when looking up transform from frame [base_link] to frame [odom] (the /tf "
        "link odom -> base_link)")
    with pytest.raises(Extrapolation, match=r"into the past\. Requested time 1699999999\.900000 but the earliest "
                                            r"data is at time 1700000000\.000000") as past:
        buffer.lookup("odom", "base_link", T0 - S // 10)
    assert not past.value.future
    exact = TransformBuffer()  # tf2's own behaviour: no tolerance at all
    exact.add(tf("odom", "base_link"), T0)
    exact.add(tf("odom", "base_link"), T0 + S // 10)
    with pytest.raises(Extrapolation):
        exact.lookup("odom", "base_link", T0 + S // 10 + 1)


def test_each_links_history_reaches_back_the_cache_time_and_older_data_is_refused() -> None:
    buffer = TransformBuffer(cache_time_s=10.0)
    for k in range(13):  # 12 s of 1 Hz samples
        buffer.add(tf("odom", "base_link", (float(k), 0.0, 0.0)), T0 + k * S)
    np.testing.assert_allclose(buffer.lookup("odom", "base_link", T0 + 2 * S)[1], [2.0, 0.0, 0.0])
    with pytest.raises(Extrapolation, match=r"into the past.*earliest data is at time 1700000002\.000000"):
        buffer.lookup("odom", "base_link", T0 + S)  # expired
    with pytest.raises(TransformError, match=r"ignoring data from the past for frame base_link at time "
                                             r"1700000001\.000000"):
        buffer.add(tf("odom", "base_link", (1.0, 0.0, 0.0)), T0 + S)
    buffer.add(tf("odom", "base_link", (4.5, 0.0, 0.0)), T0 + 4 * S + S // 2)  # late, but within the cache
    np.testing.assert_allclose(buffer.lookup("odom", "base_link", T0 + 4 * S + S // 2)[1], [4.5, 0.0, 0.0])
    buffer.add(tf("odom", "base_link", (12.5, 0.0, 0.0)), T0 + 12 * S)  # the same stamp again replaces
    np.testing.assert_allclose(buffer.lookup("odom", "base_link", T0 + 12 * S)[1], [12.5, 0.0, 0.0])


def test_without_a_stamp_the_lookup_is_at_the_latest_time_every_link_has() -> None:
    buffer = TransformBuffer()
    buffer.add(tf("odom", "base_link", (0.0, 0.0, 0.0)), T0)
    buffer.add(tf("odom", "base_link", (2.0, 0.0, 0.0)), T0 + 2 * S)
    buffer.add(tf("base_link", "bracket", (0.0, 0.0, 1.0)), T0)
    buffer.add(tf("base_link", "bracket", (0.0, 0.0, 1.0)), T0 + S)  # this link lags: latest common is T0 + 1 s
    buffer.add(tf("bracket", "camera", (0.5, 0.0, 0.0)), static=True)
    np.testing.assert_allclose(buffer.lookup("odom", "camera")[1], [1.5, 0.0, 1.0])
    with pytest.raises(Extrapolation, match="the /tf link base_link -> bracket"):
        buffer.lookup("odom", "camera", T0 + 2 * S)


def test_static_and_dynamic_links_of_one_frame() -> None:
    buffer = TransformBuffer()
    buffer.add(tf("base_link", "camera", (1.0, 0.0, 1.0)), T0)
    buffer.add(tf("base_link", "camera", (1.6, 0.0, 1.1)), static=True)  # a static one replaces the history
    np.testing.assert_allclose(buffer.lookup("base_link", "camera", T0 + 100 * S)[1], [1.6, 0.0, 1.1])
    with pytest.raises(TransformError, match="camera has a /tf_static transform"):
        buffer.add(tf("base_link", "camera", (1.0, 0.0, 1.0)), T0)
    with pytest.raises(TransformError, match="its own parent"):
        buffer.add(tf("camera", "camera"), static=True)
    buffer.add(tf("odom", "base_link", (3.0, 0.0, 0.0)), T0)
    buffer.clear_dynamic()  # time jumped back: the /tf history goes, the static transforms stay
    assert buffer.frames == {"base_link", "camera"}
    np.testing.assert_allclose(buffer.lookup("base_link", "camera")[1], [1.6, 0.0, 1.1])


def test_a_frame_that_moves_to_another_parent_is_not_blended_across_the_move() -> None:
    buffer = TransformBuffer()
    buffer.add(tf("world", "a", (10.0, 0.0, 0.0)), static=True)
    buffer.add(tf("world", "b", (20.0, 0.0, 0.0)), static=True)
    buffer.add(tf("a", "tool", (1.0, 0.0, 0.0)), T0)
    buffer.add(tf("b", "tool", (2.0, 0.0, 0.0)), T0 + S)
    np.testing.assert_allclose(buffer.lookup("world", "tool", T0 + S // 2)[1], [11.0, 0.0, 0.0])
    np.testing.assert_allclose(buffer.lookup("world", "tool", T0 + S)[1], [22.0, 0.0, 0.0])
    assert buffer.parent("tool", T0 + S // 2) == "a" and buffer.parent("tool") == "b"


def test_unknown_frames_unconnected_trees_and_loops_are_named() -> None:
    buffer = TransformBuffer()
    buffer.add(tf("base_link", "camera"), static=True)
    buffer.add(tf("odom", "base_footprint"), T0)
    with pytest.raises(FrameNotFound, match='"radar" passed to lookupTransform argument source_frame does not exist'):
        buffer.lookup("base_link", "radar", T0)
    with pytest.raises(NotConnected, match="Could not find a connection between 'odom' and 'camera' because they "
                                           "are not part of the same tree"):
        buffer.lookup("odom", "camera", T0)
    with pytest.raises(NotConnected):
        buffer.links("odom", "camera")
    buffer.add(tf("camera", "base_link"), static=True)  # base_link -> camera -> base_link
    with pytest.raises(NotConnected, match=r"contains a loop: (base_link -> camera -> base_link|camera -> "
                                           r"base_link -> camera)"):
        buffer.lookup("base_link", "camera", T0)
    np.testing.assert_array_equal(buffer.lookup("radar", "/radar")[0], np.eye(3))  # a frame to itself: identity
