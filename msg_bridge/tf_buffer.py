"""A tf2 buffer without ROS: ``/tf_static`` and ``/tf`` transforms, looked up between any two
frames at a stamp.

It follows the semantics of tf2's ``BufferCore`` (the buffer behind ``tf2_ros.Buffer``):

* A transform ``parent -> child`` is the pose of the child in the parent (``p_parent = R @ p_child
  + t``, :mod:`msg_bridge.tf`). Each child frame has one parent at a time, so the frames form a
  forest, and a lookup walks both frames up to their common ancestor.
* ``/tf_static`` transforms are latched and have no time: valid at every stamp. A later one to the
  same child replaces the earlier one (the frame's ``/tf`` history with it).
* ``/tf`` transforms are stamped. Each child frame keeps its samples of the last ``cache_time_s``
  counted from its newest one (tf2's default: 10 s); a sample older than that is refused, as tf2
  ignores "data from the past". A link that stops being published keeps its last samples, so a
  lookup after them reports the extrapolation it would need instead of answering with old data.
* A lookup at a stamp interpolates each ``/tf`` link between its samples around the stamp
  (translation linear, rotation slerp). A stamp beyond the first or last sample is refused as an
  extrapolation into the past or the future, unless it lies within ``tolerance_s`` of it: then
  that sample is used as it is (held, never extrapolated). tf2 has no such tolerance; it lets a
  frame whose transforms arrive a little after it be used without waiting.
* A lookup without a stamp (tf2's ``Time(0)``) is made at the latest time every ``/tf`` link on
  the way has data for.

Errors say what tf2 says, in the same words where a user would search for them:
:class:`FrameNotFound` (a frame no transform names), :class:`NotConnected` (two trees, or a loop)
and :class:`Extrapolation` (into the past or the future). All are :class:`TransformError`.
The buffer is thread-safe: the node adds transforms from the executor's thread and looks them up
from its worker.
"""

from __future__ import annotations

import bisect
import threading
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from msg_bridge.tf import StaticTransform, TransformError
from roadbev_core.attitude import quaternion_from_rotation, slerp
from roadbev_core.geometry import quaternion_to_rotation

__all__ = [
    "DEFAULT_CACHE_TIME_S",
    "Extrapolation",
    "FrameNotFound",
    "Link",
    "NotConnected",
    "TransformBuffer",
]

DEFAULT_CACHE_TIME_S = 10.0  # tf2's default cache time (BufferCore::DEFAULT_CACHE_TIME)


class FrameNotFound(TransformError):
    """A lookup names a frame that no transform held names (tf2's ``LookupException``)."""


class NotConnected(TransformError):
    """The two frames are in different trees, or the transforms loop (tf2's ``ConnectivityException``)."""


class Extrapolation(TransformError):
    """A ``/tf`` link has no data at the stamp (tf2's ``ExtrapolationException``)."""

    def __init__(self, message: str, *, future: bool) -> None:
        super().__init__(message)
        self.future = future  # True: the data may still come; False: it is older than the buffer holds


class Link(NamedTuple):
    """One transform on a lookup's way."""

    parent: str
    child: str
    static: bool  # from /tf_static (else /tf)


@dataclass
class _Samples:
    """The ``/tf`` samples of one child frame, in stamp order (parallel lists)."""

    stamps: list[int] = field(default_factory=list)
    transforms: list[StaticTransform] = field(default_factory=list)
    quaternions: list[np.ndarray] = field(default_factory=list)  # [4] x, y, z, w of each rotation


def _seconds(stamp_ns: int) -> str:
    return f"{stamp_ns * 1e-9:.6f}"


