"""The left camera's mount on the body from TF, without ROS.

``base_link`` -> the left camera, looked up in the node's tf2 buffer
(:class:`msg_bridge.tf_buffer.TransformBuffer`: ``/tf_static`` and ``/tf``, through any chain of
frames) at each left image's stamp, wins over ``vehicle.camera_position_m``. The camera's frame
is the left images' ``frame_id``. A chain of ``/tf_static`` transforms is applied as soon as it
joins the two frames; a chain with ``/tf`` links (a camera on a moving bracket) is looked up at
every frame's stamp. The mount is handed to the pipeline whenever it changes.

When the lookup fails although TF is meant to place the camera (a transform has the camera's
frame as its child, or a mount was taken from TF before), the frame goes on with the mount it has and the
failure is reported as ``tf missing``, naming the frames, tf2's reason and that mount.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import Protocol

import numpy as np

from msg_bridge.tf import TransformError
from msg_bridge.tf_buffer import TransformBuffer
from roadbev_core.errors import RoadbevError

__all__ = ["CameraMount", "MountTaker"]


class MountTaker(Protocol):
    """What takes the mount: :meth:`roadbev_core.pipeline.Pipeline.set_camera_mount`."""

    def set_camera_mount(self, position: Iterable[float], R_base_optical: np.ndarray) -> None: ...


def _metres(translation: np.ndarray) -> str:
    return f"{[round(float(v), 3) for v in translation]} m"


class CameraMount:
    """The camera mount applied from the TF buffer.

    Args:
        pipeline: takes the mount (may refuse it with a :class:`RoadbevError`).
        buffer: the node's transforms.
        base_frame: the vehicle body's frame (``base_frame``).
        configured: ``vehicle.camera_position_m`` now (the mount until TF gives one).
        info: writes an info line to the log.
        report: ``report(kind, reason)``: a problem for the diagnostics and the log.
    """

    def __init__(self, pipeline: MountTaker, buffer: TransformBuffer, base_frame: str,
                 configured: Callable[[], Sequence[float]], info: Callable[[str], object],
                 report: Callable[[str, str], None]) -> None:
        self._pipeline = pipeline
        self._buffer = buffer
        self._base = base_frame
        self._configured = configured
        self._info = info
        self._report = report
        self.camera_frame: str | None = None  # the left images' frame_id (the TF's parent)
        self._applied: tuple[bytes, bytes] | None = None  # the mount applied last
        self._source = ""  # where it came from: "/tf_static" or "/tf"
        self._translation = np.zeros(3)  # the position of the mount applied last

    def transforms_changed(self) -> None:
        """New ``/tf_static`` transforms: a chain of them is applied at once (a chain with ``/tf``
        links waits for a frame's stamp; a chain not joined yet says nothing: more may come)."""
        self._apply(None, report_missing=False)

    def see_frame(self, frame_id: str, stamp_ns: int) -> None:
        """A left image: its frame_id (an empty one says nothing) and stamp, at which the mount is
        looked up."""
        if frame_id:
            self.camera_frame = frame_id
        self._apply(stamp_ns, report_missing=True)

    def state(self) -> str:
        """Where the mount comes from, in a few words (for the diagnostics)."""
        if self._applied is not None:
            return f"{self._source} {self._base} -> {self.camera_frame} at {_metres(self._translation)}"
        joined = f"no TF joins {self._base} and {self.camera_frame}" if self.camera_frame else "no image yet"
        return f"vehicle.camera_position_m {list(self._configured())} ({joined})"

    def _needed(self) -> bool:
        """Whether TF is meant to place the camera: a transform places its frame, or one did."""
        return self._applied is not None or (self.camera_frame is not None
                                             and self._buffer.parent(self.camera_frame) is not None)

    def _apply(self, stamp_ns: int | None, *, report_missing: bool) -> None:
        camera, base = self.camera_frame, self._base
        if camera is None:
            return
        try:
            links = self._buffer.links(base, camera, stamp_ns)
            if stamp_ns is None and not all(link.static for link in links):
                return  # a chain through /tf is looked up at the frames' stamps
            rotation, translation = self._buffer.lookup(base, camera, stamp_ns)
        except TransformError as exc:
            if report_missing and self._needed():
                keeps = (f"the mount last taken from {self._source} ({_metres(self._translation)})"
                         if self._applied is not None else f"vehicle.camera_position_m {list(self._configured())}")
                self._report("tf missing", f"no transform {base} -> {camera} for the camera mount: {exc}; the frame "
                             f"goes on with {keeps}")
            return
        key = (translation.tobytes(), rotation.tobytes())
        if key == self._applied:
            return
        try:
            self._pipeline.set_camera_mount(translation, rotation)
        except RoadbevError as exc:
            self._report("bad tf", f"{base} -> {camera}: {exc}")
            return
        source = "/tf_static" if all(link.static for link in links) else "/tf"
        if source == "/tf_static" or source != self._source:  # a mount moving on /tf is logged once
            self._info(f"camera mount from {source}: {base} -> {camera} at {_metres(translation)}")
        self._applied, self._source, self._translation = key, source, translation
