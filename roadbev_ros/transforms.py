"""The node's transforms, without ROS: ``/tf_static`` and ``/tf`` into one tf2 buffer, and what
the node takes from it.

* The buffer (:class:`msg_bridge.tf_buffer.TransformBuffer`, ``tf_cache_time_s``,
  ``tf_tolerance_s``) holds what a tf2 listener would: ``/tf_static`` latched, ``/tf`` over the
  cache time. A malformed message, or a transform the buffer refuses (data older than its cache),
  is reported as ``bad tf``. The node's own output TF (the camera -> ``frame_id``) is left out.
* The camera mount (:class:`roadbev_ros.camera_mount.CameraMount`): ``base_frame`` -> the left
  images' frame, at each frame's stamp.
* With ``odom_from_tf``, the odometry: ``map_frame`` -> ``base_frame`` looked up at the stamp of
  each ``/tf`` transform on the way between them (:class:`TfOdometry`), handed on as the samples
  an ``odom_topic`` would give (speed and yaw rate from one sample to the next).

When the stamps jump back (a looped bag) the node forgets the ``/tf`` history, as tf2_ros does
when its clock jumps back; ``/tf`` that arrived between the jump and the node believing it (a
frame) is lost with it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from msg_bridge.tf import StaticTransform, TransformError, stamped_transforms_from_tf, transforms_from_tf
from msg_bridge.tf_buffer import Extrapolation, TransformBuffer
from roadbev_core.config import RoadbevConfig
from roadbev_core.ego_motion import PlanarPose
from roadbev_core.errors import RoadbevError
from roadbev_ros.camera_mount import CameraMount, MountTaker

__all__ = ["MAX_PENDING_STAMPS", "NodeTransforms", "TfOdometry", "planar_pose"]

MAX_PENDING_STAMPS = 200  # /tf stamps kept for an odometry lookup whose other links have not caught up


def planar_pose(stamp_ns: int, rotation: np.ndarray, translation: np.ndarray,
                previous: PlanarPose | None = None) -> PlanarPose:
    """``base_link`` in ``odom`` from a transform (``rotation`` [3, 3], ``translation`` [3]), planar;
    speed (along the heading) and yaw rate from the move since ``previous`` (0 without one)."""
    x, y = float(translation[0]), float(translation[1])
    yaw = math.atan2(float(rotation[1, 0]), float(rotation[0, 0]))
    if previous is None or stamp_ns <= previous.stamp_ns:
        return PlanarPose(stamp_ns, x, y, yaw)
    dt = (stamp_ns - previous.stamp_ns) * 1e-9
    turn = math.remainder(yaw - previous.yaw, math.tau)
    heading = previous.yaw + 0.5 * turn  # the mean heading over the step
    speed = ((x - previous.x) * math.cos(heading) + (y - previous.y) * math.sin(heading)) / dt
    return PlanarPose(stamp_ns, x, y, yaw, speed, turn / dt)


class TfOdometry:
    """``odom_frame`` -> ``base_frame`` from the buffer, as odometry samples in stamp order.

    Args:
        buffer: the node's transforms.
        odom_frame: the odometry's frame (``map_frame``).
        base_frame: the vehicle body's frame.
        take: takes each sample (:meth:`roadbev_ros.motion.MotionInputs.on_pose`).
        report: ``report(kind, reason)``: a problem for the diagnostics and the log.
    """

    def __init__(self, buffer: TransformBuffer, odom_frame: str, base_frame: str, take: Callable[[PlanarPose], None],
                 report: Callable[[str, str], None]) -> None:
        self._buffer = buffer
        self._odom, self._base = odom_frame, base_frame
        self._take = take
        self._report = report
        self._pending: list[int] = []  # stamps of /tf transforms on the way, not looked up yet
        self.newest: PlanarPose | None = None  # the last sample taken

    def add(self, transforms: list[tuple[int, StaticTransform]]) -> None:
        """``/tf`` transforms just added to the buffer: a sample at the stamp of each one on the way
        from ``base_frame`` to ``odom_frame`` (once every link on the way has data there)."""
        try:
            on_way = {link.child for link in self._buffer.links(self._odom, self._base) if not link.static}
        except TransformError:
            return  # not joined (yet): check() names it at the next frame
        after = -1 if self.newest is None else self.newest.stamp_ns
        stamps = {stamp for stamp, tf in transforms if tf.child in on_way and stamp > after}
        self._pending = sorted(set(self._pending) | stamps)[-MAX_PENDING_STAMPS:]
        while self._pending:
            stamp = self._pending[0]
            try:
                rotation, translation = self._buffer.lookup(self._odom, self._base, stamp)
            except Extrapolation as exc:
                if exc.future:
                    return  # another link on the way has no data there yet: try again with its next
                self._pending.pop(0)  # older than another link's history: never to be had
                continue
            except TransformError:
                return
            self._pending.pop(0)
            self.newest = planar_pose(stamp, rotation, translation, self.newest)
            self._take(self.newest)

    def check(self, stamp_ns: int, max_age_s: float) -> None:
        """A frame at ``stamp_ns``: reported (``tf missing``) when no sample lies within
        ``max_age_s`` before it (``map.odom_max_age_s``), with tf2's reason."""
        if self.newest is not None and self.newest.stamp_ns >= stamp_ns - int(max_age_s * 1e9):
            return
        try:
            self._buffer.lookup(self._odom, self._base, stamp_ns)
            why = "no sample near the frame yet"
        except TransformError as exc:
            why = str(exc)
        self._report("tf missing", f"no odometry {self._odom} -> {self._base} from /tf within {max_age_s:g} s of the "
                     f"frame at {stamp_ns * 1e-9:.3f} s (odom_from_tf): {why}; the frame is not fused unless a "
                     "speed (speed_topic) dead-reckons the map, and its preview comes from the frame alone")

    def reset(self) -> None:
        """The stamps jumped back: the next samples start afresh."""
        self._pending.clear()
        self.newest = None


