"""A reference preview suspension controller: ``/roadbev/preview`` in, actuator forces out.

The worked example of consuming RoadBEV's preview (docs/tutorials/preview.md, "Consume
the preview"), in the manner of ros2/examples: a small node around the ROS-free
:class:`roadbev_core.ride.OnlinePreviewController` (the preview LQR of Bender 1968 / Tomizuka
1976 on a quarter car per front wheel, :mod:`roadbev_core.ride`).

* **In**: ``roadbev_msgs/RoadPreview`` on ``preview_topic``. Where a message's profile points
  are: ``header.frame_id`` ``roadbev_road`` (per-frame previews: x ahead of the camera, the front
  axle at ``vehicle.wheelbase_m - vehicle.camera_position_m[0]``) or ``base_link`` (fused-map
  previews: x in ``base_link``, the front axle at ``vehicle.wheelbase_m``); when it holds: from
  ``header.stamp``, the wheel advancing at the message's ``vehicle_speed`` (a message without a
  speed is refused and counted). Tracks ``left``/``right`` or ``front_left``/``front_right``;
  heights in the message's own reference (only their slope along the track is used, so a
  reference offset does not matter); for ``reference`` ``contact_plane`` the plane's pitch
  (``contact_plane_pitch``) is added back (:func:`plane_slope_x`), so the plane's tilt is not
  read as road.
* **Out**: ``geometry_msgs/WrenchStamped`` on ``force_topic`` every control step, one per front
  wheel, ``header.frame_id`` = the wheel (``front_left``, ``front_right``), ``header.stamp`` =
  the step's time, ``wrench.force.z`` = the commanded actuator force (N, positive pushes the body
  up and the wheel down); ``diagnostic_msgs/DiagnosticArray`` on ``/diagnostics`` (status
  "roadbev: preview controller": messages held / refused, share of steps with a preview under
  the wheel, how far ahead the preview reaches, RMS force, the mean share of the preview's
  feedforward applied: its gain measured on the road ridden, :mod:`roadbev_core.ride.preview_gain`).
* **Clock**: the node's clock (``use_sim_time:=true`` with a replayed bag's ``/clock``); the model
  advances by the time elapsed since the last callback (several control steps when a sim-time
  timer fires late), and the forces are published once per callback. A clock that jumps back
  more than 1 s (a bag restarted) resets the controller.

The model is the reference's stand-in for suspension sensors: each wheel's quarter car rides the
previewed road itself (so its preview gain measures how well successive messages agree). On a
vehicle, set the controller's state from the measured one before each step and pass the road
velocity measured under each wheel (see :class:`roadbev_core.ride.OnlinePreviewController`).

Run: ``python -m roadbev_ros.preview_controller --ros-args -p control_rate_hz:=200.0``.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping, Sequence
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from roadbev_msgs.msg import RoadPreview

from msg_bridge import MessageError
from msg_bridge.grid_map import ROAD_FRAME
from msg_bridge.preview import preview_from_message
from roadbev_core.config import BASE_FRAME, ParamError
from roadbev_core.ride import OnlinePreviewController, PreviewLqr, RideError
from roadbev_ros.dds import node_usage, run_node
from roadbev_ros.node_params import declare_typed

__all__ = ["PreviewControllerNode", "main", "plane_slope_x"]

TIME_JUMP_BACK_S = 1.0
MAX_CATCH_UP = 50  # model steps one timer callback may run (a longer pause: the model skips ahead)
QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
DEFAULTS: dict[str, Any] = {
    "preview_topic": "/roadbev/preview",
    "force_topic": "/roadbev/suspension/force",
    "control_rate_hz": 200.0,
    "horizon_s": 1.0,
    "hold": 4,
    "max_age_s": 2.0,
    "diagnostics_period_s": 1.0,
    "vehicle.wheelbase_m": 2.80,
    "vehicle.camera_position_m": [1.60, 0.0, 1.10],
    "base_frame": BASE_FRAME,
}


def plane_slope_x(msg: Any) -> float:
    """dz/dx of a message's reference plane against gravity: 0 for ``road`` previews (level), and
    ``-tan(contact_plane_pitch)`` for ``contact_plane`` ones (the plane ``z = height - x tan(pitch)
    + ...`` of the message's contact-plane fields), so that a tilted plane does not read as road.
    Messages without those fields (older ``RoadPreview`` definitions) count as level."""
    if str(getattr(msg, "reference", "")) != "contact_plane":
        return 0.0
    pitch = float(getattr(msg, "contact_plane_pitch", 0.0))
    return -math.tan(pitch) if math.isfinite(pitch) and abs(pitch) < 0.5 else 0.0


class PreviewControllerNode(Node):
    """The reference preview controller node (see the module docstring).

    Args:
        node_name: ROS node name.
        parameter_overrides: initial parameter values, for in-process use.

    Raises:
        RideError: parameters out of range (control rate 50-1000 Hz, horizon 0-5 s, ...).
    """

    def __init__(self, *, node_name: str = "roadbev_preview_controller",
                 parameter_overrides: Mapping[str, Any] | None = None) -> None:
        overrides = [Parameter(k, value=v) for k, v in (parameter_overrides or {}).items()]
        super().__init__(node_name, parameter_overrides=overrides)
        p = {name: declare_typed(self, name, value) for name, value in DEFAULTS.items()}
        rate = float(p["control_rate_hz"])
        if not 50.0 <= rate <= 1000.0:
            raise RideError(f"control_rate_hz must be in [50, 1000], got {rate}")
        camera = [float(v) for v in p["vehicle.camera_position_m"]]
        if len(camera) != 3:
            raise RideError(f"vehicle.camera_position_m needs 3 values, got {camera}")
        self.wheel_x = {str(p["base_frame"]): float(p["vehicle.wheelbase_m"]),
                        ROAD_FRAME: float(p["vehicle.wheelbase_m"]) - camera[0]}
        self.control = OnlinePreviewController(PreviewLqr(dt=1.0 / rate, horizon_s=float(p["horizon_s"])),
                                               hold=int(p["hold"]), max_age_s=float(p["max_age_s"]))
        self.counts = {"received": 0, "refused": 0, "steps": 0, "covered_steps": 0, "resets": 0}
        self.last_refusal = ""
        self._period = {"steps": 0, "covered": 0, "force_sq": 0.0, "reach": 0.0, "gain": 0.0}
        self._last_now: int | None = None

        self.create_subscription(RoadPreview, str(p["preview_topic"]), self._on_preview, QOS)
        self._force_pub = self.create_publisher(WrenchStamped, str(p["force_topic"]), QOS)
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", QOS)
        self.create_timer(1.0 / rate, self._step)
        self.create_timer(float(p["diagnostics_period_s"]), self._publish_diagnostics)
        self.get_logger().info(f"preview controller on {p['preview_topic']} -> {p['force_topic']} at {rate:g} Hz")

    def _refuse(self, reason: str) -> None:
        self.counts["refused"] += 1
        if reason != self.last_refusal:
            self.get_logger().warning(f"preview refused: {reason}")
        self.last_refusal = reason

    def _on_preview(self, msg: Any) -> None:
        try:
            decoded = preview_from_message(msg)
            if decoded.frame_id not in self.wheel_x:
                raise RideError(f"frame {decoded.frame_id!r} is none of {', '.join(sorted(self.wheel_x))}")
            self.control.receive(decoded.stamp_ns, decoded.profiles, self.wheel_x[decoded.frame_id],
                                 slope_x=plane_slope_x(msg))
        except (MessageError, RideError) as exc:
            self._refuse(str(exc))
            return
        self.counts["received"] += 1

    def _step(self) -> None:
        now = self.get_clock().now().nanoseconds
        dt_ns = int(round(self.control.controller.dt * 1e9))
        last = self._last_now
        if last is not None and now < last - int(TIME_JUMP_BACK_S * 1e9):
            self.control.reset()
            self.counts["resets"] += 1
            last = None
        # the model advances with the clock: as many steps as have elapsed (a sim-time timer fires
        # only when /clock moves, so one callback may stand for several steps), at most MAX_CATCH_UP
        n = 1 if last is None else min(MAX_CATCH_UP, int(round((now - last) / dt_ns)))
        if n < 1:
            return
        self._last_now = now
        for k in range(n):
            commands = self.control.step(now - (n - 1 - k) * dt_ns)
        sec, nsec = divmod(now, 1_000_000_000)
        for wheel, cmd in commands.items():
            out = WrenchStamped()
            out.header.stamp.sec, out.header.stamp.nanosec = int(sec), int(nsec)
            out.header.frame_id = wheel
            out.wrench.force.z = float(cmd.force_n)
            self._force_pub.publish(out)
            self._period["force_sq"] += cmd.force_n**2
            self._period["reach"] += cmd.preview_m
            self._period["covered"] += int(cmd.covered)
            self._period["gain"] += cmd.preview_gain
            self._period["steps"] += 1
        self.counts["steps"] += n
        self.counts["covered_steps"] += int(all(c.covered for c in commands.values()))

    def _publish_diagnostics(self) -> None:
        per = self._period
        n = max(per["steps"], 1)
        covered = 100.0 * per["covered"] / n
        status = DiagnosticStatus()
        status.name = "roadbev: preview controller"
        status.hardware_id = self.get_name()
        status.level = DiagnosticStatus.OK if covered > 0 else DiagnosticStatus.WARN
        status.message = "preview under the wheels" if covered > 0 else "no preview under the wheels"
        values = {**{k: str(v) for k, v in self.counts.items()},
                  "covered_pct": f"{covered:.1f}", "preview_ahead_m": f"{per['reach'] / n:.2f}",
                  "force_rms_n": f"{math.sqrt(per['force_sq'] / n):.1f}",
                  "preview_gain": f"{per['gain'] / n:.2f}", "last_refusal": self.last_refusal}
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [status]
        self._diag_pub.publish(array)
        self._period = {"steps": 0, "covered": 0, "force_sq": 0.0, "reach": 0.0, "gain": 0.0}


def main(args: Sequence[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM; 2 on bad parameters."""

    usage = node_usage("roadbev_preview_controller", (__doc__ or "").splitlines()[0], DEFAULTS)
    return run_node(PreviewControllerNode, "roadbev_preview_controller", (RideError, ParamError),
                    None if args is None else list(args), usage=usage)


if __name__ == "__main__":
    sys.exit(main())
