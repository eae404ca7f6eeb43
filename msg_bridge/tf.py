"""``tf2_msgs/TFMessage`` and ``nav_msgs/Odometry`` <-> numpy, and a static transform tree.

A transform ``parent -> child`` (``TransformStamped``: ``header.frame_id`` = parent,
``child_frame_id`` = child) is the pose of the child frame in the parent frame: a point given in
the child frame is ``p_parent = R @ p_child + t``. :class:`TransformTree` chains such transforms
through their common ancestor, as tf2 does for ``/tf_static`` (the offline evaluation's camera
mount); :class:`msg_bridge.tf_buffer.TransformBuffer` is the node's tf2 buffer, ``/tf`` over time
included.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any, NamedTuple

import numpy as np

from msg_bridge._common import MessageError, MessageFactory, as_float, as_str, field, make_header, stamp_from_header
from roadbev_core.attitude import quaternion_from_rotation
from roadbev_core.geometry import GeometryError, quaternion_to_rotation

__all__ = [
    "OdometryPose",
    "StaticTransform",
    "TransformError",
    "TransformTree",
    "camera_mount",
    "odometry_message",
    "odometry_pose",
    "odometry_tf",
    "stamped_transforms_from_tf",
    "tf_message",
    "transforms_from_tf",
]


class TransformError(MessageError):
    """A transform that cannot be looked up (frames not connected) or is malformed."""


class StaticTransform(NamedTuple):
    """``parent -> child``: ``p_parent = rotation @ p_child + translation``."""

    parent: str
    child: str
    rotation: np.ndarray  # [3, 3]
    translation: np.ndarray  # [3]


def transforms_from_tf(msg: Any) -> list[StaticTransform]:
    """The transforms of a ``tf2_msgs/TFMessage`` (their stamps left out: ``/tf_static``).

    Raises:
        TransformError: a transform without frame names or with a non-unit rotation.
    """
    return [_transform(ts, i) for i, ts in enumerate(field(msg, "transforms"))]


def stamped_transforms_from_tf(msg: Any) -> list[tuple[int, StaticTransform]]:
    """The transforms of a ``tf2_msgs/TFMessage`` with their stamps (ns): ``/tf``.

    Raises:
        MessageError: a transform without frame names, with a non-unit rotation or a bad stamp
            (:class:`TransformError` for the first two).
    """
    return [(stamp_from_header(ts), _transform(ts, i)) for i, ts in enumerate(field(msg, "transforms"))]


def _transform(ts: Any, i: int) -> StaticTransform:
    """The ``i``-th ``geometry_msgs/TransformStamped`` of a message, without its stamp."""
    parent = as_str(field(field(ts, "header"), "frame_id"), f"transform {i} header.frame_id").lstrip("/")
    child = as_str(field(ts, "child_frame_id"), f"transform {i} child_frame_id").lstrip("/")
    if not parent or not child:
        raise TransformError(f"transform {i} lacks a parent or child frame name")
    tf = field(ts, "transform")
    t, q = field(tf, "translation"), field(tf, "rotation")
    translation = np.array([as_float(field(t, k), f"transform {i} translation.{k}") for k in "xyz"])
    quat = [as_float(field(q, k), f"transform {i} rotation.{k}") for k in "xyzw"]
    if not np.all(np.isfinite(translation)):
        raise TransformError(f"transform {parent} -> {child} has a non-finite translation")
    try:
        rotation = quaternion_to_rotation(*quat)
    except GeometryError as exc:
        raise TransformError(f"transform {parent} -> {child}: {exc}") from None
    return StaticTransform(parent, child, rotation, translation)


def tf_message(transforms: Iterable[StaticTransform], factory: MessageFactory, *, stamp_ns: int = 0) -> Any:
    """A ``tf2_msgs/TFMessage`` (e.g. for ``/tf_static``) holding ``transforms``."""
    items = []
    for tf in transforms:
        x, y, z, w = (float(v) for v in quaternion_from_rotation(tf.rotation))
        tx, ty, tz = (float(v) for v in tf.translation)
        items.append(
            factory.new(
                "geometry_msgs/msg/TransformStamped",
                header=make_header(factory, stamp_ns, tf.parent),
                child_frame_id=tf.child,
                transform=factory.new(
                    "geometry_msgs/msg/Transform",
                    translation=factory.new("geometry_msgs/msg/Vector3", x=tx, y=ty, z=tz),
                    rotation=factory.new("geometry_msgs/msg/Quaternion", x=x, y=y, z=z, w=w),
                ),
            )
        )
    return factory.new("tf2_msgs/msg/TFMessage", transforms=items)


class TransformTree:
    """Static transforms, looked up between any two connected frames."""

    def __init__(self, transforms: Iterable[StaticTransform] = ()) -> None:
        self._parent: dict[str, StaticTransform] = {}
        for tf in transforms:
            self.add(tf)

    def add(self, tf: StaticTransform) -> None:
        """Add (or replace) the transform to ``tf.child`` from its parent."""
        self._parent[tf.child] = tf

    @property
    def frames(self) -> set[str]:
        return set(self._parent) | {tf.parent for tf in self._parent.values()}

    def _to_root(self, frame: str) -> tuple[list[str], np.ndarray, np.ndarray]:
        """Chain of frames from ``frame`` to its root and ``p_root = R @ p_frame + t``."""
        chain = [frame]
        R, t = np.eye(3), np.zeros(3)
        while chain[-1] in self._parent:
            tf = self._parent[chain[-1]]
            if tf.parent in chain:
                raise TransformError(f"the transforms loop through {tf.parent}")
            R, t = tf.rotation @ R, tf.rotation @ t + tf.translation
            chain.append(tf.parent)
        return chain, R, t

    def lookup(self, target: str, source: str) -> tuple[np.ndarray, np.ndarray]:
        """``(R, t)`` with ``p_target = R @ p_source + t``.

        Raises:
            TransformError: the two frames are not connected by the transforms held.
        """
        target, source = target.lstrip("/"), source.lstrip("/")
        if target == source:
            return np.eye(3), np.zeros(3)
        src_chain, R_s, t_s = self._to_root(source)
        tgt_chain, R_t, t_t = self._to_root(target)
        if src_chain[-1] != tgt_chain[-1]:
            known = ", ".join(sorted(self.frames)) or "none"
            raise TransformError(f"no transform from {source!r} to {target!r} (frames known: {known})")
        # Both to the common root, then back from the root to the target.
        R = R_t.T @ R_s
        return R, R_t.T @ (t_s - t_t)


def camera_mount(transforms: Iterable[StaticTransform], base_frame: str,
                 camera_frame: str) -> tuple[np.ndarray, np.ndarray] | None:
    """The camera's pose in the body from static transforms, through any chain of frames as tf2
    joins them (``base_link`` -> ``camera_link`` -> the optical frame): ``(translation [3],
    rotation [3, 3])`` with ``p_base = rotation @ p_camera + translation``; None when the
    transforms do not join the two frames (or loop). A later transform to a child replaces an
    earlier one, as on ``/tf_static``."""
    try:
        rotation, translation = TransformTree(transforms).lookup(base_frame, camera_frame)
    except TransformError:
        return None
    return translation, rotation


class OdometryPose(NamedTuple):
    """The planar pose of an Odometry message: ``child_frame_id`` in ``header.frame_id``."""

    stamp_ns: int
    x: float
    y: float
    yaw: float
    frame_id: str
    child_frame_id: str


def odometry_pose(msg: Any) -> OdometryPose:
    """Planar pose (x, y, yaw) of a ``nav_msgs/Odometry``.

    Raises:
        MessageError: non-finite position or a non-unit orientation.
    """
    stamp = stamp_from_header(msg)
    pose = field(field(msg, "pose"), "pose")
    pos, q = field(pose, "position"), field(pose, "orientation")
    x, y = as_float(field(pos, "x"), "Odometry position.x"), as_float(field(pos, "y"), "Odometry position.y")
    if not (math.isfinite(x) and math.isfinite(y)):
        raise MessageError(f"Odometry at {stamp} ns has a non-finite position")
    try:
        R = quaternion_to_rotation(*(as_float(field(q, k), f"Odometry orientation.{k}") for k in "xyzw"))
    except GeometryError as exc:
        raise MessageError(f"Odometry at {stamp} ns: {exc}") from None
    frame = as_str(field(field(msg, "header"), "frame_id"), "Odometry header.frame_id")
    child = as_str(field(msg, "child_frame_id"), "Odometry child_frame_id")
    return OdometryPose(stamp, x, y, math.atan2(R[1, 0], R[0, 0]), frame, child)


def odometry_tf(msg: Any, factory: MessageFactory) -> Any:
    """The pose of a ``nav_msgs/Odometry`` as a ``tf2_msgs/TFMessage``: ``header.frame_id`` ->
    ``child_frame_id`` (``odom`` -> ``base_link``) at its stamp, in 3-D, as an odometry source that
    publishes its TF (robot_localization's ``publish_tf``) broadcasts it.

    Raises:
        MessageError: no frame names, a non-finite position or a non-unit orientation.
    """
    stamp = stamp_from_header(msg)
    parent = as_str(field(field(msg, "header"), "frame_id"), "Odometry header.frame_id").lstrip("/")
    child = as_str(field(msg, "child_frame_id"), "Odometry child_frame_id").lstrip("/")
    if not parent or not child:
        raise MessageError(f"Odometry at {stamp} ns lacks header.frame_id or child_frame_id")
    pose = field(field(msg, "pose"), "pose")
    pos, q = field(pose, "position"), field(pose, "orientation")
    translation = np.array([as_float(field(pos, k), f"Odometry position.{k}") for k in "xyz"])
    if not np.all(np.isfinite(translation)):
        raise MessageError(f"Odometry at {stamp} ns has a non-finite position")
    try:
        rotation = quaternion_to_rotation(*(as_float(field(q, k), f"Odometry orientation.{k}") for k in "xyzw"))
    except GeometryError as exc:
        raise MessageError(f"Odometry at {stamp} ns: {exc}") from None
    return tf_message([StaticTransform(parent, child, rotation, translation)], factory, stamp_ns=stamp)


def odometry_message(
    factory: MessageFactory,
    *,
    stamp_ns: int,
    position: Sequence[float] | np.ndarray,
    orientation_xyzw: Sequence[float] | np.ndarray,
    linear_velocity: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0),
    angular_velocity: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0),
    pose_covariance: np.ndarray | None = None,
    twist_covariance: np.ndarray | None = None,
    frame_id: str = "odom",
    child_frame_id: str = "base_link",
) -> Any:
    """A ``nav_msgs/Odometry``: pose in ``frame_id``, twist in the child frame (REP-105);
    covariances zero (unknown) unless given ([36] row-major)."""

    def vec(v: Sequence[float] | np.ndarray) -> Any:
        return factory.new("geometry_msgs/msg/Vector3", x=float(v[0]), y=float(v[1]), z=float(v[2]))

    p, q = position, orientation_xyzw
    pose = factory.new(
        "geometry_msgs/msg/Pose",
        position=factory.new("geometry_msgs/msg/Point", x=float(p[0]), y=float(p[1]), z=float(p[2])),
        orientation=factory.new("geometry_msgs/msg/Quaternion", x=float(q[0]), y=float(q[1]), z=float(q[2]),
                                w=float(q[3])),
    )
    zeros = np.zeros(36)
    return factory.new(
        "nav_msgs/msg/Odometry",
        header=make_header(factory, stamp_ns, frame_id),
        child_frame_id=child_frame_id,
        pose=factory.new("geometry_msgs/msg/PoseWithCovariance", pose=pose,
                         covariance=np.asarray(zeros if pose_covariance is None else pose_covariance, np.float64)),
        twist=factory.new(
            "geometry_msgs/msg/TwistWithCovariance",
            twist=factory.new("geometry_msgs/msg/Twist", linear=vec(linear_velocity), angular=vec(angular_velocity)),
            covariance=np.asarray(zeros if twist_covariance is None else twist_covariance, np.float64),
        ),
    )
