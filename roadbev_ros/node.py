"""The RoadBEV node: stereo images + camera infos + IMU in, elevation map and road preview out.

A thin node: ``msg_bridge`` converts messages to arrays and back, ``roadbev_core`` does the work.

Data flow::

    callbacks (executor thread)           worker thread
    images, infos ─► ApproximateTimeSync ─► mailbox (newest set) ─► convert ─► Frame ─► backend
    IMU ─► ImuBuffer ───────────────────────────────────────────────► attitude ┘          │
    speed ─► latest speed                                         GridMap, RoadPreview, ◄─┘
                                                                   PointCloud2 publishers

Callbacks only queue messages, so they never block on inference. The mailbox holds one set:
when inference is slower than the camera, a newer set replaces the waiting one and the replaced
set is counted as dropped (``dropped_busy``). Every left image ends as an output or a counted
drop: ``dropped_sync`` (never paired, out of order, duplicate), ``dropped_invalid`` (refused
input: malformed image or calibration, stale IMU, backend error) or ``dropped_busy``.

Bad input never stops the node: the reason is logged (throttled per kind), counted and shown in
``/diagnostics``, and the next good set is processed normally. Parameters are declared with
descriptions and ranges; a change is validated as a whole (and a new backend or grid is built)
before it is accepted, otherwise it is rejected with the reason.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from sensor_msgs.msg import Imu as ImuMsg

from msg_bridge import outputs
from msg_bridge._common import MessageError, RclpyFactory, stamp_from_header
from msg_bridge.camera_info import stereo_camera_from_camera_info
from msg_bridge.image import compressed_to_rgb, image_to_rgb
from msg_bridge.imu import imu_orientation
from roadbev_core.backends import Backend, BackendError, create
from roadbev_core.config import ConfigError, GridSpec, StereoCamera
from roadbev_core.frame import Estimate, Frame, FrameError
from roadbev_core.geometry import Attitude
from roadbev_core.preview import PreviewError, wheel_track_profiles
from roadbev_ros.diagnostics import Health, ThrottledLog, to_diagnostic_array
from roadbev_ros.imu_buffer import ImuBuffer, ImuError, ImuStale
from roadbev_ros.params import (
    PARAMETERS,
    ParamError,
    ParamSpec,
    backend_options,
    grid_from_params,
    is_backend_option,
    validate,
    validate_one,
)
from roadbev_ros.sync import ApproximateTimeSync, DropReason

__all__ = [
    "BackendFactory",
    "FrameImages",
    "NodeConfig",
    "RoadBevNode",
    "images_from_messages",
    "main",
    "output_messages",
]

# create(name, grid, **options) -> Backend; injectable so tests can run a stub backend.
BackendFactory = Callable[..., Backend]

LEFT_IMAGE, RIGHT_IMAGE, LEFT_INFO, RIGHT_INFO = "left image", "right image", "left info", "right info"
# A left image this much older than the last processed one means the clock jumped back (a bag
# started again): the synchroniser is reset instead of refusing everything as out of order.
TIME_JUMP_BACK_S = 1.0
_PARAM_NAMES = frozenset(spec.name for spec in PARAMETERS)
# Speeds older than this are treated as unknown.
SPEED_MAX_AGE_S = 1.0


@dataclass(frozen=True)
class NodeConfig:
    """The validated parameter set, with the grid built from it."""

    values: Mapping[str, Any]
    grid: GridSpec

    def __getitem__(self, name: str) -> Any:
        return self.values[name]

    @classmethod
    def from_values(cls, values: Mapping[str, Any]) -> NodeConfig:
        full = validate(values)
        grid = grid_from_params(full)
        try:  # the wheel tracks must lie on the grid
            wheel_track_profiles(
                np.full(grid.shape, np.nan, np.float32), None, grid,
                track_offsets_m=full["preview.track_offsets_m"],
                tyre_width_m=full["preview.tyre_width_m"], spacing_m=full["preview.spacing_m"],
            )
        except PreviewError as exc:
            raise ParamError(f"preview settings do not fit the grid: {exc}") from None
        return cls(full, grid)


def _descriptor(spec: ParamSpec) -> ParameterDescriptor:
    descriptor = ParameterDescriptor(
        name=spec.name, description=spec.description, read_only=spec.read_only
    )
    if spec.choices:
        descriptor.additional_constraints = "one of: " + ", ".join(spec.choices)
    if isinstance(spec.default, (float, list)):
        descriptor.dynamic_typing = True  # accept 1 for 1.0 and [0, 0, 5]; validate() coerces
        if isinstance(spec.default, float) and spec.low is not None and spec.high is not None:
            descriptor.floating_point_range = [
                FloatingPointRange(from_value=float(spec.low), to_value=float(spec.high), step=0.0)
            ]
    elif isinstance(spec.default, int) and not isinstance(spec.default, bool) and spec.low is not None \
            and spec.high is not None:
        descriptor.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high), step=1)]
    return descriptor


def _plain(value: Any) -> Any:
    """A parameter value as plain Python (rclpy hands arrays as array.array / lists)."""
    if isinstance(value, (list, tuple)) or type(value).__name__ == "array":
        return [v for v in value]
    return value


class FrameImages(NamedTuple):
    """The pixels and calibration of one synchronised set."""

    left: np.ndarray
    right: np.ndarray | None
    camera: StereoCamera
    stamp_ns: int


def images_from_messages(msgs: Sequence[Any], image_transport: str) -> FrameImages:
    """Images and rig of a synchronised set (left, right, left info, right info) or (left, info).

    Raises:
        MessageError: a malformed image or CameraInfo.
    """
    if len(msgs) == 4:
        left_msg, right_msg, left_info, right_info = msgs
    else:
        (left_msg, left_info), right_msg, right_info = msgs, None, None
    to_rgb = compressed_to_rgb if image_transport == "compressed" else image_to_rgb
    left = to_rgb(left_msg)
    right = to_rgb(right_msg) if right_msg is not None else None
    camera = stereo_camera_from_camera_info(left_info, right_info)
    return FrameImages(left, right, camera, stamp_from_header(left_msg))


def output_messages(
    estimate: Estimate, config: NodeConfig, stamp_ns: int, vehicle_speed: float | None, *, with_points: bool
) -> tuple[Any, Any, Any | None]:
    """The GridMap, RoadPreview and (optionally) PointCloud2 for one estimate (rclpy messages).

    Raises:
        ValueError: the estimate is not on the configured grid.
        PreviewError: the wheel tracks do not fit the grid.
    """
    preview = outputs.PreviewSettings(
        config["preview.track_offsets_m"], config["preview.tyre_width_m"], config["preview.spacing_m"],
        config["preview.reference_distance_m"],
    )
    return outputs.output_messages(
        estimate, config.grid, _FACTORY, stamp_ns, preview=preview, frame_id=config["frame_id"],
        vehicle_speed=vehicle_speed, with_points=with_points,
    )


_FACTORY = RclpyFactory()


class _OutputPublishers:
    """The elevation map, preview and point cloud publishers, fed from the worker thread."""

    def __init__(self, node: Any, qos: Any, config: NodeConfig) -> None:
        from grid_map_msgs.msg import GridMap
        from roadbev_msgs.msg import RoadPreview
        from sensor_msgs.msg import PointCloud2

        self._elevation = node.create_publisher(GridMap, config["elevation_topic"], qos)
        self._preview = node.create_publisher(RoadPreview, config["preview_topic"], qos)
        self._points = (
            node.create_publisher(PointCloud2, config["points_topic"], qos) if config["points_topic"] else None
        )

    def points_wanted(self) -> bool:
        """The point cloud is only built for a viewer that listens (it is the largest message)."""
        return self._points is not None and self._points.get_subscription_count() > 0

    def publish(self, elevation: Any, preview: Any, points: Any | None) -> None:
        """Publish (the GridMap first: latency is measured on it)."""
        self._elevation.publish(elevation)
        self._preview.publish(preview)
        if points is not None and self._points is not None:
            self._points.publish(points)


SENSOR_QOS = qos_profile_sensor_data
# the IMU comes in bursts of many small messages per image: a deeper best-effort queue
IMU_QOS = QoSProfile(depth=200, reliability=ReliabilityPolicy.BEST_EFFORT)
OUTPUT_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


def set_inference_threads(threads: int) -> int:
    """Threads for the backends' parallel work (torch intra-op, OpenCV); 0 = cores - 1.

    On a loaded machine a parallel section waits for its slowest thread, and the executor
    thread needs a core for the callbacks: measured on the 2-core development machine, one
    torch thread ran bev_sweep 2-4x faster inside the node than two.

    Returns:
        The number of threads set.
    """
    import cv2

    n = threads if threads > 0 else max(1, (os.cpu_count() or 2) - 1)
    cv2.setNumThreads(n)
    if "torch" in sys.modules:  # only when a backend uses torch: never import it for bm/sgbm
        sys.modules["torch"].set_num_threads(n)
    return n


def _warm_up(backend: Backend) -> None:
    """Run the backend once on a blank frame before the first real one.

    The first call of a backend pays one-time costs (torch kernel and thread-pool set-up, OpenCV
    buffers): measured about 30 ms on bev_sweep, more on the networks. Paying them at start-up
    keeps them out of the first frame's latency. The rig is a stand-in (the real one comes with
    the first CameraInfo); a backend that cannot run on it is simply not warmed.
    """
    camera = StereoCamera.rsrd_half().scaled(0.5)
    blank = np.zeros((camera.height, camera.width, 3), np.uint8)
    frame = Frame(blank, blank if backend.needs_stereo else None, camera, Attitude.from_degrees(0.0, 19.0))
    with contextlib.suppress(Exception):  # a warm-up failure must never stop the node
        backend.estimate(frame)


class RoadBevNode(Node):
    """The RoadBEV node.

    Args:
        node_name: ROS node name.
        backend_factory: ``factory(name, grid, **options) -> Backend`` (default: the
            registry's :func:`roadbev_core.backends.create`).
        parameter_overrides: initial values (as ``-p`` would give), for in-process use.
    """

    def __init__(
        self,
        *,
        node_name: str = "roadbev",
        backend_factory: BackendFactory | None = None,
        parameter_overrides: Mapping[str, Any] | None = None,
        **node_kwargs: Any,
    ) -> None:
        overrides = [Parameter(k, value=v) for k, v in (parameter_overrides or {}).items()]
        super().__init__(node_name, parameter_overrides=overrides, **node_kwargs)
        self._backend_factory = backend_factory or create
        self._declare_parameters()
        self._declare_backend_options()
        declared = self.get_parameters_by_prefix("")  # every declared parameter
        values = {name: _plain(p.value) for name, p in declared.items() if self._is_ours(name)}
        self.config = NodeConfig.from_values(values)  # ParamError on nonsense at start
        self.backend = self._make_backend(self.config)
        self.health = Health(backend=self.backend.name)
        self._log_gate = ThrottledLog(self.config["log_throttle_s"])
        self._lock = threading.Condition()
        self._pending: tuple[Any, ...] | None = None
        self._pending_arrival = 0.0
        self._stop = False
        self._imu_lock = threading.Lock()
        self.imu = self._make_imu_buffer(self.config)
        self._speed: tuple[float, float] | None = None  # (speed m/s, monotonic time)
        self.sync = self._make_sync(self.config)
        self._create_io()
        self.add_pre_set_parameters_callback(self._check_parameters)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._worker = threading.Thread(target=self._work, name="roadbev-inference", daemon=True)
        self._worker.start()
        self.get_logger().info(
            f"backend {self.backend.name}, grid {self.config.grid.n_rows}x"
            f"{self.config.grid.n_cols} @ {self.config.grid.resolution} m, inputs "
            f"{self._topic(self.config['left_image_topic'])} (+ right, camera infos, "
            f"{self.config['imu_topic']})"
        )

    # --- set-up ------------------------------------------------------------------------
    def _declare_parameters(self) -> None:
        for spec in PARAMETERS:
            try:
                self.declare_parameter(spec.name, spec.default, _descriptor(spec))
            except InvalidParameterValueException as exc:
                raise ParamError(f"parameter {spec.name}: {exc}") from None

    def _declare_backend_options(self) -> None:
        # Backend options ("<backend>.<option>") are open-ended, so they are declared from what
        # the command line / params file gives (rclpy keeps those overrides in _parameter_overrides).
        for name, override in self._parameter_overrides.items():
            if is_backend_option(name) and not self.has_parameter(name):
                backend = name.split(".", 1)[0]
                descriptor = ParameterDescriptor(
                    name=name, description=f"option of the {backend} backend", dynamic_typing=True
                )
                self.declare_parameter(name, override.value, descriptor)

    @staticmethod
    def _is_ours(name: str) -> bool:
        return name in _PARAM_NAMES or is_backend_option(name)

    def _make_backend(self, config: NodeConfig) -> Backend:
        try:
            options = backend_options(config.values, config["backend"])
            backend = self._backend_factory(config["backend"], config.grid, **options)
        except (BackendError, ConfigError, OSError, ValueError) as exc:
            raise ParamError(f"backend {config['backend']!r} cannot run: {exc}") from None
        set_inference_threads(config["inference_threads"])
        return backend

    @staticmethod
    def _make_imu_buffer(config: NodeConfig) -> ImuBuffer:
        return ImuBuffer(
            max_age_s=config["imu_max_age_s"],
            max_gap_s=config["imu_max_age_s"],
            horizon_s=config["imu_buffer_s"],
            imu_to_camera_rpy_deg=tuple(config["imu_to_camera_rpy_deg"]),
        )

    def _make_sync(self, config: NodeConfig) -> ApproximateTimeSync:
        n = 4 if self.backend.needs_stereo else 2
        return ApproximateTimeSync(
            n, config["sync_queue_size"], config["sync_slop_s"], self._on_set, self._on_sync_drop,
            jump_back_s=TIME_JUMP_BACK_S, on_reset=self._on_time_jump,
        )

    def _topic(self, base: str) -> str:
        return base + "/compressed" if self.config["image_transport"] == "compressed" else base

    def _create_io(self) -> None:
        c = self.config
        image_type = CompressedImage if c["image_transport"] == "compressed" else Image
        qos = SENSOR_QOS
        self.create_subscription(image_type, self._topic(c["left_image_topic"]),
                                 lambda m: self._on_input(LEFT_IMAGE, m), qos)
        self.create_subscription(image_type, self._topic(c["right_image_topic"]),
                                 lambda m: self._on_input(RIGHT_IMAGE, m), qos)
        self.create_subscription(CameraInfo, c["left_info_topic"],
                                 lambda m: self._on_input(LEFT_INFO, m), qos)
        self.create_subscription(CameraInfo, c["right_info_topic"],
                                 lambda m: self._on_input(RIGHT_INFO, m), qos)
        self.create_subscription(ImuMsg, c["imu_topic"], self._on_imu, IMU_QOS)
        if c["speed_topic"]:
            if c["speed_topic_type"] == "odometry":
                from nav_msgs.msg import Odometry as SpeedMsg
            else:
                from geometry_msgs.msg import TwistStamped as SpeedMsg
            self.create_subscription(SpeedMsg, c["speed_topic"], self._on_speed, qos)
        self._out = _OutputPublishers(self, OUTPUT_QOS, c)
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", OUTPUT_QOS)
        self._diag_timer = self.create_timer(c["diagnostics_period_s"], self._publish_diagnostics)

    # --- problems ----------------------------------------------------------------------
    def _problem(self, kind: str, reason: str) -> None:
        self.health.problem(kind, reason)
        if self._log_gate.allow(kind):
            suppressed = self._log_gate.suppressed.pop(kind, 0)
            more = f" ({suppressed} more since the last report)" if suppressed else ""
            self.get_logger().warning(f"{kind}: {reason}{more}")

    # --- callbacks (executor thread) ---------------------------------------------------
    def _on_input(self, which: str, msg: Any) -> None:
        if which == LEFT_IMAGE:
            self.health.frame_in()
        index = {LEFT_IMAGE: 0, RIGHT_IMAGE: 1, LEFT_INFO: 2, RIGHT_INFO: 3}[which]
        if self.sync.n_topics == 2 and index in (1, 3):
            return  # a mono backend needs neither the right image nor its info
        if self.sync.n_topics == 2:
            index //= 2
        try:
            stamp = stamp_from_header(msg)
            if stamp <= 0:
                raise MessageError("header has no stamp (0)")
        except MessageError as exc:
            self._problem("bad stamp", f"{which}: {exc}")
            if which == LEFT_IMAGE:
                self.health.drop("invalid")
            return
        self.sync.add(index, stamp, (which, msg))

    def _on_time_jump(self, topic: int, jump_ns: int) -> None:
        self._problem("time jump", f"stamps went back {jump_ns * 1e-9:.2f} s (a bag started again?); "
                      "the synchroniser starts afresh")

    def _on_sync_drop(self, topic: int, stamp: int, item: Any, reason: str) -> None:
        which = item[0]
        if reason in (DropReason.OUT_OF_ORDER, DropReason.DUPLICATE):
            self._problem("stamp order", f"{which} at {stamp * 1e-9:.6f} s: {reason}")
        elif which == LEFT_IMAGE:
            self._problem("unpaired", f"left image at {stamp * 1e-9:.6f} s dropped: {reason} "
                          "(no matching right image / camera infos within the slop)")
        if which == LEFT_IMAGE:
            self.health.drop("sync")

    def _on_set(self, *items: Any) -> None:
        self.health.set_in()
        with self._lock:
            if self._pending is not None:
                self.health.drop("busy")
            self._pending = tuple(msg for _, msg in items)
            self._pending_arrival = time.monotonic()
            self._lock.notify()

    def _on_imu(self, msg: Any) -> None:
        try:
            stamp = stamp_from_header(msg)
            q = imu_orientation(msg)
            with self._imu_lock:
                self.imu.add(stamp, tuple(q))
        except (MessageError, ImuError) as exc:
            self._problem("bad imu", str(exc))

    def _on_speed(self, msg: Any) -> None:
        twist = msg.twist.twist if hasattr(msg, "pose") else msg.twist
        speed = math.hypot(twist.linear.x, twist.linear.y)
        if math.isfinite(speed):
            self._speed = (math.copysign(speed, twist.linear.x or 1.0), time.monotonic())
        else:
            self._problem("bad speed", f"non-finite speed {twist.linear.x}, {twist.linear.y}")

    # --- parameters --------------------------------------------------------------------
    def _check_parameters(self, parameters: list[Any]) -> list[Any]:
        """Runs before rclpy's own range checks: reports every bad value in diagnostics
        (the change is then rejected by rclpy or by :meth:`_on_set_parameters`)."""
        for p in parameters:
            if p.name in _PARAM_NAMES:
                try:
                    validate_one(p.name, _plain(p.value))
                except ParamError as exc:
                    self._problem("parameter", f"rejected: {exc}")
        return parameters

    def _on_set_parameters(self, parameters: Sequence[Any]) -> Any:
        candidate = dict(self.config.values)
        for p in parameters:
            candidate[p.name] = _plain(p.value)
            if p.name in _PARAM_NAMES:
                try:
                    validate_one(p.name, candidate[p.name])
                except ParamError as exc:  # already reported by _check_parameters
                    return SetParametersResult(successful=False, reason=str(exc))
        try:
            config = NodeConfig.from_values(candidate)
            rebuild = (
                config["backend"] != self.config["backend"]
                or config.grid != self.config.grid
                or backend_options(config.values, config["backend"])
                != backend_options(self.config.values, config["backend"])
            )
            backend = self._make_backend(config) if rebuild else self.backend
        except ParamError as exc:
            self._problem("parameter", f"rejected: {exc}")
            return SetParametersResult(successful=False, reason=str(exc))
        self._apply(config, backend)
        return SetParametersResult(successful=True)

    def _apply(self, config: NodeConfig, backend: Backend) -> None:
        old = self.config
        stereo_changed = backend.needs_stereo != self.backend.needs_stereo
        with self._lock:
            self.config = config
            self.backend = backend
        self.health.backend = backend.name
        self._log_gate.period_s = config["log_throttle_s"]
        if stereo_changed:
            self.sync = self._make_sync(config)
        else:
            self.sync.configure(config["sync_queue_size"], config["sync_slop_s"])
        imu_keys = ("imu_max_age_s", "imu_buffer_s", "imu_to_camera_rpy_deg")
        if any(old[k] != config[k] for k in imu_keys):
            with self._imu_lock:
                self.imu.max_age_s = self.imu.max_gap_s = config["imu_max_age_s"]
                self.imu.horizon_s = config["imu_buffer_s"]
                self.imu.imu_to_camera_rpy_deg = tuple(config["imu_to_camera_rpy_deg"])
        if old["diagnostics_period_s"] != config["diagnostics_period_s"]:
            self._diag_timer.cancel()
            self.destroy_timer(self._diag_timer)
            self._diag_timer = self.create_timer(config["diagnostics_period_s"], self._publish_diagnostics)
        self.get_logger().info("parameters updated")

    # --- worker thread -----------------------------------------------------------------
    def _work(self) -> None:
        if "torch" in sys.modules:  # the flag is per thread; backends set it in theirs
            sys.modules["torch"].set_flush_denormal(True)
        with self._lock:
            backend = self.backend
        _warm_up(backend)
        while True:
            with self._lock:
                while self._pending is None and not self._stop:
                    self._lock.wait(0.5)
                if self._stop:
                    return
                msgs, arrival = self._pending, self._pending_arrival
                self._pending = None
                config, backend = self.config, self.backend
            try:
                self._process(msgs, arrival, config, backend)
            except (MessageError, FrameError, ImuStale, PreviewError) as exc:
                self.health.drop("invalid")
                self._problem(_kind_of(exc), str(exc))
            except Exception as exc:  # a backend failure must not end the node
                self.health.drop("invalid")
                self._problem("backend error", f"{type(exc).__name__}: {exc}")

    def _attitude(self, stamp: int, config: NodeConfig) -> Attitude:
        """The attitude at ``stamp``. IMU messages may arrive after the images, so this waits
        up to ``imu_wait_s`` for a sample at or after the stamp (rather than holding an older
        one) and for an IMU that cannot answer yet (e.g. its stamps have not jumped back yet)."""
        deadline = time.monotonic() + config["imu_wait_s"]
        while True:
            with self._imu_lock:
                newest = self.imu.newest_ns
                try:
                    attitude: Attitude | None = self.imu.attitude_at(stamp)
                except ImuStale as exc:
                    attitude, error = None, exc
            self.health.imu_age_s = None if newest is None else (stamp - newest) * 1e-9
            bracketed = newest is not None and newest >= stamp
            if (attitude is not None and bracketed) or time.monotonic() >= deadline or self._stop:
                break
            time.sleep(0.002)
        if attitude is not None:
            return attitude
        if config["require_imu"]:
            raise error
        return Attitude.from_degrees(config["default_roll_deg"], config["default_pitch_deg"])

    def _process(self, msgs: tuple[Any, ...], arrival: float, config: NodeConfig, backend: Backend) -> None:
        t0 = time.perf_counter()
        images = images_from_messages(msgs, config["image_transport"])
        t_wait = time.perf_counter()
        attitude = self._attitude(images.stamp_ns, config)
        imu_wait = time.perf_counter() - t_wait  # waiting, not work: kept out of the overhead
        frame = Frame(images.left, images.right, images.camera, attitude, images.stamp_ns)
        t1 = time.perf_counter()
        estimate = backend.estimate(frame)
        t2 = time.perf_counter()
        speed = self._speed
        vehicle_speed = None
        if speed is not None and time.monotonic() - speed[1] <= SPEED_MAX_AGE_S:
            vehicle_speed = speed[0]
        elevation, preview, points = output_messages(
            estimate, config, images.stamp_ns, vehicle_speed, with_points=self._out.points_wanted()
        )
        self._out.publish(elevation, preview, points)
        t3 = time.perf_counter()
        stamp = images.stamp_ns
        latency_ms = (time.monotonic() - arrival) * 1e3
        stamp_age_ms = (time.time_ns() - stamp) * 1e-6
        overhead_ms = ((t1 - t0) - imu_wait + (t3 - t2)) * 1e3
        self.health.output(latency_ms, stamp_age_ms, (t2 - t1) * 1e3, overhead_ms, imu_wait * 1e3)

    # --- diagnostics -------------------------------------------------------------------
    def _publish_diagnostics(self) -> None:
        snapshot = self.health.snapshot()
        snapshot.values["queued_sets"] = "1" if self._pending is not None else "0"
        snapshot.values["queued_left_images"] = str(self.sync.queued()[0])
        self._diag_pub.publish(to_diagnostic_array(snapshot, self.get_clock().now().to_msg()))

    def counts(self) -> dict[str, int]:
        """Frame accounting: every left image is an output, a drop, queued or in flight."""
        h = self.health
        return {
            "frames_in": h.frames_in,
            "outputs": h.outputs,
            "dropped_busy": h.dropped_busy,
            "dropped_sync": h.dropped_sync,
            "dropped_invalid": h.dropped_invalid,
            "queued": self.sync.queued()[0] + (self._pending is not None),
        }

    def shutdown(self) -> None:
        """Stop the worker (waits for the frame in progress)."""
        with self._lock:
            self._stop = True
            self._lock.notify_all()
        self._worker.join(timeout=30.0)


def _kind_of(exc: Exception) -> str:
    if isinstance(exc, ImuStale):
        return "imu stale"
    if isinstance(exc, FrameError):
        return "bad frame"
    if isinstance(exc, PreviewError):
        return "preview"
    return "bad input"


def main(args: Sequence[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM (console script ``roadbev_node``).

    Args:
        args: command line (``sys.argv`` when None), with ``--ros-args -p ... --params-file ...``.
    """
    from roadbev_ros.dds import init_ros

    rclpy = init_ros(list(sys.argv if args is None else args))
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    try:
        node = RoadBevNode()
    except ParamError as exc:
        print(f"roadbev_node: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.shutdown()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
