"""The node's /diagnostics over real DDS: stale when the camera stops, back when it resumes; stamp
ages by the node's clock (use_sim_time switched on at run time); the other image transport named."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from typing import Any

import pytest

from roadbev_ros.diagnostics import ERROR, OK

from ._ros_harness import MS, START_NS, Harness, stub_factory, wait_for

FRAME_NS = 100 * MS


def pitch(_t: int) -> float:
    return 0.05


def feed(h: Harness, k: int) -> int:
    stamp = START_NS + k * FRAME_NS
    h.imu_around(stamp + 3 * MS, pitch)
    h.publish_frame(stamp)
    return stamp


def clock_reaches(node: Any, stamp_ns: int) -> bool:
    return wait_for(lambda: node.get_clock().now().nanoseconds >= stamp_ns)


def latest_status(h: Harness) -> Any:
    with h.lock:
        return h.diagnostics[-1].status[0] if h.diagnostics else None


def level_becomes(h: Harness, level: int, timeout: float = 10.0) -> bool:
    def reached() -> bool:
        status = latest_status(h)
        return status is not None and status.level == bytes([level])

    return wait_for(reached, timeout)


FAST = {"diagnostics_period_s": 0.1, "diagnostics.window_s": 1.0, "diagnostics.min_rate_hz": 0.0}


@pytest.fixture
def harness(ros: Any, request: pytest.FixtureRequest) -> Iterator[Harness]:
    h = Harness(ros, params={**FAST, **getattr(request, "param", {})})
    try:
        yield h
    finally:
        h.close()


@pytest.mark.parametrize("harness", [{"diagnostics.max_stamp_age_s": 0.0}], indirect=True)
def test_diagnostics_go_stale_when_input_stops_and_recover_when_it_resumes(harness: Harness) -> None:
    for k in range(5):
        harness.wait_output(feed(harness, k))
    assert level_becomes(harness, OK), latest_status(harness)
    # the camera stops: after the window (1 s) the status is stale, and its figures are gone
    assert level_becomes(harness, ERROR), latest_status(harness)
    status = latest_status(harness)
    assert status.message.startswith("stale: no left image for"), status.message
    values = {kv.key: kv.value for kv in status.values}
    assert values["input_rate_hz"] == "0.00" and values["latency_p50_ms"] == "nan"
    assert values["frames_in"] == "5" and values["outputs"] == "5"
    with harness.lock:
        checks = [s.name for s in harness.diagnostics[-1].status]
    assert checks[1:] == ["roadbev: left image rate", "roadbev: left image stamps"]
    # it comes back
    for k in range(5, 8):
        harness.wait_output(feed(harness, k))
    assert level_becomes(harness, OK), latest_status(harness)


def test_stamp_ages_use_the_node_clock_and_use_sim_time_is_settable_at_run_time(harness: Harness) -> None:
    from rclpy.parameter import Parameter
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rosgraph_msgs.msg import Clock

    node = harness.node
    harness.wait_output(feed(harness, 0))
    # the harness's stamps are from 2023: by the wall clock they are far too old
    def stamps_said_old() -> bool:
        with harness.lock:
            return any(len(m.status) > 2 and "s old on arrival" in m.status[2].message for m in harness.diagnostics)

    assert wait_for(stamps_said_old)
    result = node.set_parameters([Parameter("use_sim_time", value=True)])[0]
    assert result.successful, result.reason
    assert node.get_clock().ros_time_is_active  # type: ignore[attr-defined]
    clock_pub = harness.feeder.create_publisher(Clock, "/clock", QoSProfile(depth=10,
                                                reliability=ReliabilityPolicy.RELIABLE))
    assert wait_for(lambda: clock_pub.get_subscription_count() > 0)
    for k in range(1, 8):
        stamp = START_NS + k * FRAME_NS
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(stamp + 40 * MS, 1_000_000_000)
        clock_pub.publish(msg)  # a bag's clock, 40 ms ahead of the frame being played
        assert clock_reaches(node, stamp)
        harness.wait_output(feed(harness, k))
    assert level_becomes(harness, OK), latest_status(harness)
    values = harness.latest_diagnostics()
    assert 0.0 <= float(values["stamp_age_p50_ms"]) < 1000.0, values  # not 9.6e10
    # the bag ends: /clock stops, the diagnostics go on with the last stamp and say so
    assert wait_for(lambda: harness.latest_diagnostics()["clock"].startswith("stopped for"), 5.0)
    harness.feeder.destroy_publisher(clock_pub)


def test_the_map_and_the_preview_reference_are_reported(harness: Harness) -> None:
    from nav_msgs.msg import Odometry

    harness.wait_output(feed(harness, 0))
    assert wait_for(lambda: harness.latest_diagnostics().get("preview_reference") == "road", 5.0)
    values = harness.latest_diagnostics()
    assert values["map"] == "waiting: no odometry on /odom received yet", values
    assert values["map_frames_fused"] == "0" and values["motion_age_s"] == "never"
    odom = harness.feeder.create_publisher(Odometry, "/odom", 50)
    assert wait_for(lambda: odom.get_subscription_count() > 0)
    for k in range(1, 5):
        msg = Odometry()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(START_NS + (k + 1) * FRAME_NS, 1_000_000_000)
        msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
        msg.pose.pose.position.x, msg.pose.pose.orientation.w, msg.twist.twist.linear.x = float(k), 1.0, 10.0
        odom.publish(msg)
        harness.wait_output(feed(harness, k))

    def fusing() -> bool:
        v = harness.latest_diagnostics()
        return v.get("map") == "fusing" and int(v.get("map_frames_fused", "0")) >= 1

    assert wait_for(fusing, 5.0), harness.latest_diagnostics()
    values = harness.latest_diagnostics()
    assert values["preview_reference"].startswith("contact_plane ("), values
    assert float(values["motion_age_s"]) < 5.0


def test_the_other_transport_is_named_when_nothing_arrives(ros: Any) -> None:
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import CompressedImage

    from roadbev_ros.node import RoadBevNode

    tag = uuid.uuid4().hex[:8]
    topic = f"/hint_{tag}/image_rect"
    node = RoadBevNode(node_name=f"roadbev_{tag}", backend_factory=stub_factory(),
                       parameter_overrides={"left_image_topic": topic})
    camera = ros.create_node(f"camera_{tag}")
    try:
        camera.create_publisher(CompressedImage, topic + "/compressed", qos_profile_sensor_data)
        assert wait_for(lambda: node.count_publishers(topic + "/compressed") == 1)
        node._publish_diagnostics()  # what the timer does
        message = node.health.snapshot().message
        assert message.startswith("waiting for input") and "image_transport:=compressed" in message, message
        assert f"{topic}/compressed has a publisher" in message
    finally:
        node.shutdown()
        node.destroy_node()
        camera.destroy_node()


@pytest.mark.parametrize("harness", [{"max_image_mb": 0.005}], indirect=True)
def test_an_image_over_the_size_limit_is_refused_on_arrival_and_counted(harness: Harness) -> None:
    node = harness.node  # the harness's 64 x 48 rgb8 images are 9 KiB, over 0.005 MiB
    for k in range(3):
        feed(harness, k)
    assert wait_for(lambda: node.health.problems["image too large"] == 6), dict(node.health.problems)
    counts = node.counts()
    assert counts["frames_in"] == 3 and counts["dropped_invalid"] == 3 and counts["outputs"] == 0, counts
    assert node.sync.queued() == [0, 0, 3, 3] and node.sync.queued_bytes == 0  # only the camera infos wait
    assert "MiB is larger than the limit" in node.health.last_error
    values = harness.latest_diagnostics()
    assert wait_for(lambda: harness.latest_diagnostics().get("problem.image too large") == "6"), values


def test_the_byte_bound_must_hold_a_stereo_pair() -> None:
    from roadbev_core.config import ParamError, RoadbevConfig

    with pytest.raises(ParamError, match="sync_queue_mb = 100 must hold a stereo pair"):
        RoadbevConfig.from_params({"sync_queue_mb": 100.0, "max_image_mb": 64.0})
    assert RoadbevConfig.from_params({"sync_queue_mb": 128.0}).sync.queue_mb == 128.0
