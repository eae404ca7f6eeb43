"""The RoadBEV node: stereo images + camera infos + IMU in, elevation map and road preview out.

Wiring only, in the manner of ros2/examples: subscriptions convert messages (``msg_bridge``) and
feed the ROS-free :class:`roadbev_core.pipeline.Pipeline`, which does the work::

    callbacks (executor thread)           worker thread
    images, infos ─► ApproximateTimeSync ─► mailbox (newest set) ─► camera_input ─► pipeline.process
    IMU, speed ─► pipeline.add_imu / add_speed                    output_messages ◄──────┘
                                                                  GridMap, RoadPreview, PointCloud2

Callbacks only queue messages. The mailbox holds the newest set: when inference is slower than
the camera a waiting set is replaced and counted (``dropped_busy``). Every left image ends as an
output or a counted drop (``dropped_sync``: unpaired, out of order, duplicate; ``dropped_invalid``:
malformed or oversized image, bad calibration, stale IMU, backend error). Bad input never stops
the node: it is logged (throttled per kind), counted and shown in ``/diagnostics``. Parameters
come from the typed config tree (:mod:`roadbev_ros.node_params`); a change is validated as a
whole and a new backend is built before it is accepted, otherwise it is rejected with the reason
and the running backend stays.
"""

from __future__ import annotations

import contextlib
import functools
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from grid_map_msgs.srv import GetGridMap
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from sensor_msgs.msg import Imu as ImuMsg

from msg_bridge import MessageError, RclpyFactory, stamp_from_header
from msg_bridge.grid_map import fused_map_message
from msg_bridge.image import check_image_message
from msg_bridge.imu import imu_orientation
from msg_bridge.pipeline_io import (
    camera_input,
    odometry_sample,
    output_messages,
    speed_from_message,
    speed_message_type,
)
from msg_bridge.tf import StaticTransform, camera_mount, odometry_tf, transforms_from_tf
from roadbev_core.config import ParamError, RoadbevConfig
from roadbev_core.errors import RoadbevError
from roadbev_core.pipeline import BackendFactory, Pipeline, check_config
from roadbev_core.selfcheck import self_check
from roadbev_ros.diagnostics import (
    COMPRESSED_SUFFIX,
    Health,
    ThrottledLog,
    problem_kind,
    to_diagnostic_array,
    transport_hint,
)
from roadbev_ros.mailbox import Mailbox
from roadbev_ros.node_args import parser as node_parser
from roadbev_ros.node_params import (
    ROS_PARAMETERS,
    check_params_files,
    config_of,
    declare_parameters,
    plain,
    value_error,
)
from roadbev_ros.publishers import OutputPublishers
from roadbev_ros.sync import ApproximateTimeSync, DropReason

__all__ = ["RoadBevNode", "main"]

LEFT_IMAGE, RIGHT_IMAGE, LEFT_INFO, RIGHT_INFO = "left image", "right image", "left info", "right info"
# A camera message this much older than the last paired one means the clock jumped back (a bag
# looped or started again): the synchroniser, the IMU history and the pipeline start afresh.
# (Half a second: a looped bag of one second jumps back by one second less one frame.)
TIME_JUMP_BACK_S = 0.5
SENSOR_QOS = qos_profile_sensor_data
# the IMU comes in bursts of many small messages per image: a deeper best-effort queue
IMU_QOS = QoSProfile(depth=200, reliability=ReliabilityPolicy.BEST_EFFORT)
OUTPUT_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
# /tf_static is latched: transient local, as tf2's static broadcaster publishes it
TF_STATIC_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)
_FACTORY = RclpyFactory()
RESTART_MARGIN_S = 0.1  # motion samples this far (+ imu_max_age_s) around the new timeline's frames
RECENT_MOTION_S = 3.0  # ... that arrived at most this long ago


