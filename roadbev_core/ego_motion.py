"""Ego-motion: the planar pose of ``base_link`` in ``odom`` at any frame stamp.

Contract, "Vehicle, odometry, TF and the fused road map": the vehicle's own odometry
(``nav_msgs/Odometry``, ``odom`` -> ``base_link``, planar, drifting) gives x, y and yaw; where
only a speed is known, the pose is dead reckoned from it and the IMU's yaw. Vertical motion
(heave, pitch, roll over bumps) is never taken from here: the fused map estimates it.

:class:`EgoMotion` keeps recent odometry samples and answers the pose at a stamp by linear
interpolation (yaw unwrapped) between the two samples around it; a stamp just beyond the newest
sample is extrapolated with that sample's twist, up to ``max_age_s``. As with the IMU, a frame
waits for a sample at or after its stamp (:meth:`EgoMotion.brackets`), so the pose the node uses
is the one ``roadbev eval`` computes from the same bag. Pure Python/numpy.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import NamedTuple

from roadbev_core.errors import RoadbevError

__all__ = ["EgoMotion", "EgoMotionError", "EgoMotionStale", "PlanarPose"]


class EgoMotionError(RoadbevError, ValueError):
    """An odometry sample that cannot be used (non-finite, no stamp)."""


class EgoMotionStale(RoadbevError, RuntimeError):
    """No pose at the asked stamp (no odometry, or too old)."""


class PlanarPose(NamedTuple):
    """``base_link`` in ``odom``, planar.

    Attributes:
        stamp_ns: when.
        x, y: position (m).
        yaw: heading (rad, unwrapped along the stream).
        speed: forward speed (m/s; negative when reversing).
        yaw_rate: (rad/s).
    """

    stamp_ns: int
    x: float
    y: float
    yaw: float
    speed: float = 0.0
    yaw_rate: float = 0.0


@dataclass
class EgoMotion:
    """Recent planar poses and the pose at any stamp among (or just after) them.

    Attributes:
        max_age_s: how far beyond the newest (or before the oldest) sample a stamp may lie.
        max_gap_s: two samples around a stamp may be at most this far apart.
        horizon_s: history kept behind the newest sample.
        jump_back_s: a sample this much older than the newest means the clock jumped back
            (a bag started again): the history starts again from it.
    """

    max_age_s: float = 0.2
    max_gap_s: float = 0.5
    horizon_s: float = 5.0
    jump_back_s: float = 1.0

    def __post_init__(self) -> None:
        self._stamps: list[int] = []
        self._poses: list[PlanarPose] = []
        self._reckoned: PlanarPose | None = None  # dead reckoning state (speed + IMU yaw)

    def __len__(self) -> int:
        return len(self._stamps)

    @property
    def newest(self) -> PlanarPose | None:
        return self._poses[-1] if self._poses else None

    def clear(self) -> None:
        self._stamps.clear()
        self._poses.clear()
        self._reckoned = None

    def add(self, pose: PlanarPose) -> None:
        """One odometry sample (a repeated stamp replaces the earlier one).

        Raises:
            EgoMotionError: a non-finite value or a stamp <= 0.
        """
        if pose.stamp_ns <= 0:
            raise EgoMotionError("odometry sample has no stamp")
        values = (pose.x, pose.y, pose.yaw, pose.speed, pose.yaw_rate)
        if not all(math.isfinite(v) for v in values):
            raise EgoMotionError(f"odometry sample at {pose.stamp_ns} ns is not finite: {values}")
        if self._stamps and pose.stamp_ns < self._stamps[-1] - int(self.jump_back_s * 1e9):
            self.clear()
        i = bisect.bisect_left(self._stamps, pose.stamp_ns)
        # keep the yaw continuous with the neighbour before it
        if i > 0:
            prev = self._poses[i - 1].yaw
            pose = pose._replace(yaw=pose.yaw + 2 * math.pi * round((prev - pose.yaw) / (2 * math.pi)))
        if i < len(self._stamps) and self._stamps[i] == pose.stamp_ns:
            self._poses[i] = pose
        else:
            self._stamps.insert(i, pose.stamp_ns)
            self._poses.insert(i, pose)
        cut = bisect.bisect_left(self._stamps, self._stamps[-1] - int(self.horizon_s * 1e9))
        if cut:
            del self._stamps[:cut]
            del self._poses[:cut]

    def dead_reckon(self, stamp_ns: int, speed: float, yaw: float) -> PlanarPose:
        """Advance the dead-reckoned pose to ``stamp_ns`` with ``speed`` (m/s) along the heading
        ``yaw`` (rad, e.g. the IMU's yaw of ``base_link``), add it as a sample and return it.
        The first call starts at the origin: ``odom`` is ``base_link`` at the first stamp."""
        if not (math.isfinite(speed) and math.isfinite(yaw)):
            raise EgoMotionError(f"dead reckoning needs a finite speed and yaw, got {speed}, {yaw}")
        last = self._reckoned
        if last is None or stamp_ns <= last.stamp_ns - int(self.jump_back_s * 1e9):
            pose = PlanarPose(int(stamp_ns), 0.0, 0.0, yaw, speed, 0.0)
        elif stamp_ns <= last.stamp_ns:
            return last
        else:
            dt = (stamp_ns - last.stamp_ns) * 1e-9
            yaw = yaw + 2 * math.pi * round((last.yaw - yaw) / (2 * math.pi))
            mid = 0.5 * (yaw + last.yaw)
            step = 0.5 * (speed + last.speed) * dt
            pose = PlanarPose(int(stamp_ns), last.x + step * math.cos(mid), last.y + step * math.sin(mid), yaw,
                              speed, (yaw - last.yaw) / dt)
        self._reckoned = pose
        self.add(pose)
        return pose

    def brackets(self, stamp_ns: int) -> bool:
        """Whether a sample at or after ``stamp_ns`` has arrived (the answer will not change)."""
        return bool(self._stamps) and self._stamps[-1] >= stamp_ns

    def pose_at(self, stamp_ns: int) -> PlanarPose:
        """The pose at ``stamp_ns``.

        Raises:
            EgoMotionStale: no sample, a gap around the stamp, or the nearest sample too far.
        """
        if not self._stamps:
            raise EgoMotionStale("no odometry received")
        i = bisect.bisect_left(self._stamps, stamp_ns)
        if i < len(self._stamps) and self._stamps[i] == stamp_ns:
            return self._poses[i]
        if i == 0 or i == len(self._stamps):
            near = self._poses[0 if i == 0 else -1]
            dt = (stamp_ns - near.stamp_ns) * 1e-9
            if abs(dt) > self.max_age_s:
                where = "newer than" if i else "older than"
                raise EgoMotionStale(f"frame stamp is {abs(dt):.3f} s {where} the odometry (limit {self.max_age_s} s)")
            yaw = near.yaw + near.yaw_rate * dt
            mid = near.yaw + 0.5 * near.yaw_rate * dt
            return PlanarPose(int(stamp_ns), near.x + near.speed * dt * math.cos(mid),
                              near.y + near.speed * dt * math.sin(mid), yaw, near.speed, near.yaw_rate)
        a, b = self._poses[i - 1], self._poses[i]
        gap = (b.stamp_ns - a.stamp_ns) * 1e-9
        if gap > self.max_gap_s:
            raise EgoMotionStale(f"odometry gap of {gap:.3f} s around the frame stamp (limit {self.max_gap_s} s)")
        f = (stamp_ns - a.stamp_ns) / (b.stamp_ns - a.stamp_ns)
        return PlanarPose(int(stamp_ns), a.x + f * (b.x - a.x), a.y + f * (b.y - a.y), a.yaw + f * (b.yaw - a.yaw),
                          a.speed + f * (b.speed - a.speed), a.yaw_rate + f * (b.yaw_rate - a.yaw_rate))
