"""The reference preview controller node in-process over real DDS: previews in, forces and diagnostics out."""

from __future__ import annotations

import uuid
from typing import Any

import numpy as np
import pytest

from msg_bridge import RclpyFactory
from msg_bridge.preview import road_preview_message
from roadbev_core.preview import PreviewProfiles, TrackProfile
from roadbev_core.ride import RideError

from ._ros_harness import Spinning, wait_for


def _bump_profiles(speed: float | None) -> PreviewProfiles:
    """Per-frame style profiles (x ahead of the camera from 2.16 m): a 4 cm bump 4-4.3 m ahead."""
    x = 2.175 + 0.03 * np.arange(164)
    elevation = np.where((x > 4.0) & (x < 4.3), 0.04, 0.0).astype(np.float32)
    tracks = tuple(TrackProfile(name, y, 0.2, elevation, np.full_like(elevation, 0.005))
                   for name, y in (("left", 0.8), ("right", -0.8)))
    return PreviewProfiles(2.175, 0.03, tracks, vehicle_speed=speed)


def test_node_commands_forces_from_previews(ros: Any) -> None:
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import WrenchStamped
    from roadbev_msgs.msg import RoadPreview

    from roadbev_ros.preview_controller import PreviewControllerNode

    tag = uuid.uuid4().hex[:8]
    preview_topic, force_topic = f"/t{tag}/preview", f"/t{tag}/force"
    node = PreviewControllerNode(node_name=f"ctl_{tag}", parameter_overrides={
        "preview_topic": preview_topic, "force_topic": force_topic, "control_rate_hz": 100.0,
        "diagnostics_period_s": 0.2})
    with Spinning(ros, node) as spun:
        pub = spun.publisher(RoadPreview, preview_topic)
        forces = spun.collect(WrenchStamped, force_topic)
        diagnostics = spun.collect(DiagnosticArray, "/diagnostics")
        lock = spun.lock
        assert spun.connected(pub)
        assert wait_for(lambda: len(forces) >= 4, 5.0)
        with lock:
            idle = [f.wrench.force.z for f in forces]
        assert idle and max(abs(v) for v in idle) < 1e-6  # nothing held: the model rests, no force
        factory = RclpyFactory()
        now = node.get_clock().now().nanoseconds
        pub.publish(road_preview_message(_bump_profiles(None), factory, stamp_ns=now))  # no speed: refused
        pub.publish(road_preview_message(_bump_profiles(10.0), factory, stamp_ns=now))
        assert wait_for(lambda: node.counts["received"] == 1 and node.counts["refused"] == 1, 5.0)

        def strong() -> bool:
            with lock:
                wheels = {f.header.frame_id for f in forces if abs(f.wrench.force.z) > 20.0}
            return wheels == {"front_left", "front_right"}

        assert wait_for(strong, 5.0), "no force ahead of the previewed bump"

        def reported() -> bool:
            with lock:
                return any(s.name == "roadbev: preview controller" and
                           {kv.key: kv.value for kv in s.values}.get("refused") == "1"
                           for d in diagnostics for s in d.status)

        assert wait_for(reported, 5.0)
        assert "vehicle_speed" in node.last_refusal


def test_node_refuses_bad_parameters(ros: Any) -> None:
    from roadbev_ros.preview_controller import PreviewControllerNode

    with pytest.raises(RideError, match="control_rate_hz"):
        PreviewControllerNode(node_name=f"ctl_{uuid.uuid4().hex[:8]}", parameter_overrides={"control_rate_hz": 5.0})


def test_plane_slope_of_a_message() -> None:
    from types import SimpleNamespace

    from roadbev_ros.preview_controller import plane_slope_x

    assert plane_slope_x(SimpleNamespace(reference="road", contact_plane_pitch=0.1)) == 0.0
    assert plane_slope_x(SimpleNamespace()) == 0.0  # an older RoadPreview without the fields
    # nose-down pitch: the plane falls ahead (z = height - x tan(pitch))
    assert plane_slope_x(SimpleNamespace(reference="contact_plane", contact_plane_pitch=0.02)) == pytest.approx(
        -np.tan(0.02))
