"""``sensor_msgs/Imu`` -> camera attitude (roll, pitch), with slerp between two samples.

Contract: ``orientation`` is the IMU body frame (x forward, y left, z up) relative to a gravity
aligned ENU frame; only roll and pitch are used; ``imu_to_camera_rpy_deg`` is the rotation from
the IMU body frame to the camera body frame (see
:func:`roadbev_core.geometry.attitude_from_quaternion`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from msg_bridge._common import (
    MessageError,
    MessageFactory,
    as_float,
    buffer_view,
    field,
    make_header,
    stamp_from_header,
)
from roadbev_core.geometry import Attitude, GeometryError, attitude_from_quaternion

__all__ = [
    "QUATERNION_NORM_TOL",
    "attitude_at",
    "attitude_from_imu",
    "imu_message",
    "imu_orientation",
    "interpolate_orientation",
    "slerp",
]

# How far from 1 the norm of an orientation quaternion may be (float32 round-off passes).
QUATERNION_NORM_TOL = 1e-3


def _unit_quaternion(values: Sequence[float], what: str) -> np.ndarray:
    q = np.array([as_float(v, what) for v in values], dtype=np.float64)
    with np.errstate(over="ignore"):  # a huge component overflows to inf: not unit, reported below
        norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > QUATERNION_NORM_TOL:
        raise MessageError(f"{what} is not a unit quaternion (norm {norm:.6g})")
    return q / norm


def imu_orientation(msg: Any) -> np.ndarray:
    """[4] unit quaternion (x, y, z, w) of an Imu message's orientation.

    Raises:
        MessageError: NaN/inf or non-unit quaternion, or an ``orientation_covariance[0]`` of
            -1 (REP-145: the IMU does not provide an orientation).
    """
    covariance = buffer_view(field(msg, "orientation_covariance"), np.float64, "Imu.orientation_covariance")
    if covariance.size and covariance[0] == -1.0:
        raise MessageError("Imu has no orientation (orientation_covariance[0] == -1)")
    o = field(msg, "orientation")
    values = [field(o, "x"), field(o, "y"), field(o, "z"), field(o, "w")]
    return _unit_quaternion(values, "Imu.orientation")


def _attitude(q: np.ndarray, imu_to_camera_rpy_deg: Sequence[float]) -> Attitude:
    try:
        return attitude_from_quaternion(*(float(v) for v in q), imu_to_camera_rpy_deg=tuple(imu_to_camera_rpy_deg))
    except GeometryError as exc:
        raise MessageError(f"Imu orientation gives no usable attitude: {exc}") from None


def attitude_from_imu(msg: Any, imu_to_camera_rpy_deg: Sequence[float] = (0.0, 0.0, 0.0)) -> Attitude:
    """Camera roll and pitch from one Imu message."""
    return _attitude(imu_orientation(msg), imu_to_camera_rpy_deg)


def slerp(q0: np.ndarray, q1: np.ndarray, t: float) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (x, y, z, w) along the shorter arc.

    Args:
        q0, q1: [4] unit quaternions; t: 0 gives q0, 1 gives q1 (values outside extrapolate).
    """
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    dot = float(np.dot(q0, q1))
    if dot < 0.0:  # q and -q are the same rotation: take the shorter way round
        q1, dot = -q1, -dot
    if dot > 0.9995:  # nearly parallel: normalised lerp is exact to float precision
        q = q0 + t * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = math.acos(min(dot, 1.0))
    sin_theta = math.sin(theta)
    q = (math.sin((1.0 - t) * theta) * q0 + math.sin(t * theta) * q1) / sin_theta
    return q / np.linalg.norm(q)


def interpolate_orientation(
    stamp0_ns: int, q0: np.ndarray, stamp1_ns: int, q1: np.ndarray, stamp_ns: int
) -> np.ndarray:
    """[4] orientation at ``stamp_ns`` by slerp between two stamped samples."""
    if stamp1_ns == stamp0_ns:
        return np.asarray(q0 if stamp_ns <= stamp0_ns else q1, dtype=np.float64)
    t = (stamp_ns - stamp0_ns) / (stamp1_ns - stamp0_ns)
    return slerp(q0, q1, t)


def attitude_at(
    before: Any,
    after: Any,
    stamp_ns: int,
    imu_to_camera_rpy_deg: Sequence[float] = (0.0, 0.0, 0.0),
) -> Attitude:
    """Camera attitude at ``stamp_ns`` interpolated (slerp) between two Imu messages.

    Raises:
        MessageError: a malformed orientation, or samples in the wrong time order.
    """
    t0, t1 = stamp_from_header(before), stamp_from_header(after)
    if t1 < t0:
        raise MessageError(f"Imu samples out of order ({t0} ns after {t1} ns)")
    q = interpolate_orientation(t0, imu_orientation(before), t1, imu_orientation(after), stamp_ns)
    return _attitude(q, imu_to_camera_rpy_deg)


def imu_message(
    factory: MessageFactory,
    *,
    stamp_ns: int,
    orientation_xyzw: Sequence[float],
    angular_velocity: Sequence[float] = (0.0, 0.0, 0.0),
    linear_acceleration: Sequence[float] = (0.0, 0.0, 9.81),
    frame_id: str = "imu_link",
) -> Any:
    """A ``sensor_msgs/Imu``; covariances are left unknown (zeros) as REP-145 allows."""
    q = _unit_quaternion(orientation_xyzw, "orientation")
    x, y, z, w = (float(v) for v in q)
    return factory.new(
        "sensor_msgs/msg/Imu",
        header=make_header(factory, stamp_ns, frame_id),
        orientation=factory.new("geometry_msgs/msg/Quaternion", x=x, y=y, z=z, w=w),
        angular_velocity=factory.new("geometry_msgs/msg/Vector3", **_xyz(angular_velocity)),
        linear_acceleration=factory.new("geometry_msgs/msg/Vector3", **_xyz(linear_acceleration)),
    )


def _xyz(values: Sequence[float]) -> dict[str, float]:
    x, y, z = (float(v) for v in values)
    return {"x": x, "y": y, "z": z}