class RoadBevNode(Node):
    """The RoadBEV node.

    Args:
        node_name: ROS node name.
        backend_factory: ``factory(name, grid, **options) -> Backend`` (default: the registry).
        parameter_overrides: initial values (as ``-p`` would give), for in-process use.

    Raises:
        ParamError: unknown, wrong-typed or inconsistent parameters, or a backend that cannot run.
    """

    def __init__(self, *, node_name: str = "roadbev", backend_factory: BackendFactory | None = None,
                 parameter_overrides: Mapping[str, Any] | None = None, **node_kwargs: Any) -> None:
        overrides = [Parameter(k, value=v) for k, v in (parameter_overrides or {}).items()]
        super().__init__(node_name, parameter_overrides=overrides, **node_kwargs)
        declare_parameters(self)
        self.config: RoadbevConfig = config_of(self)
        # The outputs are advertised before the backend loads (seconds) and the inputs are
        # subscribed after it has loaded and warmed up: a recorder started beside the node matches
        # the outputs while the node loads, and a replay that waits for the node's subscriptions
        # (roadbev replay) starts only once the node can answer its first frame at full speed.
        self._out = OutputPublishers(self, OUTPUT_QOS, self.config.topics, self.config.map)
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", OUTPUT_QOS)
        try:
            self.pipeline = Pipeline(self.config, backend_factory=backend_factory)
        except RoadbevError as exc:
            raise ParamError(str(exc)) from None
        self.pipeline.warm_up()  # before the inputs are subscribed (above)
        self.health = Health(backend=self.pipeline.backend.name)
        self.health.configure(self.config.diagnostics)
        self._log_gate = ThrottledLog(self.config.diagnostics.log_throttle_s)
        self._mailbox: Mailbox[tuple[Any, ...]] = Mailbox()
        self._passes = 0  # time jumps back so far: a frame of an earlier pass fails quietly
        self.sync = self._make_sync()
        topics = self.config.topics
        image_type = CompressedImage if topics.image_transport == "compressed" else Image
        inputs = ((LEFT_IMAGE, self._image_topic(topics.left_image), image_type),
                  (RIGHT_IMAGE, self._image_topic(topics.right_image), image_type),
                  (LEFT_INFO, topics.left_info, CameraInfo), (RIGHT_INFO, topics.right_info, CameraInfo))
        # what each synchronised input has received, by the name the graph gives its topic: an
        # input that never arrived is named when its partners are dropped unpaired
        self._inputs = {which: self.resolve_topic_name(topic) for which, topic, _ in inputs}
        self._received: dict[str, int] = dict.fromkeys(self._inputs, 0)
        for which, topic, kind in inputs:
            self.create_subscription(kind, topic, functools.partial(self._on_input, which), SENSOR_QOS)
        # IMU, speed and odometry messages of the last seconds: when the stamps jump back, the
        # reset is believed a message later, and the samples of the new timeline that arrived
        # meanwhile are given again to the fresh pipeline (its held first frames need them)
        self._recent_motion: deque[tuple[float, int, Callable[[Any], None], Any]] = deque(maxlen=4000)
        self.create_subscription(ImuMsg, topics.imu, self._remembered(self._on_imu), IMU_QOS)
        if topics.speed:
            self.create_subscription(speed_message_type(topics.speed_type), topics.speed,
                                     self._remembered(self._on_speed), SENSOR_QOS)
        if topics.odom:
            from nav_msgs.msg import Odometry

            self.create_subscription(Odometry, topics.odom, self._remembered(self._on_odometry), IMU_QOS)
        from std_srvs.srv import Trigger
        from tf2_msgs.msg import TFMessage

        self.create_subscription(TFMessage, "/tf_static", self._on_tf_static, TF_STATIC_QOS)
        self.create_service(Trigger, "~/clear_map", self._on_clear_map)
        self.create_service(Trigger, "~/save_map", self._on_save_map)
        self.create_service(GetGridMap, "~/get_submap", self._on_get_submap)
        self._camera_frame: str | None = None  # the left images' frame_id (the TF's parent)
        self._motion_in = 0  # odometry and speed samples taken: what the map needs besides frames
        self._motion_at: float | None = None  # monotonic time of the newest of them
        self._fused = 0  # frames fused into the map
        self._preview_kind = ""  # reference (and contact-plane source) of the newest preview
        self._clock_seen: tuple[int, float] | None = None  # node clock (ns), monotonic s when it last changed
        self._cleared_at: float | None = None  # node-clock seconds of the last ~/clear_map
        self._static: dict[str, StaticTransform] = {}  # child frame -> its /tf_static transform, as tf2 keeps them
        self._mount: tuple[bytes, bytes] | None = None  # the camera mount applied last
        self._diag_timer = self._diagnostics_timer(self.config.diagnostics.period_s)
        self.add_pre_set_parameters_callback(self._report_bad_values)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._worker = threading.Thread(target=self._work, name="roadbev-inference", daemon=True)
        self._worker.start()
        grid = self.config.grid
        self.get_logger().info(
            f"backend {self.pipeline.backend.name}, grid {grid.n_rows}x{grid.n_cols} @ {grid.resolution} m, "
            f"inputs {self._resolved_image_topic(topics.left_image)} (+ right, camera infos, "
            f"{self.resolve_topic_name(topics.imu)})"
        )

    def _make_sync(self) -> ApproximateTimeSync:
        n = 4 if self.pipeline.backend.needs_stereo else 2
        s = self.config.sync
        return ApproximateTimeSync(n, s.queue_size, s.slop_s, self._on_set, self._on_sync_drop,
                                   jump_back_s=TIME_JUMP_BACK_S, on_reset=self._on_time_jump,
                                   max_bytes=int(s.queue_mb * 2**20), on_outlier=self._on_stamp_outlier)

    def _diagnostics_timer(self, period_s: float) -> Any:
        """On the steady clock: diagnostics go on while a simulated /clock stops or jumps back."""
        return self.create_timer(period_s, self._publish_diagnostics, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _image_topic(self, base: str) -> str:
        """The topic to subscribe for the image stream ``base``: raw, ``base`` (rcl applies the
        remaps); compressed, the remapped ``base`` + ``/compressed``, so that remapping the base
        topic moves its transports with it, as image_transport does."""
        if self.config.topics.image_transport == "compressed":
            return self.resolve_topic_name(base) + COMPRESSED_SUFFIX
        return base

    def _resolved_image_topic(self, base: str) -> str:
        """The image topic as the graph names it (remapped, fully qualified): for logs and diagnostics."""
        return self.resolve_topic_name(self._image_topic(base))

    def _problem(self, kind: str, reason: str) -> None:
        self.health.problem(kind, reason)
        if self._log_gate.allow(kind):
            suppressed = self._log_gate.suppressed.pop(kind, 0)
            more = f" ({suppressed} more since the last report)" if suppressed else ""
            self.get_logger().warning(f"{kind}: {reason}{more}")

    # --- callbacks (executor thread) -------------------------------------------------------------
    def _on_input(self, which: str, msg: Any) -> None:
        self._received[which] += 1
        index = {LEFT_IMAGE: 0, RIGHT_IMAGE: 1, LEFT_INFO: 2, RIGHT_INFO: 3}[which]
        if self.sync.n_topics == 2:
            if index in (1, 3):
                return  # a mono backend needs neither the right image nor its info
            index //= 2
        try:
            stamp = stamp_from_header(msg)
            if stamp <= 0:
                raise MessageError("header has no stamp (0)")
        except MessageError as exc:
            if which == LEFT_IMAGE:
                self.health.frame_in()
                self.health.drop("invalid")
            self._problem("bad stamp", f"{which}: {exc}")
            return
        if which == LEFT_IMAGE:  # the stamp's age by the node's clock (sim time under use_sim_time)
            self.health.frame_in((self.get_clock().now().nanoseconds - stamp) * 1e-9)
        nbytes = 0
        if which in (LEFT_IMAGE, RIGHT_IMAGE):  # refused before it is held (issue 19: 46 MB images)
            try:
                nbytes = check_image_message(msg, int(self.config.sync.max_image_mb * 2**20), which)
            except MessageError as exc:
                if which == LEFT_IMAGE:
                    self.health.drop("invalid")
                self._problem("image too large", str(exc))
                return
        self.sync.add(index, stamp, (which, msg), nbytes)

    def _on_time_jump(self, topic: int, jump_ns: int) -> None:
        """A looped or restarted bag, or a /clock reset (the synchroniser saw the stamps jump back
        and stay back, and has reset itself): a reset of everything fused, a WARN and a count."""
        self._passes += 1
        self.pipeline.reset()
        self._restore_motion()
        if self._mailbox.clear():  # a set of the old pass must not meet the new pass's IMU
            self.health.drop("sync")
        self.health.time_jump()
        self.get_logger().warning(f"stamps went back {jump_ns * 1e-9:.2f} s and stayed back (a bag started "
                                  "again, a /clock reset): the synchroniser, the IMU history, the odometry "
                                  "and the fused map start afresh")

    def _on_stamp_outlier(self, topic: int, ahead_ns: int) -> None:
        """One set stamped far ahead of the stream (a stamp glitch): it was dropped downstream or
        published; the stream goes on from the stamps before it and nothing is reset."""
        if topic == 0:
            self._problem("stamp order", f"a left image stamped {ahead_ns * 1e-9:.2f} s ahead of the stream "
                          "(a stamp glitch): nothing was reset")

    def _on_sync_drop(self, topic: int, stamp: int, item: Any, reason: str) -> None:
        which = item[0]
        if reason == DropReason.RESET:
            pass  # counted below; the jump itself is logged once by _on_time_jump
        elif reason in (DropReason.OUT_OF_ORDER, DropReason.DUPLICATE, DropReason.GLITCH):
            self._problem("stamp order", f"{which} at {stamp * 1e-9:.6f} s: {reason}")
        elif which == LEFT_IMAGE:
            stereo = self.sync.n_topics == 4
            needed = (LEFT_IMAGE, RIGHT_IMAGE, LEFT_INFO, RIGHT_INFO) if stereo else (LEFT_IMAGE, LEFT_INFO)
            silent = [f"{self._inputs[name]} ({name})" for name in needed if self._received[name] == 0]
            if silent:
                self._problem("unpaired", f"left image at {stamp * 1e-9:.6f} s dropped: nothing received on "
                              f"{', '.join(silent)}; is it published, and remapped to?")
            else:
                self._problem("unpaired", f"left image at {stamp * 1e-9:.6f} s dropped: {reason} "
                              "(no matching right image / camera infos within the slop)")
        elif reason == DropReason.OVERFLOW_BYTES:
            self._problem("unpaired", f"{which} at {stamp * 1e-9:.6f} s dropped: {reason} (sync_queue_mb)")
        if which == LEFT_IMAGE:
            self.health.drop("sync")

    def _on_set(self, *items: Any) -> None:
        self.health.set_in()
        if self._mailbox.put(tuple(msg for _, msg in items)):
            self.health.drop("busy")  # the waiting set was replaced by a newer one

    def _remembered(self, handler: Callable[[Any], None]) -> Callable[[Any], None]:
        """``handler`` for a subscription, the message kept in :attr:`_recent_motion` first."""
        def callback(msg: Any) -> None:
            with contextlib.suppress(MessageError):  # the handler names a bad stamp
                self._recent_motion.append((time.monotonic(), stamp_from_header(msg), handler, msg))
            handler(msg)
        return callback

    def _restore_motion(self) -> None:
        """Give the fresh pipeline the motion samples of the new timeline that arrived before the
        jump back was believed: stamps within the span the synchroniser saw, arrived lately."""
        span = self.sync.restart_span
        if span is None:
            return
        margin = int((self.config.imu.max_age_s + RESTART_MARGIN_S) * 1e9)
        since = time.monotonic() - RECENT_MOTION_S
        for arrived, stamp, handler, msg in list(self._recent_motion):
            if arrived >= since and span[0] - margin <= stamp <= span[1] + margin:
                handler(msg)

    def _on_imu(self, msg: Any) -> None:
        try:
            self.pipeline.add_imu(stamp_from_header(msg), imu_orientation(msg))
        except RoadbevError as exc:
            self._problem("bad imu", str(exc))

    def _on_odometry(self, msg: Any) -> None:
        try:
            if self.pipeline.add_odometry(odometry_sample(msg)):
                self._problem("odometry jump", "the odometry jumped and is followed from its new frame; the fused "
                              "map starts again")
            self._motion_in += 1
            self._motion_at = time.monotonic()
            if self.config.topics.publish_odom_tf:
                self._out.publish_tf(odometry_tf(msg, _FACTORY))
        except RoadbevError as exc:
            self._problem("bad odometry", str(exc))

    def _on_tf_static(self, msg: Any) -> None:
        """``base_link`` -> the left camera from ``/tf_static`` (through any chain of frames, every
        static broadcaster's message kept, a later transform to a child replacing an earlier one,
        as tf2's buffer does) wins over vehicle.camera_position_m."""
        try:
            self._static.update((tf.child, tf) for tf in transforms_from_tf(msg))
        except RoadbevError as exc:
            self._problem("bad tf", str(exc))
            return
        self._apply_camera_mount()

    def _apply_camera_mount(self) -> None:
        if self._camera_frame is None:
            return
        base = self.config.topics.base_frame
        mount = camera_mount(list(self._static.values()), base, self._camera_frame)
        if mount is None:
            return  # not joined (yet): vehicle.camera_position_m stands
        translation, rotation = mount
        key = (translation.tobytes(), rotation.tobytes())
        if key == self._mount:
            return
        try:
            self.pipeline.set_camera_mount(translation, rotation)
        except RoadbevError as exc:
            self._problem("bad tf", f"{base} -> {self._camera_frame}: {exc}")
            return
        self._mount = key
        self.get_logger().info(f"camera mount from /tf_static: {base} -> {self._camera_frame} at "
                               f"{[round(float(v), 3) for v in translation]} m")

    def _on_clear_map(self, request: Any, response: Any) -> Any:
        """``~/clear_map`` (std_srvs/Trigger), as elevation_mapping's: the fused map starts afresh."""
        self.pipeline.clear_map()
        self._cleared_at = self.get_clock().now().nanoseconds * 1e-9
        response.success = True
        response.message = "fused map cleared"
        self.get_logger().info("fused map cleared (~/clear_map)")
        return response

    def _on_save_map(self, request: Any, response: Any) -> Any:
        """``~/save_map`` (std_srvs/Trigger): the newest fused map to ``map.save_dir`` as an MCAP
        bag (one GridMap, as published); the reply names the file or says why not."""
        from pathlib import Path

        from msg_bridge.outputs import save_map_bag

        window = self.pipeline.last_map
        if window is None:
            response.success, response.message = False, f"no fused map to save: {self._why_no_map()}"
            return response
        # absolute: a relative map.save_dir is taken from the node's working directory, which a
        # launch file or a service call does not show
        path = Path(self.config.map.save_dir).expanduser().resolve() / f"roadbev_map_{window.stamp_ns}.mcap"
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            save_map_bag(path, window, self.config)
        except (RoadbevError, OSError) as exc:
            response.success, response.message = False, f"cannot save the map to {path}: {exc}"
            self._problem("save map", response.message)
            return response
        response.success, response.message = True, str(path)
        self.get_logger().info(f"fused map saved to {path}")
        return response

    def _on_get_submap(self, request: Any, response: Any) -> Any:
        """``~/get_submap`` (grid_map_msgs/GetGridMap, as elevation_mapping's): the cells of the
        newest fused map within ``length_x`` x ``length_y`` around ``position`` in ``frame_id`` (the
        map's frame; a length <= 0 takes the whole map along it), with the ``layers`` asked for (all
        when none). The service has no status field: when nothing can be served the answer is a map
        without layers, and the reason goes to the log (a client's request is not the node's
        fault, so the diagnostics are left alone)."""
        window = self.pipeline.last_map
        frame = self.config.map.frame
        reason = ""
        if window is None:
            reason = f"no fused map: {self._why_no_map()}"
        elif request.frame_id.lstrip("/") not in ("", frame):
            reason = f"frame {request.frame_id!r}: the map is served in its own frame, {frame!r}"
        else:
            window = window.crop((request.position_x, request.position_y), (request.length_x, request.length_y))
            if window is None:
                reason = (f"no cell of the map within {request.length_x:g} x {request.length_y:g} m around "
                          f"({request.position_x:g}, {request.position_y:g}) in {frame!r}")
        if reason or window is None:
            self.get_logger().warning(f"~/get_submap: {reason}")
            response.map.header.frame_id = frame
            return response
        msg = fused_map_message(window, _FACTORY, frame_id=frame)
        wanted = list(request.layers)
        unknown = [name for name in wanted if name not in msg.layers]
        if unknown:
            self.get_logger().warning(f"~/get_submap: no layer {', '.join(unknown)} (the map has "
                                      f"{', '.join(msg.layers)})")
        if wanted:
            keep = [i for i, name in enumerate(msg.layers) if name in wanted]
            msg.layers = [msg.layers[i] for i in keep]
            msg.data = [msg.data[i] for i in keep]
            msg.basic_layers = [name for name in msg.basic_layers if name in msg.layers]
        response.map = msg
        return response

    def _why_no_map(self) -> str:
        """Why the node holds no fused map now, the first cause that applies."""
        topics = self.config.topics
        if not self.config.map.enabled:
            return "map.enabled is false"
        if self._cleared_at is not None:
            return (f"the map was cleared by ~/clear_map at {self._cleared_at:.3f} s and no frame has been fused "
                    "since")
        if self._motion_in == 0:
            sources = [f"odometry on {self.resolve_topic_name(topics.odom)}" if topics.odom else "",
                       f"speed on {self.resolve_topic_name(topics.speed)}" if topics.speed else ""]
            named = " or ".join(s for s in sources if s)
            return f"no {named} received yet" if named else "neither odom_topic nor speed_topic is set"
        return "no frame has been fused yet (frames need odometry around their stamps, map.odom_max_age_s)"

    def _on_speed(self, msg: Any) -> None:
        try:
            self.pipeline.add_speed(*speed_from_message(msg))
            self._motion_in += 1
            self._motion_at = time.monotonic()
        except RoadbevError as exc:
            self._problem("bad speed", str(exc))

    # --- parameters ------------------------------------------------------------------------------
    def _report_bad_values(self, parameters: list[Any]) -> list[Any]:
        """Runs before rclpy's own range checks, so a value rclpy refuses is in the diagnostics too."""
        for p in parameters:
            error = value_error(p.name, plain(p.value))
            if error:
                self._problem("parameter", f"rejected: {error}")
        return parameters

    def _on_set_parameters(self, parameters: Sequence[Any]) -> SetParametersResult:
        error = next(filter(None, (value_error(p.name, plain(p.value)) for p in parameters)), None)
        if error:  # already reported by _report_bad_values
            return SetParametersResult(successful=False, reason=error)
        changes = {p.name: plain(p.value) for p in parameters if p.name not in ROS_PARAMETERS}
        if not changes:  # use_sim_time: rclpy's time source takes it
            return SetParametersResult(successful=True)
        try:
            config = check_config(self.config.with_params(changes))
            self.pipeline.reconfigure(config)  # builds a new backend first; the old one runs on failure
        except RoadbevError as exc:
            self._problem("parameter", f"rejected: {exc}")
            return SetParametersResult(successful=False, reason=str(exc))
        old, self.config = self.config, config
        self.health.backend = self.pipeline.backend.name
        self._log_gate.period_s = config.diagnostics.log_throttle_s
        if (self.sync.n_topics == 4) != self.pipeline.backend.needs_stereo:
            self.sync = self._make_sync()
        else:
            self.sync.configure(config.sync.queue_size, config.sync.slop_s, int(config.sync.queue_mb * 2**20))
        if old.diagnostics.period_s != config.diagnostics.period_s:
            self.destroy_timer(self._diag_timer)
            self._diag_timer = self._diagnostics_timer(config.diagnostics.period_s)
        self.health.configure(config.diagnostics)
        self.get_logger().info("parameters updated")
        return SetParametersResult(successful=True)

    # --- worker thread ---------------------------------------------------------------------------
    def _work(self) -> None:
        while True:
            taken = self._mailbox.take()
            if taken is None:
                return
            msgs, arrival = taken
            passes = self._passes
            try:
                self._process(msgs, arrival)
            except RoadbevError as exc:
                if passes != self._passes:  # the clock jumped back meanwhile (IMU history reset)
                    self.health.drop("sync")
                    continue
                self.health.drop("invalid")
                self._problem(problem_kind(exc), str(exc))
            except Exception as exc:  # a backend failure must not end the node
                self.health.drop("invalid")
                self._problem("backend error", f"{type(exc).__name__}: {exc}")

    def _process(self, msgs: tuple[Any, ...], arrival: float) -> None:
        config = self.config
        t0 = time.perf_counter()
        inputs = camera_input(msgs, config.topics.image_transport)
        frame_id = str(msgs[0].header.frame_id)
        if frame_id and frame_id != self._camera_frame:
            self._camera_frame = frame_id
            self._apply_camera_mount()
        # IMU messages may arrive after the images: wait for a sample at or after the stamp
        imu_wait = self.pipeline.wait_for_attitude(inputs.stamp_ns, config.imu.wait_s, lambda: self._mailbox.closed)
        self.health.imu_age_s = self.pipeline.imu_age_s(inputs.stamp_ns)
        t1 = time.perf_counter()
        output = self.pipeline.process(inputs)
        t2 = time.perf_counter()
        messages = output_messages(output, config, _FACTORY, with_points=self._out.points_wanted(),
                                   camera_frame=self._camera_frame)
        if not self.context.ok():
            return  # shutting down (SIGINT): publishing on a shut-down context can crash the process
        late_s = time.monotonic() - arrival
        bound_s = config.diagnostics.max_latency_s
        if bound_s and late_s > bound_s:  # a preview this late points at road already driven over
            self.health.drop("stale")
            self._problem("stale output", f"the frame at {inputs.stamp_ns * 1e-9:.3f} s was ready {late_s * 1e3:.0f} "
                          f"ms after its input arrived (max_latency_s {bound_s:g}): not published")
            return
        self._out.publish(messages)
        self._note_outputs(output)
        t3 = time.perf_counter()
        latency_ms = (time.monotonic() - arrival) * 1e3
        stamp_age_ms = (self.get_clock().now().nanoseconds - inputs.stamp_ns) * 1e-6
        estimate_ms = output.timings_ms["estimate"]
        overhead_ms = ((t1 - t0) - imu_wait + (t2 - t1) - estimate_ms * 1e-3 + (t3 - t2)) * 1e3
        self.health.output(latency_ms, stamp_age_ms, estimate_ms, overhead_ms, imu_wait * 1e3)
        # coverage of every frame, and when it is low the likely causes (measured on such frames only)
        check = self_check(output.estimate, output.frame, config.grid, measure_when_ok=False)
        self.health.coverage(check.coverage_pct, check.ok, check.message)

    # --- diagnostics -----------------------------------------------------------------------------
    def _note_outputs(self, output: Any) -> None:
        """What the diagnostics report of the map and the preview."""
        if output.fusion is not None:
            self._fused += 1
        if output.preview is not None:
            plane = output.preview.contact_plane
            self._preview_kind = output.preview.reference + (f" ({plane.source})" if plane is not None else "")

    def _map_state(self) -> str:
        """The fused map in a few words: fusing, or why not."""
        if not self.config.map.enabled:
            return "off (map.enabled false)"
        if self.pipeline.map_active:
            return "fusing"
        return f"waiting: {self._why_no_map()}"

    def _clock_state(self, now_ns: int) -> str:
        """Whether the node's clock moves (a replay's /clock stops when the bag ends: the
        diagnostics after it carry the same stamp, and say so)."""
        steady = time.monotonic()
        if self._clock_seen is None or now_ns != self._clock_seen[0]:
            self._clock_seen = (now_ns, steady)  # the clock's value and when it last changed
            return "running"
        return f"stopped for {steady - self._clock_seen[1]:.0f} s (use_sim_time and no /clock)"

    def _publish_diagnostics(self) -> None:
        quiet = self.health.input_rate.in_window() == 0
        left = self._resolved_image_topic(self.config.topics.left_image)
        self.health.input_hint = transport_hint(self, left) if quiet else ""
        snapshot = self.health.snapshot()
        snapshot.values["queued_sets"] = "1" if self._mailbox.waiting else "0"
        snapshot.values["queued_left_images"] = str(self.sync.queued()[0])
        snapshot.values["map"] = self._map_state()
        snapshot.values["map_frames_fused"] = str(self._fused)
        snapshot.values["motion_age_s"] = ("never" if self._motion_at is None
                                           else f"{time.monotonic() - self._motion_at:.2f}")
        snapshot.values["preview_reference"] = self._preview_kind or "none yet"
        now = self.get_clock().now()
        snapshot.values["clock"] = self._clock_state(now.nanoseconds)
        self._diag_pub.publish(to_diagnostic_array(snapshot, now.to_msg()))

    def counts(self) -> dict[str, int]:
        """Frame accounting: every left image is an output, a drop, queued or in flight."""
        h = self.health
        return {"frames_in": h.frames_in, "outputs": h.outputs, "dropped_busy": h.dropped_busy,
                "dropped_sync": h.dropped_sync, "dropped_invalid": h.dropped_invalid, "dropped_stale": h.dropped_stale,
                "queued": self.sync.queued()[0] + self._mailbox.waiting}

    def shutdown(self) -> None:
        """Stop the worker (waits for the frame in progress)."""
        self._mailbox.close()
        self._worker.join(timeout=30.0)


def main(args: Sequence[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM (console script ``roadbev_node``); 2 on bad parameters.

    Args:
        args: command line (``sys.argv`` when None), with ``--ros-args -p ... --params-file ...``.
    """
    from roadbev_ros.dds import asks_for_help, init_ros, raise_interrupt, spin_until_shutdown

    argv = list(sys.argv if args is None else args)
    if asks_for_help(argv):
        node_parser("roadbev_node").print_help()
        return 0
    rclpy = None
    try:
        notes = check_params_files(argv, "roadbev")
        # Our own SIGINT / SIGTERM (KeyboardInterrupt in the spin): rclpy's handlers shut the
        # context down at once, while the inference thread may be inside a publish, which crashed
        # the node (exit -11) now and then under load; this way the worker is joined first.
        rclpy = init_ros(argv, handle_signals=False)
        for sig in (signal.SIGINT, signal.SIGTERM):  # SIGINT too: a shell's background job ignores it
            signal.signal(sig, raise_interrupt)
        node = RoadBevNode()
    except ParamError as exc:
        print(f"roadbev node: error: {exc}", file=sys.stderr)
        if rclpy is not None:
            rclpy.try_shutdown()
        return 2
    for note in notes:
        node.get_logger().warning(note)
    spin_until_shutdown(rclpy, node, on_exit=node.shutdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