class TransformBuffer:
    """``/tf_static`` and ``/tf`` transforms and lookups between frames (see the module docstring).

    Args:
        cache_time_s: how long each ``/tf`` link's history reaches back from its newest sample.
        tolerance_s: a stamp this close beyond a link's first or last sample takes that sample.
    """

    def __init__(self, cache_time_s: float = DEFAULT_CACHE_TIME_S, tolerance_s: float = 0.0) -> None:
        if not cache_time_s > 0 or not tolerance_s >= 0:
            raise ValueError(f"cache_time_s must be > 0 and tolerance_s >= 0, got {cache_time_s}, {tolerance_s}")
        self.cache_ns = int(round(cache_time_s * 1e9))
        self.tolerance_ns = int(round(tolerance_s * 1e9))
        self._static: dict[str, StaticTransform] = {}  # child frame -> its transform
        self._dynamic: dict[str, _Samples] = {}  # child frame -> its /tf samples
        self._lock = threading.Lock()

    # --- adding -------------------------------------------------------------------------------
    def add(self, tf: StaticTransform, stamp_ns: int = 0, *, static: bool = False) -> None:
        """One transform: from ``/tf_static`` (``static``: no time) or ``/tf`` at ``stamp_ns``.

        Raises:
            TransformError: a frame as its own parent; a ``/tf`` sample older than the link's cache
                (or to a frame that has a ``/tf_static`` transform): it is not kept.
        """
        if tf.parent == tf.child:
            raise TransformError(f"ignoring the transform {tf.parent} -> {tf.child}: a frame cannot be its own parent")
        with self._lock:
            if static:
                self._static[tf.child] = tf
                self._dynamic.pop(tf.child, None)
                return
            if tf.child in self._static:
                raise TransformError(f"ignoring {tf.parent} -> {tf.child} on /tf: {tf.child} has a /tf_static "
                                     "transform, which holds at every time")
            samples = self._dynamic.setdefault(tf.child, _Samples())
            if samples.stamps and stamp_ns < samples.stamps[-1] - self.cache_ns:
                raise TransformError(
                    f"ignoring data from the past for frame {tf.child} at time {_seconds(stamp_ns)}: older than "
                    f"its newest, {_seconds(samples.stamps[-1])}, by more than the cache time "
                    f"({self.cache_ns * 1e-9:g} s)")
            i = bisect.bisect_left(samples.stamps, stamp_ns)
            quaternion = quaternion_from_rotation(tf.rotation)
            if i < len(samples.stamps) and samples.stamps[i] == stamp_ns:  # the same stamp again: replaced
                samples.transforms[i], samples.quaternions[i] = tf, quaternion
            else:
                samples.stamps.insert(i, stamp_ns)
                samples.transforms.insert(i, tf)
                samples.quaternions.insert(i, quaternion)
            expired = bisect.bisect_left(samples.stamps, samples.stamps[-1] - self.cache_ns)
            if expired:
                del samples.stamps[:expired], samples.transforms[:expired], samples.quaternions[:expired]

    def clear_dynamic(self) -> None:
        """Forget every ``/tf`` sample (time jumped back, as tf2_ros clears its buffer); the static
        transforms stay."""
        with self._lock:
            self._dynamic.clear()

    # --- what is held -------------------------------------------------------------------------
    @property
    def frames(self) -> set[str]:
        """Every frame a transform held names."""
        with self._lock:
            return self._frames()

    def _frames(self) -> set[str]:
        out = set(self._static) | {tf.parent for tf in self._static.values()} | set(self._dynamic)
        for samples in self._dynamic.values():
            out.update(tf.parent for tf in samples.transforms)
        return out

    def parent(self, frame: str, stamp_ns: int | None = None) -> str | None:
        """The parent of ``frame`` at the stamp (None: the latest); None when no transform places
        ``frame`` (a root, or a frame not known)."""
        with self._lock:
            return self._parent(frame.lstrip("/"), stamp_ns)

    # --- lookups ------------------------------------------------------------------------------
    def lookup(self, target: str, source: str, stamp_ns: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(R [3, 3], t [3])`` with ``p_target = R @ p_source + t`` at ``stamp_ns`` (None: the
        latest time the ``/tf`` links on the way all have data for).

        Raises:
            FrameNotFound, NotConnected, Extrapolation: as tf2's lookupTransform.
        """
        target, source = target.lstrip("/"), source.lstrip("/")
        if target == source:
            return np.eye(3), np.zeros(3)
        with self._lock:
            up_source, up_target = self._ways(target, source, stamp_ns)
            if stamp_ns is None:
                stamp_ns = self._latest_common(up_source + up_target)
            R_s, t_s = self._compose(up_source, stamp_ns, target, source)
            R_t, t_t = self._compose(up_target, stamp_ns, target, source)
        # both up to the common ancestor, then back down from it to the target
        return R_t.T @ R_s, R_t.T @ (t_s - t_t)

    def links(self, target: str, source: str, stamp_ns: int | None = None) -> list[Link]:
        """The transforms a lookup from ``source`` to ``target`` goes through: from ``source`` up
        to the common ancestor, then from ``target`` up to it.

        Raises:
            FrameNotFound, NotConnected: as :meth:`lookup`.
        """
        target, source = target.lstrip("/"), source.lstrip("/")
        if target == source:
            return []
        with self._lock:
            up_source, up_target = self._ways(target, source, stamp_ns)
            return [self._link(child, stamp_ns) for child in up_source + up_target]

    def _ways(self, target: str, source: str, stamp_ns: int | None) -> tuple[list[str], list[str]]:
        """The child frames of the links from ``source`` and from ``target`` up to their common ancestor."""
        frames = self._frames()
        for frame, role in ((target, "target"), (source, "source")):
            if frame not in frames:
                raise FrameNotFound(f'"{frame}" passed to lookupTransform argument {role}_frame does not exist')
        from_source = self._to_root(source, stamp_ns)
        from_target = self._to_root(target, stamp_ns)
        on_source_way = {frame: i for i, frame in enumerate(from_source)}
        common = next((i for i, frame in enumerate(from_target) if frame in on_source_way), None)
        if common is None:
            raise NotConnected(f"Could not find a connection between '{target}' and '{source}' because they are "
                               "not part of the same tree (the transforms form two or more unconnected trees)")
        return from_source[:on_source_way[from_target[common]]], from_target[:common]

    def _parent(self, child: str, stamp_ns: int | None) -> str | None:
        """The parent of ``child`` at the stamp (of the sample at or before it; None: a root)."""
        static = self._static.get(child)
        if static is not None:
            return static.parent
        samples = self._dynamic.get(child)
        if samples is None:
            return None
        i = len(samples.stamps) - 1 if stamp_ns is None else bisect.bisect_right(samples.stamps, stamp_ns) - 1
        return samples.transforms[max(i, 0)].parent

    def _to_root(self, frame: str, stamp_ns: int | None) -> list[str]:
        """``frame`` and its ancestors up to its root."""
        way = [frame]
        seen = {frame}
        while (parent := self._parent(way[-1], stamp_ns)) is not None:
            if parent in seen:
                loop = " -> ".join([*way[way.index(parent):], parent])
                raise NotConnected(f"The tf tree is invalid because it contains a loop: {loop}")
            way.append(parent)
            seen.add(parent)
        return way

    def _link(self, child: str, stamp_ns: int | None) -> Link:
        static = self._static.get(child)
        if static is not None:
            return Link(static.parent, child, True)
        parent = self._parent(child, stamp_ns)
        assert parent is not None  # a frame on a way up has a parent
        return Link(parent, child, False)

    def _latest_common(self, children: list[str]) -> int | None:
        """The newest stamp every ``/tf`` link among ``children`` has data for (None: all static)."""
        newest = [self._dynamic[c].stamps[-1] for c in children if c not in self._static]
        return min(newest) if newest else None

    def _compose(self, children: list[str], stamp_ns: int | None, target: str, source: str
                 ) -> tuple[np.ndarray, np.ndarray]:
        """``(R, t)`` from the first frame of the links to the parent of the last."""
        R, t = np.eye(3), np.zeros(3)
        for child in children:
            static = self._static.get(child)
            tf = static if static is not None else self._sample(child, stamp_ns, target, source)
            R, t = tf.rotation @ R, tf.rotation @ t + tf.translation
        return R, t

    def _sample(self, child: str, stamp_ns: int | None, target: str, source: str) -> StaticTransform:
        """The ``/tf`` link to ``child`` at the stamp: interpolated, or the nearest sample within
        the tolerance."""
        samples = self._dynamic[child]
        stamps = samples.stamps
        if stamp_ns is None:
            return samples.transforms[-1]
        i = bisect.bisect_left(stamps, stamp_ns)
        if i < len(stamps) and stamps[i] == stamp_ns:
            return samples.transforms[i]
        if i == 0 or i == len(stamps):
            nearest = 0 if i == 0 else len(stamps) - 1
            where = (f", when looking up transform from frame [{source}] to frame [{target}] (the /tf link "
                     f"{samples.transforms[nearest].parent} -> {child})")
            if abs(stamp_ns - stamps[nearest]) <= self.tolerance_ns:
                return samples.transforms[nearest]
            future = i > 0
            if len(stamps) == 1:
                raise Extrapolation(f"Lookup would require extrapolation at time {_seconds(stamp_ns)}, but only time "
                                    f"{_seconds(stamps[0])} is in the buffer{where}", future=future)
            if future:
                raise Extrapolation(f"Lookup would require extrapolation into the future. Requested time "
                                    f"{_seconds(stamp_ns)} but the latest data is at time {_seconds(stamps[-1])}"
                                    f"{where}", future=True)
            raise Extrapolation(f"Lookup would require extrapolation into the past. Requested time "
                                f"{_seconds(stamp_ns)} but the earliest data is at time {_seconds(stamps[0])}"
                                f"{where}", future=False)
        before, after = samples.transforms[i - 1], samples.transforms[i]
        if before.parent != after.parent:  # the frame moved to another parent between them: no blend
            return before
        w = (stamp_ns - stamps[i - 1]) / (stamps[i] - stamps[i - 1])
        q = slerp(samples.quaternions[i - 1], samples.quaternions[i], w)
        translation = before.translation + w * (after.translation - before.translation)
        return StaticTransform(before.parent, child, quaternion_to_rotation(*q), translation)
