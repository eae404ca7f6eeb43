"""The RoadBEV node: stereo images + camera infos + IMU in, elevation map and road preview out.

Wiring only, in the manner of ros2/examples: subscriptions convert messages (``msg_bridge``) and
feed the ROS-free :class:`roadbev_core.pipeline.Pipeline`, which does the work::

    callbacks (executor thread)           worker thread
    images, infos ─► ApproximateTimeSync ─► mailbox (newest set) ─► camera_input ─► pipeline.process
    IMU, speed ─► pipeline.add_imu / add_speed                    output_messages ◄──────┘
                                                                  GridMap, RoadPreview, PointCloud2

Image callbacks only queue; IMU, speed and odometry feed the pipeline. The mailbox holds the
newest set (a replaced one counts as ``dropped_busy``). Every left image ends as an output or a
counted drop (``roadbev_ros.diagnostics.DROP_KINDS``). Bad input never stops the node: it is
logged (throttled per kind), counted and shown in ``/diagnostics``. Parameters come from the
typed config tree (:mod:`roadbev_ros.node_params`); a change is validated as a whole and a new
backend is built before it is accepted, otherwise it is rejected with the reason.

The rules are ROS-free, each in its module: ``camera_inputs`` (checks, synchroniser, drops),
``motion``, ``transforms`` (``/tf_static``, ``/tf``), ``map_services``, ``diagnostics``, ``node_params``.
"""

from __future__ import annotations

import functools
import signal
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from grid_map_msgs.srv import GetGridMap, ProcessFile
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from sensor_msgs.msg import Imu as ImuMsg
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage

from msg_bridge import RclpyFactory
from msg_bridge.pipeline_io import camera_input, output_messages, speed_message_type
from roadbev_core.config import ParamError, RoadbevConfig
from roadbev_core.errors import RoadbevError
from roadbev_core.pacing import Pacer
from roadbev_core.pipeline import BackendFactory, Pipeline, check_config
from roadbev_core.selfcheck import self_check
from roadbev_ros.camera_inputs import LEFT_IMAGE, LEFT_INFO, RIGHT_IMAGE, RIGHT_INFO, CameraInputs
from roadbev_ros.dds import asks_for_help, init_ros, raise_interrupt, spin_until_shutdown
from roadbev_ros.diagnostics import (
    COMPRESSED_SUFFIX,
    NodeDiagnostics,
    far_field_state,
    to_diagnostic_array,
    transport_hint,
)
from roadbev_ros.mailbox import Mailbox
from roadbev_ros.map_services import MapServices
from roadbev_ros.motion import MotionInputs
from roadbev_ros.node_args import parser as node_parser
from roadbev_ros.node_params import check_params_files, config_of, declare_parameters, param_changes, report_bad_values
from roadbev_ros.publishers import OutputPublishers
from roadbev_ros.sync import ApproximateTimeSync
from roadbev_ros.transforms import NodeTransforms

__all__ = ["RoadBevNode", "main"]

