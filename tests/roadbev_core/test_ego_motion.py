"""Ego-motion: interpolation between odometry samples, short extrapolation, dead reckoning."""

from __future__ import annotations

import math

import pytest

from roadbev_core.ego_motion import EgoMotion, EgoMotionError, EgoMotionStale, PlanarPose

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
