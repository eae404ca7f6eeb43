"""The left camera's mount on the body from ``/tf_static``, without ROS.

``base_link`` -> the left camera from ``/tf_static`` (through any chain of frames, every static
broadcaster's message kept, a later transform to a child replacing an earlier one, as tf2's
buffer does) wins over ``vehicle.camera_position_m``. The camera's frame is the left images'
``frame_id``; the mount is handed to the pipeline whenever the two frames are joined by a
transform it has not taken yet.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any, Protocol

import numpy as np

from msg_bridge.tf import StaticTransform, camera_mount, transforms_from_tf
from roadbev_core.errors import RoadbevError

__all__ = ["CameraMount", "MountTaker"]


class MountTaker(Protocol):
    """What takes the mount: :meth:`roadbev_core.pipeline.Pipeline.set_camera_mount`."""

    def set_camera_mount(self, position: Iterable[float], R_base_optical: np.ndarray) -> None: ...


class CameraMount:
    """The static transforms seen and the camera mount applied from them.

    Args:
        pipeline: takes the mount (may refuse it with a :class:`RoadbevError`).
        base_frame: the vehicle body's frame (``base_frame``).
        info: writes an info line to the log.
        report: ``report(kind, reason)``: a problem for the diagnostics and the log.
    """

    def __init__(self, pipeline: MountTaker, base_frame: str, info: Callable[[str], object],
                 report: Callable[[str, str], None]) -> None:
        self._pipeline = pipeline
        self._base = base_frame
        self._info = info
        self._report = report
        self._static: dict[str, StaticTransform] = {}  # child frame -> its /tf_static transform
        self.camera_frame: str | None = None  # the left images' frame_id (the TF's parent)
        self._applied: tuple[bytes, bytes] | None = None  # the mount applied last

    def add_static(self, msg: Any) -> None:
        """A ``tf2_msgs/TFMessage`` of ``/tf_static`` (a malformed one is reported and left out)."""
        try:
            self._static.update((tf.child, tf) for tf in transforms_from_tf(msg))
        except RoadbevError as exc:
            self._report("bad tf", str(exc))
            return
        self._apply()

    def see_frame(self, frame_id: str) -> None:
        """The frame_id of a left image (an empty one says nothing)."""
        if frame_id and frame_id != self.camera_frame:
            self.camera_frame = frame_id
            self._apply()

    def _apply(self) -> None:
        if self.camera_frame is None:
            return
        base = self._base
        mount = camera_mount(list(self._static.values()), base, self.camera_frame)
        if mount is None:
            return  # not joined (yet): vehicle.camera_position_m stands
        translation, rotation = mount
        key = (translation.tobytes(), rotation.tobytes())
        if key == self._applied:
            return
        try:
            self._pipeline.set_camera_mount(translation, rotation)
        except RoadbevError as exc:
            self._report("bad tf", f"{base} -> {self.camera_frame}: {exc}")
            return
        self._applied = key
        self._info(f"camera mount from /tf_static: {base} -> {self.camera_frame} at "
                   f"{[round(float(v), 3) for v in translation]} m")