SENSOR_QOS = qos_profile_sensor_data
# the IMU comes in bursts of many small messages per image: a deeper best-effort queue
IMU_QOS = QoSProfile(depth=200, reliability=ReliabilityPolicy.BEST_EFFORT)
OUTPUT_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
# /tf_static is latched: transient local, as tf2's static broadcaster publishes it; /tf as tf2_ros listens
TF_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
TF_STATIC_QOS = QoSProfile(depth=100, reliability=TF_QOS.reliability, durability=DurabilityPolicy.TRANSIENT_LOCAL)
_FACTORY = RclpyFactory()


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
        self._out = OutputPublishers(self, OUTPUT_QOS, self.config.topics, self.config.map, self.config.far_field)
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", OUTPUT_QOS)
        try:
            self.pipeline = Pipeline(self.config, backend_factory=backend_factory)
        except RoadbevError as exc:
            raise ParamError(str(exc)) from None
        self.pipeline.warm_up()  # before the inputs are subscribed (above)
        log = self.get_logger()
        self._status = NodeDiagnostics(self.pipeline.backend.name, self.config.diagnostics, log.warning,
                                       far_field=self._far_field_state())
        self.health, self._problem = self._status.health, self._status.report
        self._mailbox: Mailbox[tuple[Any, ...]] = Mailbox()
        self._pacer = Pacer(self.config.backend.pace_load, lead_m=self.config.backend.pace_lead_m)
        topics = self.config.topics
        image_type = CompressedImage if topics.image_transport == "compressed" else Image
        inputs = ((LEFT_IMAGE, self._image_topic(topics.left_image), image_type),
                  (RIGHT_IMAGE, self._image_topic(topics.right_image), image_type),
                  (LEFT_INFO, topics.left_info, CameraInfo), (RIGHT_INFO, topics.right_info, CameraInfo))
        self._inputs = {which: self.resolve_topic_name(topic) for which, topic, _ in inputs}
        self._camera = CameraInputs(self._inputs, self.config.sync, self.pipeline.backend.needs_stereo,
                                    health=self.health, report=self._problem, warn=log.warning,
                                    now_ns=lambda: self.get_clock().now().nanoseconds, mailbox=self._mailbox,
                                    on_time_jump=self._on_time_jump, on_set=self._pacer.note_set)
        for which, topic, kind in inputs:
            self.create_subscription(kind, topic, functools.partial(self._camera.add, which), SENSOR_QOS)
        self._motion = MotionInputs(self.pipeline, self._problem, _FACTORY,
                                    publish_tf=self._out.publish_tf if topics.publish_odom_tf else None)
        self.create_subscription(ImuMsg, topics.imu, self._motion.on_imu, IMU_QOS)
        if topics.speed:
            self.create_subscription(speed_message_type(topics.speed_type), topics.speed, self._motion.on_speed,
                                     SENSOR_QOS)
        if topics.odom:
            self.create_subscription(Odometry, topics.odom, self._motion.on_odometry, IMU_QOS)
        self._tf = NodeTransforms(self.pipeline, lambda: self.config, log.info, self._problem, self._motion.on_pose)
        self.create_subscription(TFMessage, "/tf_static", self._tf.on_static, TF_STATIC_QOS)
        self.create_subscription(TFMessage, "/tf", self._tf.on_tf, TF_QOS)
        self._map = MapServices(self.pipeline, lambda: self.config, lambda: self._motion.samples,
                                self.resolve_topic_name, lambda: self.get_clock().now().nanoseconds * 1e-9, _FACTORY,
                                log.info, log.warning, self._problem)
        self.create_service(Trigger, "~/clear_map", self._map.clear_map)
        self.create_service(Trigger, "~/save_map", self._map.save_map)
        self.create_service(ProcessFile, "~/save_map_to", self._map.save_map_to)
        self.create_service(GetGridMap, "~/get_submap", self._map.get_submap)
        self._diag_timer = self._diagnostics_timer(self.config.diagnostics.period_s)
        self.add_pre_set_parameters_callback(functools.partial(report_bad_values, report=self._problem))
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._worker = threading.Thread(target=self._work, name="roadbev-inference", daemon=True)
        self._worker.start()
        grid = self.config.grid
        log.info(f"backend {self.pipeline.backend.name}, grid {grid.n_rows}x{grid.n_cols} @ {grid.resolution} m, "
                 f"inputs {self._resolved_image_topic(topics.left_image)} (+ right, camera infos, "
                 f"{self.resolve_topic_name(topics.imu)})")

    @property
    def sync(self) -> ApproximateTimeSync:
        """The camera inputs' synchroniser."""
        return self._camera.sync

    @property
    def _fused(self) -> int:
        """Frames fused into the map so far."""
        return self._status.tally.fused

    def _diagnostics_timer(self, period_s: float) -> Any:
        """On the steady clock: diagnostics go on while a simulated /clock stops or jumps back."""
        return self.create_timer(period_s, self._publish_diagnostics, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _far_field_state(self) -> str:
        """The far field as the pipeline runs it (the ``far_field`` diagnostic); where it is asked
        for and the backend has none, the reason is also logged as a warning (at start and at each
        parameter change)."""
        why_not = self.pipeline.far_field_off
        if why_not:
            self.get_logger().warning(f"{why_not}; the map and the previews end at the grid's far edge "
                                      f"and {self.config.far_field.topic} stays silent")
        return far_field_state(self.pipeline.far_backend is not None, why_not)

    def _pace_state(self) -> str:
        """The ``pace`` diagnostic: who answers the frames and why (:mod:`roadbev_core.pacing`)."""
        pace, backend = self.pipeline.pace, self.pipeline.backend.name
        if pace.near is None:
            return f"off: {pace.off_reason}" if pace.off_reason else "off"
        return self._pacer.state().describe(backend, pace.near.name, self._pacer.load)

    def _image_topic(self, base: str) -> str:
        """The topic of the image stream ``base``: raw, ``base`` (rcl applies the remaps); compressed,
        the remapped ``base`` + ``/compressed``: a remap of the base moves it, as in image_transport."""
        if self.config.topics.image_transport == "compressed":
            return self.resolve_topic_name(base) + COMPRESSED_SUFFIX
        return base

    def _resolved_image_topic(self, base: str) -> str:
        """The image topic as the graph names it (remapped, fully qualified): for logs and diagnostics."""
        return self.resolve_topic_name(self._image_topic(base))

    # --- callbacks (executor thread) -------------------------------------------------------------
    def _on_time_jump(self, restart_span: tuple[int, int] | None) -> None:
        """The stamps jumped back (a looped bag): the pipeline starts afresh, with the motion
        samples of the new timeline that arrived before the jump was believed."""
        self.pipeline.reset()
        self._pacer.reset()
        self._tf.time_jumped()
        self._motion.replay(restart_span, self.config.imu.max_age_s)

    def _on_set_parameters(self, parameters: Sequence[Any]) -> SetParametersResult:
        error, changes = param_changes(parameters)  # an error is already reported by report_bad_values
        if error or not changes:  # no change of the config's: use_sim_time, which rclpy's time source takes
            return SetParametersResult(successful=error is None, reason=error or "")
        try:
            config = check_config(self.config.with_params(changes))
            self.pipeline.reconfigure(config)  # builds a new backend first; the old one runs on failure
        except RoadbevError as exc:
            self._problem("parameter", f"rejected: {exc}")
            return SetParametersResult(successful=False, reason=str(exc))
        old, self.config = self.config, config
        self._pacer.load, self._pacer.lead_m = config.backend.pace_load, config.backend.pace_lead_m
        self._camera.configure(config.sync, self.pipeline.backend.needs_stereo)
        if old.diagnostics.period_s != config.diagnostics.period_s:
            self.destroy_timer(self._diag_timer)
            self._diag_timer = self._diagnostics_timer(config.diagnostics.period_s)
        self._status.configure(self.pipeline.backend.name, config.diagnostics, far_field=self._far_field_state())
        self.get_logger().info("parameters updated")
        return SetParametersResult(successful=True)

    # --- worker thread ---------------------------------------------------------------------------
    def _work(self) -> None:
        while True:
            taken = self._mailbox.take()
            if taken is None:
                return
            msgs, arrival = taken
            passes = self._camera.passes
            try:
                self._process(msgs, arrival)
            except Exception as exc:  # bad input or a backend failure must not end the node
                self._status.frame_failed(exc, earlier_pass=passes != self._camera.passes)

    def _process(self, msgs: tuple[Any, ...], arrival: float) -> None:
        config = self.config
        t0 = time.perf_counter()
        inputs = camera_input(msgs, config.topics.image_transport)
        self._tf.see_frame(str(msgs[0].header.frame_id), inputs.stamp_ns)
        # IMU and odometry messages may arrive after the images: the estimate waits for an IMU
        # sample at or after the stamp, the map stage for an odometry one (by then it has mostly
        # come), both within imu_wait_s of the set's arrival
        def stop() -> bool:
            return self._mailbox.closed

        imu_wait = self.pipeline.wait_for_attitude(inputs.stamp_ns, config.imu.wait_s, stop)
        self.health.imu_age_s = self.pipeline.imu_age_s(inputs.stamp_ns)
        waited = [imu_wait]
        deadline = time.monotonic() - imu_wait + config.imu.wait_s

        def wait_for_pose() -> None:
            waited.append(self.pipeline.wait_for_pose(inputs.stamp_ns, max(0.0, deadline - time.monotonic()), stop))

        paced = self._pacer.choose(self.pipeline.latest_speed(inputs.stamp_ns))
        output = self.pipeline.process(inputs, before_map=wait_for_pose, paced=paced)
        wait = sum(waited)
        messages = output_messages(output, config, _FACTORY, with_points=self._out.points_wanted(),
                                   with_preview_markers=self._out.preview_markers_wanted(),
                                   camera_frame=self._tf.mount.camera_frame)
        self._pacer.note_cost(output.paced, time.perf_counter() - t0 - wait)
        if not self.context.ok():
            return  # shutting down (SIGINT): publishing on a shut-down context can crash the process
        if self._status.late(inputs.stamp_ns, time.monotonic() - arrival, config.diagnostics.max_latency_s):
            return  # a preview this late points at road already driven over
        self._out.publish(messages)
        self._status.tally.note(output)
        t3 = time.perf_counter()
        latency_ms = (time.monotonic() - arrival) * 1e3
        stamp_age_ms = (self.get_clock().now().nanoseconds - inputs.stamp_ns) * 1e-6
        estimate_ms = output.timings_ms["estimate"]
        overhead_ms = ((t3 - t0) - wait - estimate_ms * 1e-3) * 1e3
        self.health.output(latency_ms, stamp_age_ms, estimate_ms, overhead_ms, wait * 1e3)
        # coverage of every frame, and when it is low the likely causes (measured on such frames only)
        check = self_check(output.estimate, output.frame, config.grid, measure_when_ok=False)
        self.health.coverage(check.coverage_pct, check.ok, check.message)

    # --- diagnostics (steady-clock timer) --------------------------------------------------------
    def _publish_diagnostics(self) -> None:
        quiet = self.health.input_rate.in_window() == 0
        left = self._resolved_image_topic(self.config.topics.left_image)
        now = self.get_clock().now()
        snapshot = self._status.snapshot(
            input_hint=transport_hint(self, left) if quiet else "", queued_set=self._mailbox.waiting,
            queued_left_images=self.sync.queued()[0], map_state=self._map.state(), motion_age_s=self._motion.age_s(),
            camera_mount=self._tf.mount.state(), pace=self._pace_state(), now_ns=now.nanoseconds)
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
    argv = list(sys.argv if args is None else args)
    if asks_for_help(argv):
        node_parser("roadbev_node").print_help()
        return 0
    rclpy = None
    try:
        notes = check_params_files(argv, "roadbev")
        # Our own SIGINT / SIGTERM (KeyboardInterrupt in the spin): rclpy's handlers shut the
        # context down at once, while the inference thread may be inside a publish, which can crash
        # the process (a publish on a destroyed context); this way the worker is joined first.
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
