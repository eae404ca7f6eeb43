"""The node's motion inputs without ROS: IMU, speed and odometry into the pipeline, and their replay."""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import pytest

from msg_bridge import bag_factory, make_header
from msg_bridge.imu import imu_message
from msg_bridge.tf import odometry_message, transforms_from_tf
from roadbev_core.ego_motion import PlanarPose
from roadbev_core.errors import RoadbevError
from roadbev_ros.motion import RECENT_MOTION_S, MotionInputs

MS = 1_000_000
START_NS = 1_700_000_000 * 1_000_000_000
FACTORY = bag_factory()
LEVEL = (0.0, 0.0, 0.0, 1.0)


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


class Taker:
    """Takes the samples as the pipeline does; refuses what it is told to."""

    def __init__(self) -> None:
        self.imu: list[int] = []
        self.speeds: list[tuple[int, float]] = []
        self.poses: list[PlanarPose] = []
        self.jumped = False

    def add_imu(self, stamp_ns: int, orientation_xyzw: Iterable[float]) -> None:
        self.imu.append(stamp_ns)

    def add_speed(self, stamp_ns: int, speed_mps: float) -> None:
        if speed_mps > 100:
            raise RoadbevError(f"speed {speed_mps} m/s is not plausible")
        self.speeds.append((stamp_ns, speed_mps))

    def add_odometry(self, pose: PlanarPose) -> bool:
        self.poses.append(pose)
        return self.jumped


def speed(stamp_ns: int, mps: float) -> Any:
    twist = FACTORY.new("geometry_msgs/msg/Twist", linear=FACTORY.new("geometry_msgs/msg/Vector3", x=mps, y=0.0, z=0.0),
                        angular=FACTORY.new("geometry_msgs/msg/Vector3", x=0.0, y=0.0, z=0.0))
    return FACTORY.new("geometry_msgs/msg/TwistStamped", header=make_header(FACTORY, stamp_ns, "base_link"),
                       twist=twist)


def motion(**kwargs: Any) -> tuple[MotionInputs, Taker, list[tuple[str, str]], FakeClock]:
    taker, problems, clock = Taker(), [], FakeClock()
    inputs = MotionInputs(taker, lambda kind, reason: problems.append((kind, reason)), FACTORY, clock=clock, **kwargs)
    return inputs, taker, problems, clock


def test_samples_reach_the_pipeline_and_odometry_and_speed_are_counted() -> None:
    inputs, taker, problems, clock = motion()
    assert inputs.samples == 0 and inputs.age_s() is None
    inputs.on_imu(imu_message(FACTORY, stamp_ns=START_NS, orientation_xyzw=LEVEL))
    assert taker.imu == [START_NS] and inputs.samples == 0  # the IMU is not what the map needs
    inputs.on_speed(speed(START_NS, 8.0))
    clock.t += 0.5
    inputs.on_odometry(odometry_message(FACTORY, stamp_ns=START_NS, position=(1.0, 2.0, 0.0), orientation_xyzw=LEVEL,
                                        linear_velocity=(8.0, 0.0, 0.0)))
    assert taker.speeds == [(START_NS, 8.0)] and taker.poses[0].x == 1.0 and taker.poses[0].speed == 8.0
    assert inputs.samples == 2
    clock.t += 0.25
    assert inputs.age_s() == pytest.approx(0.25)
    assert problems == []


def test_bad_messages_are_reported_never_raised() -> None:
    inputs, taker, problems, _ = motion()
    no_orientation = imu_message(FACTORY, stamp_ns=START_NS, orientation_xyzw=LEVEL)
    no_orientation.orientation_covariance[0] = -1.0  # REP-145: the IMU gives no orientation
    inputs.on_imu(no_orientation)
    inputs.on_speed(speed(START_NS, math.nan))
    inputs.on_speed(speed(START_NS, 200.0))  # refused by the pipeline
    assert [kind for kind, _ in problems] == ["bad imu", "bad speed", "bad speed"]
    assert "no orientation" in problems[0][1] and "not plausible" in problems[-1][1]
    assert inputs.samples == 0 and taker.imu == [] and taker.speeds == []


def test_an_odometry_jump_is_reported_and_the_sample_still_taken() -> None:
    inputs, taker, problems, _ = motion()
    taker.jumped = True
    inputs.on_odometry(odometry_message(FACTORY, stamp_ns=START_NS, position=(0.0, 0.0, 0.0), orientation_xyzw=LEVEL))
    assert [kind for kind, _ in problems] == ["odometry jump"] and inputs.samples == 1


def test_odometry_is_published_again_as_tf_only_when_asked() -> None:
    published: list[Any] = []
    inputs, _, _, _ = motion(publish_tf=published.append)
    inputs.on_odometry(odometry_message(FACTORY, stamp_ns=START_NS, position=(3.0, -1.0, 0.0), orientation_xyzw=LEVEL))
    (tf,) = transforms_from_tf(published[0])
    assert (tf.parent, tf.child) == ("odom", "base_link") and list(tf.translation) == [3.0, -1.0, 0.0]
    quiet, _, _, _ = motion()
    quiet.on_odometry(odometry_message(FACTORY, stamp_ns=START_NS, position=(3.0, -1.0, 0.0), orientation_xyzw=LEVEL))
    assert len(published) == 1


def test_replay_gives_again_the_recent_samples_of_the_new_timeline() -> None:
    inputs, taker, _, clock = motion()
    old = START_NS + 60_000 * MS  # the pass before the jump back
    inputs.on_imu(imu_message(FACTORY, stamp_ns=START_NS + 50 * MS, orientation_xyzw=LEVEL))  # in the span,
    clock.t += RECENT_MOTION_S + 1.0  # ... but arrived too long ago
    for stamp in (old, START_NS - 50 * MS, START_NS, START_NS + 100 * MS, START_NS + 400 * MS):
        inputs.on_imu(imu_message(FACTORY, stamp_ns=stamp, orientation_xyzw=LEVEL))
    inputs.on_speed(speed(START_NS + 20 * MS, 5.0))
    taker.imu.clear()
    taker.speeds.clear()
    inputs.replay((START_NS, START_NS + 100 * MS), imu_max_age_s=0.1)  # margin 0.1 + 0.1 s around the span
    assert taker.imu == [START_NS - 50 * MS, START_NS, START_NS + 100 * MS]
    assert taker.speeds == [(START_NS + 20 * MS, 5.0)] and inputs.samples == 2  # counted again when taken again
    taker.imu.clear()
    inputs.replay(None, imu_max_age_s=0.1)  # no span: nothing
    assert taker.imu == []


def test_odometry_samples_from_tf_are_taken_counted_and_replayed() -> None:
    inputs, taker, problems, _ = motion()
    pose = PlanarPose(START_NS, 1.0, 2.0, 0.1, 8.0, 0.0)
    inputs.on_pose(pose)
    assert taker.poses == [pose] and inputs.samples == 1 and problems == []
    taker.jumped = True
    inputs.on_pose(PlanarPose(START_NS + 150 * MS, 50.0, 2.0, 0.1, 8.0, 0.0))
    assert [kind for kind, _ in problems] == ["odometry jump"]
    taker.poses.clear()
    taker.jumped = False
    inputs.replay((START_NS, START_NS), imu_max_age_s=0.0)  # the margin (0.1 s) takes the first only
    assert taker.poses == [pose] and inputs.samples == 3
