"""``sensor_msgs/Imu`` <-> orientation quaternions (the attitude maths is :mod:`roadbev_core.attitude`).

The interface (docs/interface/frames-and-grid.md): ``orientation`` is the IMU body frame (x forward,
y left, z up) relative to a gravity aligned ENU frame; only roll and pitch are used;
``imu_to_camera_rpy_deg`` is the rotation from the IMU body frame to the camera body frame (see
:func:`roadbev_core.geometry.attitude_from_quaternion`). The attitude at an image stamp is
interpolated by :class:`roadbev_core.attitude.ImuBuffer`, for the node and the bag readers alike.
"""

from __future__ import annotations

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
)
from roadbev_core.attitude import ImuError, unit_quaternion
from roadbev_core.geometry import Attitude, GeometryError, attitude_from_quaternion

__all__ = [
    "attitude_from_imu",
    "imu_message",
    "imu_orientation",
]


def _unit_quaternion(values: Sequence[Any] | np.ndarray, what: str) -> np.ndarray:
    try:
        return unit_quaternion([as_float(v, what) for v in values], what)
    except ImuError as exc:
        raise MessageError(str(exc)) from None


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


def attitude_from_imu(msg: Any, imu_to_camera_rpy_deg: Sequence[float] = (0.0, 0.0, 0.0)) -> Attitude:
    """Camera roll and pitch from one Imu message.

    Raises:
        MessageError: a malformed orientation, or one that gives no usable attitude.
    """
    x, y, z, w = (float(v) for v in imu_orientation(msg))
    rpy = (float(imu_to_camera_rpy_deg[0]), float(imu_to_camera_rpy_deg[1]), float(imu_to_camera_rpy_deg[2]))
    try:
        return attitude_from_quaternion(x, y, z, w, imu_to_camera_rpy_deg=rpy)
    except GeometryError as exc:
        raise MessageError(f"Imu orientation gives no usable attitude: {exc}") from None


def imu_message(
    factory: MessageFactory,
    *,
    stamp_ns: int,
    orientation_xyzw: Sequence[float] | np.ndarray,
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