class NodeTransforms:
    """``/tf_static`` and ``/tf`` into the buffer, the camera mount, and the odometry from TF.

    Args:
        pipeline: takes the camera mount.
        config: the node's config (read when built: the TF settings are read-only).
        info: writes an info line to the log.
        report: ``report(kind, reason)``: a problem for the diagnostics and the log.
        odometry: takes the odometry samples from TF; used with ``odom_from_tf``.
    """

    def __init__(self, pipeline: MountTaker, config: Callable[[], RoadbevConfig], info: Callable[[str], object],
                 report: Callable[[str, str], None], odometry: Callable[[PlanarPose], None]) -> None:
        topics = config().topics
        self._config = config
        self._report = report
        self._own_frame = topics.frame_id
        self.buffer = TransformBuffer(topics.tf_cache_time_s, topics.tf_tolerance_s)
        self.mount = CameraMount(pipeline, self.buffer, topics.base_frame,
                                 lambda: config().vehicle.camera_position_m, info, report)
        self.odometry = (TfOdometry(self.buffer, config().map.frame, topics.base_frame, odometry, report)
                         if topics.odom_from_tf else None)

    def on_static(self, msg: Any) -> None:
        """A ``tf2_msgs/TFMessage`` of ``/tf_static``."""
        if self._add(msg, static=True):
            self.mount.transforms_changed()

    def on_tf(self, msg: Any) -> None:
        """A ``tf2_msgs/TFMessage`` of ``/tf``."""
        kept = self._add(msg, static=False)
        if kept and self.odometry is not None:
            self.odometry.add(kept)

    def _add(self, msg: Any, *, static: bool) -> list[tuple[int, StaticTransform]]:
        """The transforms of ``msg`` into the buffer; those kept, with their stamps (0: static)."""
        try:
            stamped = [(0, tf) for tf in transforms_from_tf(msg)] if static else stamped_transforms_from_tf(msg)
        except RoadbevError as exc:  # a malformed message is left out whole
            self._report("bad tf", str(exc))
            return []
        kept, refused = [], []
        for stamp_ns, tf in stamped:
            if tf.child == self._own_frame:
                continue  # the node's own output TF (camera -> frame_id), heard back on /tf
            try:
                self.buffer.add(tf, stamp_ns, static=static)
                kept.append((stamp_ns, tf))
            except TransformError as exc:
                refused.append(str(exc))
        if refused:
            more = f" (and {len(refused) - 1} more in the message)" if len(refused) > 1 else ""
            self._report("bad tf", refused[0] + more)
        return kept

    def see_frame(self, frame_id: str, stamp_ns: int) -> None:
        """A left image (worker thread): the camera mount at its stamp, and whether the odometry
        from TF reaches it."""
        self.mount.see_frame(frame_id, stamp_ns)
        if self.odometry is not None:
            self.odometry.check(stamp_ns, self._config().map.odom_max_age_s)

    def time_jumped(self) -> None:
        """The stamps jumped back (a looped bag): the ``/tf`` history is forgotten."""
        self.buffer.clear_dynamic()
        if self.odometry is not None:
            self.odometry.reset()
