"""The reference hazard monitor in-process over real DDS: fused maps and odometry in, tracked
hazards, the severity cost, the viewers' markers and diagnostics out."""

from __future__ import annotations

import math
import uuid
from typing import Any

import numpy as np
import pytest

from msg_bridge import RclpyFactory
from msg_bridge.grid_map import fused_map_message
from msg_bridge.hazards import cost_from_occupancy_grid, hazards_from_message
from msg_bridge.tf import odometry_message
from roadbev_core.errors import RoadbevError

from ..msg_bridge.test_hazards import NOT_BUILT, rclpy_hazard_messages_built
from ..roadbev_core.test_hazard_tracking import _window
from ._ros_harness import Spinning, wait_for

pytestmark = pytest.mark.skipif(not rclpy_hazard_messages_built(), reason=NOT_BUILT)
SPEED = 10.0


def test_node_reports_a_bump_ahead_with_its_distance_and_cost(ros: Any) -> None:
    from diagnostic_msgs.msg import DiagnosticArray
    from grid_map_msgs.msg import GridMap
    from nav_msgs.msg import OccupancyGrid, Odometry
    from roadbev_msgs.msg import RoadHazardArray
    from visualization_msgs.msg import MarkerArray

    from roadbev_ros.hazard_monitor import HazardMonitorNode

    tag = uuid.uuid4().hex[:8]
    topics = {"map_topic": f"/t{tag}/map", "odom_topic": f"/t{tag}/odom", "hazards_topic": f"/t{tag}/hazards",
              "cost_topic": f"/t{tag}/cost", "markers_topic": f"/t{tag}/markers"}
    node = HazardMonitorNode(node_name=f"haz_{tag}", parameter_overrides={**topics, "diagnostics_period_s": 0.2})
    factory = RclpyFactory()
    with Spinning(ros, node) as spun:
        map_pub = spun.publisher(GridMap, topics["map_topic"])
        odom_pub = spun.publisher(Odometry, topics["odom_topic"])
        hazards = spun.collect(RoadHazardArray, topics["hazards_topic"])
        costs = spun.collect(OccupancyGrid, topics["cost_topic"])
        markers = spun.collect(MarkerArray, topics["markers_topic"])
        diagnostics = spun.collect(DiagnosticArray, "/diagnostics")
        lock = spun.lock
        assert spun.connected(map_pub, odom_pub)
        assert wait_for(lambda: node.count_subscribers(topics["markers_topic"]) > 0, 15.0)
        bad = fused_map_message(_window(10.0, 500_000_000), factory, frame_id="odom")
        bad.layers = ["elevation"]  # not a fused map: refused and counted
        bad.data = bad.data[:1]
        map_pub.publish(bad)
        assert wait_for(lambda: node.counts["refused"] == 1, 5.0)
        frames = 6  # base_link from 12 m to 17 m: the bump at 20 m is 8 m ahead, then 3 m
        for k in range(frames + 1):  # odometry a little beyond the last map (the pose is interpolated)
            stamp = 1_000_000_000 + k * 100_000_000
            odom_pub.publish(odometry_message(factory, stamp_ns=stamp, position=(12.0 + k, 0.0, 0.0),
                                              orientation_xyzw=(0.0, 0.0, 0.0, 1.0),
                                              linear_velocity=(SPEED, 0.0, 0.0)))
        assert wait_for(lambda: len(node.ego) == frames + 1, 5.0)
        for k in range(frames):
            stamp = 1_000_000_000 + k * 100_000_000
            map_pub.publish(fused_map_message(_window(12.0 + k, stamp), factory, frame_id="odom"))
        assert wait_for(lambda: len(hazards) == frames and len(costs) == frames and len(markers) == frames, 10.0)
        with lock:
            last = hazards_from_message(hazards[-1])
            cost, res, centre = cost_from_occupancy_grid(costs[-1])
            shown = list(markers[-1].markers)
        assert last.frame_id == "odom" and last.stamp_ns == 1_000_000_000 + (frames - 1) * 100_000_000
        assert last.vehicle_speed == pytest.approx(SPEED)
        [bump] = [h for h in last.hazards if h.kind == "bump"]
        assert bump.x == pytest.approx(20.0, abs=0.05) and bump.height_m == pytest.approx(0.05, rel=0.15)
        # base_link at 17 m: the front axle at 19.8 m, the bump's near edge at ~19.78 m
        assert bump.distance_ahead_m == pytest.approx(-0.02, abs=0.1)
        assert bump.first_reported_distance_m > 3.0  # reported at the second map, 4 m earlier
        assert math.isfinite(bump.time_to_arrival_s)
        # the viewers' markers: the bump as a box and a label, in the map's frame
        [box] = [m for m in shown if m.ns == "hazards" and m.id == bump.id]
        [label] = [m for m in shown if m.ns == "hazard_labels" and m.id == bump.id]
        assert box.header.frame_id == "odom" and box.pose.position.x == pytest.approx(bump.x, abs=1e-6)
        assert box.scale.z == pytest.approx(abs(bump.height_m), rel=1e-5)
        assert label.text.startswith("bump +") and f"confidence {bump.confidence:.2f}" in label.text
        assert [r.name for r in last.roughness] == ["front_left", "front_right"]
        window = _window(17.0, 0)
        assert cost.shape == window.elevation.shape and res == pytest.approx(0.03)
        assert centre == pytest.approx(window.centre, abs=1e-5)  # float32 origin
        xs, _ = window.cell_centres()
        assert cost[np.argmin(np.abs(xs - 20.0))].min() >= 45  # the 5 cm crest: half the full cost

        def reported() -> bool:
            with lock:
                return any(s.name == "roadbev: hazard monitor" and
                           {kv.key: kv.value for kv in s.values}.get("refused") == "1"
                           for d in diagnostics for s in d.status)

        assert wait_for(reported, 5.0)
        assert "not a fused map" in node.last_refusal


def test_node_refuses_bad_parameters(ros: Any) -> None:
    from roadbev_ros.hazard_monitor import HazardMonitorNode

    with pytest.raises(RoadbevError, match="confirm_hits"):
        HazardMonitorNode(node_name=f"haz_{uuid.uuid4().hex[:8]}", parameter_overrides={"confirm_hits": 0})
