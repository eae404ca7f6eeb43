"""Ego-motion: the planar pose of ``base_link`` in ``odom`` at any frame stamp.

The vehicle's own odometry (``nav_msgs/Odometry``, ``odom`` -> ``base_link``, planar, drifting;
docs/interface/topics.md, "The node's inputs", and docs/concepts/fused_map.md) gives x, y and yaw;
where only a speed is known, the pose is dead reckoned from it and the IMU's yaw. Vertical motion
(heave, pitch, roll over bumps) is never taken from here: the fused map estimates it.

:class:`EgoMotion` keeps recent odometry samples and answers the pose at a stamp by linear
interpolation (yaw unwrapped) between the two samples around it; a stamp just beyond the newest
sample is extrapolated with that sample's twist, up to ``max_age_s``. As with the IMU, a frame
waits for a sample at or after its stamp (:meth:`EgoMotion.brackets`), so the pose the node uses
is the one ``roadbev eval`` computes from the same bag.

Every sample is gated against what a car can do before it is kept: a speed (reported, or implied
by the distance from the sample before it) above ``max_speed_mps``, or a heading change faster
than ``max_yaw_rate``, is refused (:class:`OdometryJump`) and the history is left as it was. When
``reanchor_samples`` refused samples in a row agree with each other (each plausible from the
one before), the odometry itself has jumped (a localisation reset, a re-initialised
odometer): the history starts again from them and :meth:`EgoMotion.add` says so, so that the
map built in the old frame is dropped rather than smeared. Pure Python/numpy.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import NamedTuple

from roadbev_core.errors import RoadbevError

__all__ = ["EgoMotion", "EgoMotionError", "EgoMotionStale", "OdometryJump", "PlanarPose"]


class EgoMotionError(RoadbevError, ValueError):
    """An odometry sample that cannot be used (non-finite, no stamp)."""


class OdometryJump(EgoMotionError):
    """An odometry sample no car could have produced from the one before it (refused)."""


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
        max_speed_mps: the fastest the vehicle goes: a faster reported speed, or a move from the
            sample before that needs one, is refused.
        max_yaw_rate: the fastest the heading turns (rad/s), reported or implied.
        position_noise_m: the odometry's own position noise, allowed on top of the move.
        reanchor_samples: refused samples in a row, consistent with each other, that mean the
            odometry itself jumped: the history starts again from them.
    """

    max_age_s: float = 0.2
    max_gap_s: float = 0.5
    horizon_s: float = 5.0
    jump_back_s: float = 1.0
    max_speed_mps: float = 70.0
    max_yaw_rate: float = 2.0
    position_noise_m: float = 0.5
    reanchor_samples: int = 5

    def __post_init__(self) -> None:
        self._stamps: list[int] = []
        self._poses: list[PlanarPose] = []
        self._reckoned: PlanarPose | None = None  # dead reckoning state (speed + IMU yaw)
        self._refused: list[PlanarPose] = []  # the refused samples in a row, newest last

    def __len__(self) -> int:
        return len(self._stamps)

    @property
    def newest(self) -> PlanarPose | None:
        return self._poses[-1] if self._poses else None

    def clear(self) -> None:
        self._stamps.clear()
        self._poses.clear()
        self._reckoned = None
        self._refused.clear()

    def implausible(self, before: PlanarPose, after: PlanarPose) -> str:
        """Why ``after`` cannot follow ``before`` (either order in time), or ""."""
        dt = abs(after.stamp_ns - before.stamp_ns) * 1e-9
        if abs(after.speed) > self.max_speed_mps:
            return f"a speed of {after.speed:.1f} m/s (limit {self.max_speed_mps:g})"
        if abs(after.yaw_rate) > self.max_yaw_rate:
            return f"a yaw rate of {after.yaw_rate:.2f} rad/s (limit {self.max_yaw_rate:g})"
        moved = math.hypot(after.x - before.x, after.y - before.y)
        if moved > self.max_speed_mps * dt + self.position_noise_m:
            return (f"a move of {moved:.2f} m in {dt:.3f} s (limit {self.max_speed_mps:g} m/s + "
                    f"{self.position_noise_m:g} m)")
        turned = abs(math.remainder(after.yaw - before.yaw, 2 * math.pi))
        if turned > self.max_yaw_rate * dt + 0.1:
            return f"a turn of {turned:.2f} rad in {dt:.3f} s (limit {self.max_yaw_rate:g} rad/s)"
        return ""

    def add(self, pose: PlanarPose) -> bool:
        """One odometry sample (a repeated stamp replaces the earlier one).

        Returns:
            True when the sample completed a run of refused samples that agree with each other:
            the odometry jumped, and the history now starts from that run (re-anchored).

        Raises:
            EgoMotionError: a non-finite value or a stamp <= 0.
            OdometryJump: a sample no car could have produced from the one before it (not kept).
        """
        if pose.stamp_ns <= 0:
            raise EgoMotionError("odometry sample has no stamp")
        values = (pose.x, pose.y, pose.yaw, pose.speed, pose.yaw_rate)
        if not all(math.isfinite(v) for v in values):
            raise EgoMotionError(f"odometry sample at {pose.stamp_ns} ns is not finite: {values}")
        if self._stamps and pose.stamp_ns < self._stamps[-1] - int(self.jump_back_s * 1e9):
            self.clear()
        i = bisect.bisect_left(self._stamps, pose.stamp_ns)
        neighbour = self._poses[i - 1] if i > 0 else (self._poses[i] if i < len(self._poses) else None)
        why = self.implausible(neighbour, pose) if neighbour is not None else ""
        if why:
            agrees = not self._refused or not self.implausible(self._refused[-1], pose)
            self._refused = [*self._refused, pose] if agrees else [pose]
            if len(self._refused) < self.reanchor_samples:
                raise OdometryJump(f"odometry at {pose.stamp_ns * 1e-9:.3f} s refused: {why}")
            run = list(self._refused)
            self.clear()
            for sample in run:
                self._insert(sample)
            return True
        self._refused.clear()
        self._insert(pose)
        return False

    def _insert(self, pose: PlanarPose) -> None:
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
