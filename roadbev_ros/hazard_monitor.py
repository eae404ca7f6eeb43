"""A reference road-hazard monitor: the fused map in, tracked hazards and a planner's cost out.

The worked example of consuming ``/roadbev/map`` for planning (docs/tutorials/hazards.md, "Plan
with hazards"), in the manner of ros2/examples: a small node around the ROS-free
:class:`roadbev_core.hazard_tracking.HazardTracker`.

* **In**: the fused map (``grid_map_msgs/GridMap`` on ``map_topic``, layers ``elevation`` and
  ``uncertainty`` in ``odom``, ``/roadbev/map`` of docs/interface/topics.md) and, when ``odom_topic`` is not empty,
  the vehicle's ``nav_msgs/Odometry`` (``base_link`` in ``odom``): the pose at each map's stamp
  places the front axle (distances and times to arrival) and the wheel tracks (roughness).
  Without odometry the hazards are still tracked, with NaN distances and no roughness.
* **Out**: ``roadbev_msgs/RoadHazardArray`` on ``hazards_topic`` (the reported hazards, nearest
  first, and the ISO 8608 roughness along each front wheel track) and ``nav_msgs/OccupancyGrid``
  on ``cost_topic`` (severity 0..100 of every map cell: |height above the road's level| /
  ``full_cost_height_m``, -1 unknown), both stamped and framed like the map, one per map;
  ``visualization_msgs/MarkerArray`` on ``markers_topic`` for viewers (a box and a label per
  reported hazard, :func:`msg_bridge.markers.hazard_markers`), built only while subscribed;
  ``diagnostic_msgs/DiagnosticArray`` on ``/diagnostics`` (status "roadbev: hazard monitor").
* Bad input (a GridMap that is not a fused map, a map older than the last) is refused, counted
  and reported, never a crash; a map more than 1 s older than the last (a bag restarted) resets
  the tracker.

Run: ``python -m roadbev_ros.hazard_monitor --ros-args -p odom_topic:=/odom``.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping, Sequence
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from grid_map_msgs.msg import GridMap
from nav_msgs.msg import OccupancyGrid, Odometry
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from roadbev_msgs.msg import RoadHazardArray
from visualization_msgs.msg import MarkerArray

from msg_bridge import MessageError, RclpyFactory
from msg_bridge.grid_map import map_window_from_message
from msg_bridge.hazards import occupancy_grid_message, road_hazards_message
from msg_bridge.markers import hazard_markers
from msg_bridge.pipeline_io import odometry_sample
from roadbev_core.config import VehicleConfig
from roadbev_core.ego_motion import EgoMotion, EgoMotionError, EgoMotionStale
from roadbev_core.errors import RoadbevError
from roadbev_core.hazard_tracking import HazardTracker, TrackerError, TrackerSettings
from roadbev_core.hazards import HazardSettings
from roadbev_ros.dds import node_usage, run_node
from roadbev_ros.node_params import declare_typed

__all__ = ["DEFAULTS", "HazardMonitorNode", "main"]

TIME_JUMP_BACK_S = 1.0
QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
DEFAULTS: dict[str, Any] = {
    "map_topic": "/roadbev/map",
    "odom_topic": "/odom",
    "hazards_topic": "/roadbev/hazards",
    "cost_topic": "/roadbev/hazard_cost",
    "markers_topic": "/roadbev/hazard_markers",
    "min_height_m": HazardSettings.min_height_m,
    "min_significance": HazardSettings.min_significance,
    "confirm_hits": 2,
    "max_misses": 2,
    "gate_m": 0.5,
    "full_cost_height_m": 0.10,
    "odom_max_age_s": 0.2,
    "diagnostics_period_s": 1.0,
    "vehicle.wheelbase_m": 2.80,
    "vehicle.track_width_m": 1.60,
}


class HazardMonitorNode(Node):
    """The reference hazard monitor node (see the module docstring).

    Args:
        node_name: ROS node name.
        parameter_overrides: initial parameter values, for in-process use.

    Raises:
        RoadbevError: parameters out of range (a TrackerError, HazardError or ParamError saying which).
    """

    def __init__(self, *, node_name: str = "roadbev_hazard_monitor",
                 parameter_overrides: Mapping[str, Any] | None = None) -> None:
        overrides = [Parameter(k, value=v) for k, v in (parameter_overrides or {}).items()]
        super().__init__(node_name, parameter_overrides=overrides)
        p = {name: declare_typed(self, name, value) for name, value in DEFAULTS.items()}
        vehicle = VehicleConfig(wheelbase_m=float(p["vehicle.wheelbase_m"]),
                                track_width_m=float(p["vehicle.track_width_m"]))
        self.tracker = HazardTracker(TrackerSettings(
            detector=HazardSettings(min_height_m=float(p["min_height_m"]),
                                    min_significance=float(p["min_significance"])), gate_m=float(p["gate_m"]),
            confirm_hits=int(p["confirm_hits"]), max_misses=int(p["max_misses"]),
            full_cost_height_m=float(p["full_cost_height_m"]), vehicle=vehicle))
        self.ego = EgoMotion(max_age_s=float(p["odom_max_age_s"]))
        self.counts = {"maps": 0, "refused": 0, "without_pose": 0, "odometry_refused": 0, "resets": 0, "reported": 0}
        self.last_refusal = ""
        self._last_stamp: int | None = None
        self._last_report: Any = None
        self._factory = RclpyFactory()

        self.create_subscription(GridMap, str(p["map_topic"]), self._on_map, QOS)
        self._use_odometry = bool(str(p["odom_topic"]))
        if self._use_odometry:
            self.create_subscription(Odometry, str(p["odom_topic"]), self._on_odometry, QOS)
        self._hazards_pub = self.create_publisher(RoadHazardArray, str(p["hazards_topic"]), QOS)
        self._cost_pub = self.create_publisher(OccupancyGrid, str(p["cost_topic"]), QOS)
        markers_topic = str(p["markers_topic"])
        self._markers_pub = self.create_publisher(MarkerArray, markers_topic, QOS) if markers_topic else None
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", QOS)
        self.create_timer(float(p["diagnostics_period_s"]), self._publish_diagnostics)
        self.get_logger().info(f"hazard monitor on {p['map_topic']} -> {p['hazards_topic']}, {p['cost_topic']}")

    def _refuse(self, key: str, reason: str) -> None:
        self.counts[key] += 1
        if reason != self.last_refusal:
            self.get_logger().warning(reason)
        self.last_refusal = reason

    def _on_odometry(self, msg: Any) -> None:
        try:
            self.ego.add(odometry_sample(msg))
        except (MessageError, EgoMotionError) as exc:
            self._refuse("odometry_refused", f"odometry refused: {exc}")

    def _on_map(self, msg: Any) -> None:
        try:
            window = map_window_from_message(msg)
            last = self._last_stamp
            if last is not None and window.stamp_ns < last - int(TIME_JUMP_BACK_S * 1e9):
                self.tracker.reset()
                self.ego.clear()
                self.counts["resets"] += 1
            base = None
            if self._use_odometry:
                try:
                    base = self.ego.pose_at(window.stamp_ns)
                except EgoMotionStale:
                    self.counts["without_pose"] += 1
            report = self.tracker.update(window, base)
        except (MessageError, TrackerError, RoadbevError) as exc:
            self._refuse("refused", f"map refused: {exc}")
            return
        self._last_stamp = window.stamp_ns
        frame = str(msg.header.frame_id)
        self._hazards_pub.publish(road_hazards_message(report, self._factory, frame_id=frame))
        self._cost_pub.publish(occupancy_grid_message(report.cost, report.resolution, report.centre, self._factory,
                                                      stamp_ns=report.stamp_ns, frame_id=frame))
        if self._markers_pub is not None and self._markers_pub.get_subscription_count() > 0:  # for a viewer only
            self._markers_pub.publish(hazard_markers(report, self._factory, frame_id=frame))
        self.counts["maps"] += 1
        self.counts["reported"] = len(report.hazards)
        self._last_report = report

    def _publish_diagnostics(self) -> None:
        report = self._last_report
        ok = self.counts["maps"] > 0
        status = DiagnosticStatus()
        status.name = "roadbev: hazard monitor"
        status.hardware_id = self.get_name()
        status.level = DiagnosticStatus.OK if ok else DiagnosticStatus.WARN
        status.message = f"{self.counts['reported']} hazards reported" if ok else "no fused map yet"
        values = {k: str(v) for k, v in self.counts.items()}
        values["last_refusal"] = self.last_refusal
        if report is not None:
            for r in report.roughness:
                values[f"roughness_{r.name}"] = r.iso_class or "unknown"
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [status]
        self._diag_pub.publish(array)


def main(args: Sequence[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM; 2 on bad parameters."""

    usage = node_usage("roadbev_hazard_monitor", (__doc__ or "").splitlines()[0], DEFAULTS)
    return run_node(HazardMonitorNode, "roadbev_hazard_monitor", (RoadbevError,), None if args is None else list(args),
                    usage=usage)


if __name__ == "__main__":
    sys.exit(main())
