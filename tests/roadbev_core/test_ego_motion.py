"""Ego-motion: interpolation between odometry samples, short extrapolation, dead reckoning."""

from __future__ import annotations

import math

import pytest

from roadbev_core.ego_motion import EgoMotion, EgoMotionError, EgoMotionStale, OdometryJump, PlanarPose

S = 1_000_000_000


def test_pose_between_samples_is_interpolated_with_an_unwrapped_yaw() -> None:
    ego = EgoMotion()
    ego.add(PlanarPose(1 * S, 0.0, 0.0, math.pi - 0.1, 10.0, 0.0))
    ego.add(PlanarPose(1 * S + S // 10, 1.0, 0.5, -math.pi + 0.1, 10.0, 0.0))  # crosses +-pi
    pose = ego.pose_at(1 * S + S // 20)
    assert pose.x == pytest.approx(0.5) and pose.y == pytest.approx(0.25)
    assert pose.yaw == pytest.approx(math.pi)
    assert ego.brackets(1 * S + S // 20) and not ego.brackets(2 * S)


def test_a_stamp_just_past_the_newest_sample_is_extrapolated_with_its_twist() -> None:
    ego = EgoMotion(max_age_s=0.2)
    ego.add(PlanarPose(S, 2.0, 0.0, 0.0, 10.0, 0.0))
    assert ego.pose_at(S + S // 10).x == pytest.approx(3.0)
    with pytest.raises(EgoMotionStale, match="newer than"):
        ego.pose_at(S + S // 2)
    with pytest.raises(EgoMotionStale, match="no odometry"):
        EgoMotion().pose_at(S)


def test_a_gap_around_the_stamp_is_stale() -> None:
    ego = EgoMotion(max_gap_s=0.5)
    ego.add(PlanarPose(S, 0.0, 0.0, 0.0))
    ego.add(PlanarPose(3 * S, 1.0, 0.0, 0.0))
    with pytest.raises(EgoMotionStale, match="gap"):
        ego.pose_at(2 * S)


def test_bad_samples_are_refused_and_a_jump_back_starts_afresh() -> None:
    ego = EgoMotion()
    with pytest.raises(EgoMotionError):
        ego.add(PlanarPose(S, math.nan, 0.0, 0.0))
    with pytest.raises(EgoMotionError):
        ego.add(PlanarPose(0, 0.0, 0.0, 0.0))
    ego.add(PlanarPose(10 * S, 5.0, 0.0, 0.0))
    ego.add(PlanarPose(2 * S, 0.0, 0.0, 0.0))  # a bag started again
    assert len(ego) == 1 and ego.newest is not None and ego.newest.x == 0.0


def test_dead_reckoning_follows_speed_and_yaw() -> None:
    ego = EgoMotion()
    ego.dead_reckon(S, 10.0, 0.0)
    ego.dead_reckon(2 * S, 10.0, 0.0)
    pose = ego.dead_reckon(3 * S, 10.0, math.pi / 2)
    assert pose.x == pytest.approx(10.0 + 10.0 * math.cos(math.pi / 4))
    assert pose.y == pytest.approx(10.0 * math.sin(math.pi / 4))
    assert ego.pose_at(2 * S).x == pytest.approx(10.0)


def _drive(ego: EgoMotion, start: int, n: int, x0: float = 0.0, speed: float = 10.0) -> None:
    for k in range(n):  # 50 Hz along x
        ego.add(PlanarPose(start + k * S // 50, x0 + speed * k / 50, 0.0, 0.0, speed, 0.0))


def test_a_teleport_is_refused_and_the_history_kept() -> None:
    ego = EgoMotion()
    _drive(ego, S, 10)
    before = ego.newest
    with pytest.raises(OdometryJump, match=r"a move of 99999\d\.\d+ m in 0\.020 s"):
        ego.add(PlanarPose(S + 10 * S // 50, 1e6, 0.0, 0.0, 10.0, 0.0))
    assert ego.newest == before
    _drive(ego, S + 11 * S // 50, 3, x0=11 * 10 / 50)  # the odometry goes on where it was
    assert ego.newest is not None and ego.newest.x == pytest.approx(2.6)


@pytest.mark.parametrize("bad, reason", [
    (PlanarPose(S + S // 50, 0.2, 0.0, 0.0, 120.0, 0.0), "a speed of 120.0 m/s"),
    (PlanarPose(S + S // 50, 0.2, 0.0, 0.0, 10.0, 5.0), "a yaw rate of 5.00 rad/s"),
    (PlanarPose(S + S // 50, 0.2, 0.0, 1.0, 10.0, 0.0), "a turn of 1.00 rad in 0.020 s"),
    (PlanarPose(S + S // 50, 50.2, 0.0, 0.0, 10.0, 0.0), "a move of 50.20 m in 0.020 s"),
])
def test_what_no_car_can_do_is_refused_with_the_reason(bad: PlanarPose, reason: str) -> None:
    ego = EgoMotion()
    ego.add(PlanarPose(S, 0.0, 0.0, 0.0, 10.0, 0.0))
    with pytest.raises(OdometryJump, match=reason):
        ego.add(bad)
    assert len(ego) == 1


def test_a_sustained_jump_reanchors_after_the_refused_run_agrees() -> None:
    ego = EgoMotion(reanchor_samples=5)
    _drive(ego, S, 10)
    jumped = [PlanarPose(S + (10 + k) * S // 50, 500.0 + 0.2 * k, 3.0, 0.0, 10.0, 0.0) for k in range(5)]
    for pose in jumped[:4]:
        with pytest.raises(OdometryJump):
            ego.add(pose)
    assert ego.add(jumped[4]) is True  # the fifth in a row that agree: the odometry itself jumped
    assert len(ego) == 5 and ego.newest == jumped[4]
    assert ego.pose_at(jumped[2].stamp_ns).x == pytest.approx(500.4)
    assert ego.add(PlanarPose(jumped[4].stamp_ns + S // 50, 501.0, 3.0, 0.0, 10.0, 0.0)) is False


def test_scattered_outliers_never_reanchor() -> None:
    ego = EgoMotion(reanchor_samples=3)
    _drive(ego, S, 5)
    for k, x in enumerate((1e3, -1e3, 5e3, 1e4)):  # refused, but not a consistent run
        with pytest.raises(OdometryJump):
            ego.add(PlanarPose(S + (5 + k) * S // 50, x, 0.0, 0.0, 10.0, 0.0))
    assert ego.newest is not None and ego.newest.x == pytest.approx(0.8)
