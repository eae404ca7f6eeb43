"""The attitude at a stamp: slerp, quaternions from rotations, the buffer's refusals (stale, gaps, bad samples)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from roadbev_core.attitude import (
    QUATERNION_NORM_TOL,
    ImuBuffer,
    ImuError,
    ImuStale,
    imu_buffer,
    quaternion_from_rotation,
    slerp,
)
from roadbev_core.config import ImuConfig
from roadbev_core.geometry import Attitude, quaternion_to_rotation, rotation_from_rpy

MS = 1_000_000


def axis_quat(axis: int, angle: float) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a rotation by ``angle`` about coordinate axis ``axis``."""
    q = np.zeros(4)
    q[axis] = math.sin(angle / 2)
    q[3] = math.cos(angle / 2)
    return q


def hamilton(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Quaternion product a * b (x, y, z, w order)."""
    av, aw, bv, bw = a[:3], a[3], b[:3], b[3]
    return np.concatenate([aw * bv + bw * av + np.cross(av, bv), [aw * bw - av @ bv]])


def quat_from_rpy(roll: float, pitch: float, yaw: float = 0.0) -> tuple[float, float, float, float]:
    q = hamilton(hamilton(axis_quat(2, yaw), axis_quat(1, pitch)), axis_quat(0, roll))
    return tuple(float(v) for v in q)  # type: ignore[return-value]


def test_quat_helper_matches_geometry() -> None:
    np.testing.assert_allclose(
        quaternion_to_rotation(*quat_from_rpy(0.1, -0.2, 0.3)), rotation_from_rpy(0.1, -0.2, 0.3), atol=1e-12
    )


def test_slerp_endpoints_midpoint_and_short_arc() -> None:
    q0 = np.array(quat_from_rpy(0.0, 0.0))
    q1 = np.array(quat_from_rpy(0.0, 0.4))
    np.testing.assert_allclose(slerp(q0, q1, 0.0), q0, atol=1e-15)
    np.testing.assert_allclose(slerp(q0, q1, 1.0), q1, atol=1e-15)
    np.testing.assert_allclose(slerp(q0, q1, 0.5), quat_from_rpy(0.0, 0.2), atol=1e-12)
    # -q1 is the same rotation: interpolation must not take the long way round
    np.testing.assert_allclose(np.abs(slerp(q0, -q1, 0.5)), np.abs(quat_from_rpy(0.0, 0.2)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(slerp(q0, q1, 0.3)), 1.0)
    # nearly parallel samples (a 100 Hz IMU) take the normalised-lerp branch: still on the arc
    q2 = np.array(quat_from_rpy(0.0, 1e-4))
    np.testing.assert_allclose(slerp(q0, q2, 0.5), quat_from_rpy(0.0, 5e-5), atol=1e-14)


@pytest.mark.parametrize(
    "rpy", [(0.0, 0.0, 0.0), (0.1, -0.2, 0.3), (3.0, 0.1, -2.0), (0.0, 0.0, math.pi), (1.5, 1.4, 0.2)]
)
def test_quaternion_from_rotation_inverts_quaternion_to_rotation(rpy: tuple[float, float, float]) -> None:
    R = rotation_from_rpy(*rpy)
    q = quaternion_from_rotation(R)
    assert q[3] >= 0.0
    np.testing.assert_allclose(quaternion_to_rotation(*q), R, atol=1e-12)


def test_one_norm_tolerance_for_every_sample() -> None:
    buf = ImuBuffer()
    buf.add(1_000 * MS, (0.0, 0.0, 0.0, 1.0 + 0.5 * QUATERNION_NORM_TOL))  # float32 round-off passes
    with pytest.raises(ImuError, match="not a unit quaternion"):
        buf.add(1_010 * MS, (0.0, 0.0, 0.0, 1.0 + 2.0 * QUATERNION_NORM_TOL))
    assert len(buf) == 1


def test_interpolates_a_changing_attitude_to_the_image_stamp() -> None:
    buf = ImuBuffer(max_age_s=0.05, max_gap_s=0.05)
    # pitch ramps 0.01 rad per 10 ms sample, roll constant, with yaw that must be ignored
    for k in range(20):
        buf.add(1_000 * MS + k * 10 * MS, quat_from_rpy(0.02, 0.01 * k, 0.5))
    att = buf.attitude_at(1_000 * MS + 73 * MS)
    assert att.pitch == pytest.approx(0.073, abs=1e-4)
    assert att.roll == pytest.approx(0.02, abs=1e-6)


def test_holds_the_edge_sample_within_max_age_then_refuses() -> None:
    buf = ImuBuffer(max_age_s=0.05)
    buf.add(1_000 * MS, quat_from_rpy(0.0, 0.1))
    buf.add(1_010 * MS, quat_from_rpy(0.0, 0.1))
    assert buf.attitude_at(1_050 * MS).pitch == pytest.approx(0.1)
    assert buf.attitude_at(975 * MS).pitch == pytest.approx(0.1)
    with pytest.raises(ImuStale, match="newer than"):
        buf.attitude_at(1_100 * MS)
    with pytest.raises(ImuStale, match="older than"):
        buf.attitude_at(900 * MS)


def test_refuses_across_an_imu_gap() -> None:
    buf = ImuBuffer(max_age_s=0.05, max_gap_s=0.05)
    buf.add(1_000 * MS, quat_from_rpy(0.0, 0.0))
    buf.add(1_300 * MS, quat_from_rpy(0.0, 0.3))
    with pytest.raises(ImuStale, match="gap"):
        buf.attitude_at(1_150 * MS)


def test_empty_buffer_refuses() -> None:
    with pytest.raises(ImuStale, match="no IMU"):
        ImuBuffer().attitude_at(1)


@pytest.mark.parametrize(
    "q", [(math.nan, 0.0, 0.0, 1.0), (0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 2.0), (0.0, math.inf, 0.0, 1.0)]
)
def test_bad_samples_are_refused_and_do_not_enter(q: tuple[float, float, float, float]) -> None:
    buf = ImuBuffer()
    with pytest.raises(ImuError):
        buf.add(1_000 * MS, q)
    assert len(buf) == 0


def test_out_of_order_samples_are_sorted_and_history_is_bounded() -> None:
    buf = ImuBuffer(horizon_s=0.5, max_gap_s=0.05)
    buf.add(1_020 * MS, quat_from_rpy(0.0, 0.02))
    buf.add(1_000 * MS, quat_from_rpy(0.0, 0.0))
    buf.add(1_010 * MS, quat_from_rpy(0.0, 0.01))
    assert buf.attitude_at(1_015 * MS).pitch == pytest.approx(0.015, abs=1e-6)
    for k in range(200):
        buf.add(2_000 * MS + k * 10 * MS, quat_from_rpy(0.0, 0.0))
    assert len(buf) <= 51
    assert buf.newest_ns == 2_000 * MS + 199 * 10 * MS
    assert buf.age_s(buf.newest_ns + 250 * MS) == pytest.approx(0.25)


def test_imu_to_camera_rotation_is_applied() -> None:
    buf = ImuBuffer(imu_to_camera_rpy_deg=(0.0, 5.0, 0.0))
    buf.add(1_000 * MS, quat_from_rpy(0.0, 0.0))
    assert buf.attitude_at(1_000 * MS).degrees == pytest.approx(Attitude.from_degrees(0.0, 5.0).degrees)


def test_a_clock_jump_back_restarts_the_history() -> None:
    buf = ImuBuffer(jump_back_s=1.0, max_gap_s=0.05)
    for k in range(10):
        buf.add(10_000 * MS + k * 10 * MS, quat_from_rpy(0.0, 0.3))
    buf.add(1_000 * MS, quat_from_rpy(0.0, 0.1))  # nine seconds back: a bag started again
    buf.add(1_010 * MS, quat_from_rpy(0.0, 0.1))
    assert len(buf) == 2 and buf.newest_ns == 1_010 * MS
    assert buf.attitude_at(1_005 * MS).pitch == pytest.approx(0.1)
    buf.add(1_005 * MS, quat_from_rpy(0.0, 0.1))  # slightly out of order is not a jump
    assert len(buf) == 3


def test_the_buffer_follows_the_imu_config() -> None:
    config = ImuConfig(max_age_s=0.05, buffer_s=0.5, imu_to_camera_rpy_deg=(0.0, 5.0, 0.0))
    buf = imu_buffer(config)
    assert (buf.max_age_s, buf.max_gap_s, buf.horizon_s) == (0.05, 0.05, 0.5)
    assert buf.imu_to_camera_rpy_deg == (0.0, 5.0, 0.0)
    assert imu_buffer(config, whole_history=True).horizon_s == math.inf
    # a parameter change at run time keeps the samples
    buf.add(1_000 * MS, quat_from_rpy(0.0, 0.0))
    buf.configure(ImuConfig(max_age_s=0.2))
    assert len(buf) == 1 and (buf.max_age_s, buf.max_gap_s, buf.horizon_s) == (0.2, 0.2, ImuConfig().buffer_s)
    assert buf.attitude_at(1_150 * MS).degrees == pytest.approx(Attitude.from_degrees(0.0, 0.0).degrees)
