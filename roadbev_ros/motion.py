"""The node's motion inputs, without ROS: IMU, speed and odometry messages (or odometry samples
taken from ``/tf``) into the pipeline.

Each message is converted (:mod:`msg_bridge`) and handed to the pipeline; a bad one is reported,
never raised. When the stamps jump back (a bag looped), the synchroniser believes the jump only a
message later, so samples of the new timeline reach the old pipeline before it is reset:
:class:`MotionInputs` keeps the messages of the last seconds and, after the reset, gives those of
the new timeline again to the fresh pipeline (its held first frames need them). It also counts
the odometry and speed samples taken: what the fused map needs besides frames.
"""

from __future__ import annotations

import contextlib
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any, Protocol

from msg_bridge import MessageError, MessageFactory, stamp_from_header
from msg_bridge.imu import imu_orientation
from msg_bridge.pipeline_io import odometry_sample, speed_from_message
from msg_bridge.tf import odometry_tf
from roadbev_core.ego_motion import PlanarPose
from roadbev_core.errors import RoadbevError

__all__ = ["RECENT_MOTION_S", "RESTART_MARGIN_S", "MotionInputs", "MotionTaker"]

RESTART_MARGIN_S = 0.1  # motion samples this far (+ imu_max_age_s) around the new timeline's frames
RECENT_MOTION_S = 3.0  # ... that arrived at most this long ago

Handler = Callable[[Any], object]


class MotionTaker(Protocol):
    """What takes the samples: :class:`roadbev_core.pipeline.Pipeline`."""

    def add_imu(self, stamp_ns: int, orientation_xyzw: Iterable[float]) -> None: ...

    def add_speed(self, stamp_ns: int, speed_mps: float) -> None: ...

    def add_odometry(self, pose: PlanarPose) -> bool: ...


class MotionInputs:
    """IMU, speed and odometry messages into ``pipeline``, and the bookkeeping around them.

    Args:
        pipeline: takes the samples.
        report: ``report(kind, reason)``: a problem for the diagnostics and the log.
        factory: builds the TF messages of ``publish_tf``.
        publish_tf: when given, each odometry message is published again as the TF ``odom`` ->
            ``base_link`` (``publish_odom_tf``).
        maxlen: messages kept (the IMU comes in bursts of many small messages per image).
        clock: seconds, monotonic (injectable for tests).
    """

    def __init__(self, pipeline: MotionTaker, report: Callable[[str, str], None], factory: MessageFactory, *,
                 publish_tf: Callable[[Any], object] | None = None, maxlen: int = 4000,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._pipeline = pipeline
        self._report = report
        self._publish_tf = publish_tf
        self._factory = factory
        self._clock = clock
        self._recent: deque[tuple[float, int, Handler, Any]] = deque(maxlen=maxlen)  # (arrived, stamp, ...)
        self.samples = 0  # odometry and speed samples taken
        self._last_at: float | None = None  # clock time of the newest of them

    # --- subscription callbacks: each message kept, then handled ---------------------------------
    def on_imu(self, msg: Any) -> None:
        self._remember(self._imu, msg)

    def on_speed(self, msg: Any) -> None:
        self._remember(self._speed, msg)

    def on_odometry(self, msg: Any) -> None:
        self._remember(self._odometry, msg)

    def on_pose(self, pose: PlanarPose) -> None:
        """An odometry sample taken from ``/tf`` (``odom_from_tf``: :class:`roadbev_ros.transforms.TfOdometry`)."""
        self._recent.append((self._clock(), pose.stamp_ns, self._pose, pose))
        self._pose(pose)

    def _remember(self, handler: Handler, msg: Any) -> None:
        with contextlib.suppress(MessageError):  # the handler names a bad stamp
            self._recent.append((self._clock(), stamp_from_header(msg), handler, msg))
        handler(msg)

    def _imu(self, msg: Any) -> None:
        try:
            self._pipeline.add_imu(stamp_from_header(msg), imu_orientation(msg))
        except RoadbevError as exc:
            self._report("bad imu", str(exc))

    def _speed(self, msg: Any) -> None:
        try:
            self._pipeline.add_speed(*speed_from_message(msg))
            self._took()
        except RoadbevError as exc:
            self._report("bad speed", str(exc))

    def _odometry(self, msg: Any) -> None:
        try:
            sample = odometry_sample(msg)
        except RoadbevError as exc:
            self._report("bad odometry", str(exc))
            return
        if self._pose(sample) and self._publish_tf is not None:
            try:
                self._publish_tf(odometry_tf(msg, self._factory))
            except RoadbevError as exc:
                self._report("bad odometry", str(exc))

    def _pose(self, pose: PlanarPose) -> bool:
        """One odometry sample into the pipeline; whether it was taken."""
        try:
            if self._pipeline.add_odometry(pose):
                self._report("odometry jump", "the odometry jumped and is followed from its new frame; the fused "
                             "map starts again")
        except RoadbevError as exc:
            self._report("bad odometry", str(exc))
            return False
        self._took()
        return True

    def _took(self) -> None:
        self.samples += 1
        self._last_at = self._clock()

    def replay(self, span: tuple[int, int] | None, imu_max_age_s: float) -> None:
        """Hand again the messages of the new timeline that arrived before the jump back was
        believed: stamps within ``span`` (the synchroniser's :attr:`restart_span`, nanoseconds)
        widened by ``imu_max_age_s`` + :data:`RESTART_MARGIN_S`, arrived in the last
        :data:`RECENT_MOTION_S`."""
        if span is None:
            return
        margin = int((imu_max_age_s + RESTART_MARGIN_S) * 1e9)
        since = self._clock() - RECENT_MOTION_S
        for arrived, stamp, handler, msg in list(self._recent):
            if arrived >= since and span[0] - margin <= stamp <= span[1] + margin:
                handler(msg)

    def age_s(self) -> float | None:
        """Seconds since the newest odometry or speed sample taken; None before the first."""
        return None if self._last_at is None else self._clock() - self._last_at
