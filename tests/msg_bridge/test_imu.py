"""Imu -> orientation and attitude with the extrinsic, malformed orientations.

Interpolation to an image stamp is tested in tests/roadbev_core/test_attitude.py.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from msg_bridge import MessageError, MessageFactory, bag_factory
from msg_bridge.imu import attitude_from_imu, imu_message, imu_orientation

from ._msg_bridge_fakes import quaternion_xyzw


def _imu(factory: MessageFactory, roll: float, pitch: float, yaw: float = 0.0, stamp_ns: int = 0) -> Any:
    return imu_message(factory, stamp_ns=stamp_ns, orientation_xyzw=quaternion_xyzw(roll, pitch, yaw))


def test_roll_and_pitch_are_read_and_yaw_dropped(factory: MessageFactory) -> None:
    attitude = attitude_from_imu(_imu(factory, 0.05, 0.12, yaw=2.5))
    assert attitude.roll == pytest.approx(0.05, abs=1e-12)
    assert attitude.pitch == pytest.approx(0.12, abs=1e-12)


def test_extrinsic_pitch_adds_to_the_imu_pitch(factory: MessageFactory) -> None:
    # Camera pitched 3 deg down relative to a level IMU: the camera's pitch is +3 deg.
    attitude = attitude_from_imu(_imu(factory, 0.0, 0.0), imu_to_camera_rpy_deg=(0.0, 3.0, 0.0))
    assert attitude.degrees == pytest.approx((0.0, 3.0), abs=1e-9)


@pytest.mark.parametrize(
    ("xyzw", "message"),
    [
        ((0.0, 0.0, 0.0, 0.0), "not a unit quaternion"),
        ((0.0, 0.0, 0.0, 2.0), "not a unit quaternion"),
        ((math.nan, 0.0, 0.0, 1.0), "finite"),
        ((0.0, math.inf, 0.0, 1.0), "finite"),
    ],
)
def test_bad_quaternions_raise_message_error(xyzw: tuple[float, ...], message: str) -> None:
    factory = bag_factory()
    msg = _imu(factory, 0.0, 0.0)
    msg.orientation = factory.new("geometry_msgs/msg/Quaternion", x=xyzw[0], y=xyzw[1], z=xyzw[2], w=xyzw[3])
    with pytest.raises(MessageError, match=message):
        attitude_from_imu(msg)


def test_imu_without_orientation_is_refused() -> None:
    msg = _imu(bag_factory(), 0.0, 0.0)
    msg.orientation_covariance = np.array([-1.0] + [0.0] * 8)
    with pytest.raises(MessageError, match="no orientation"):
        imu_orientation(msg)


def test_upside_down_camera_gives_message_error(factory: MessageFactory) -> None:
    with pytest.raises(MessageError, match="no usable attitude"):
        attitude_from_imu(_imu(factory, 0.0, math.pi / 2))


def test_quaternion_helper_of_the_tests_matches_the_rotation() -> None:
    from roadbev_core.geometry import quaternion_to_rotation, rotation_from_rpy

    R = quaternion_to_rotation(*quaternion_xyzw(0.1, -0.2, 0.3))
    np.testing.assert_allclose(R, rotation_from_rpy(0.1, -0.2, 0.3), atol=1e-12)
