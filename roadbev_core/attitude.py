"""The camera attitude at an image stamp, from IMU orientations: the one implementation.

The node, ``roadbev eval``, the online evaluation, the demo, the benchmarks and the training
data readers all ask this module for the attitude of a frame, with one set of rules:

* an orientation must be a finite quaternion whose norm is within :data:`QUATERNION_NORM_TOL`
  of 1 (float32 round-off passes; an all-zero "no orientation" quaternion does not);
* between two samples the orientation is their slerp, unless they are more than ``max_gap_s``
  apart (a gap in the IMU stream: refused);
* before the first or after the last sample the nearest one is used if it is at most
  ``max_age_s`` away (no extrapolation), else refused.

Refusals raise :class:`ImuStale`, a bad sample :class:`ImuError`. Quaternions are (x, y, z, w)
throughout; the quaternion maths (:func:`slerp`, :func:`quaternion_from_rotation`) lives here
and nowhere else.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import NamedTuple, cast

import numpy as np

from roadbev_core.config import ImuConfig
from roadbev_core.errors import RoadbevError
from roadbev_core.geometry import Attitude, GeometryError, attitude_from_quaternion

__all__ = [
    "QUATERNION_NORM_TOL",
    "ImuBuffer",
    "ImuError",
    "ImuSample",
    "ImuStale",
    "imu_buffer",
    "quaternion_from_rotation",
    "slerp",
    "unit_quaternion",
]

# How far from 1 the norm of an orientation quaternion may be (float32 round-off passes).
QUATERNION_NORM_TOL = 1e-3


class ImuError(RoadbevError, ValueError):
    """An IMU sample that cannot be used (NaN, not a unit quaternion, no stamp)."""


class ImuStale(RoadbevError, RuntimeError):
    """No trustworthy attitude for the asked stamp (no IMU, a gap, or too old)."""


class ImuSample(NamedTuple):
    """One IMU orientation: stamp (ns) and unit quaternion (x, y, z, w) of the IMU body in ENU."""

    stamp_ns: int
    orientation_xyzw: tuple[float, float, float, float]


# --- quaternion maths ---------------------------------------------------------------------------
def unit_quaternion(values: Iterable[float], what: str = "orientation") -> np.ndarray:
    """[4] the quaternion ``values`` normalised, after checking it is one.

    Raises:
        ImuError: not four finite numbers, or a norm further than QUATERNION_NORM_TOL from 1.
    """
    q = np.asarray(list(values), dtype=np.float64)
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        raise ImuError(f"{what} has non-finite components {q.tolist()}")
    with np.errstate(over="ignore"):  # a huge component overflows to inf: not unit, reported below
        norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > QUATERNION_NORM_TOL:  # an all-zero quaternion means "no orientation" (REP-145)
        raise ImuError(f"{what} is not a unit quaternion (norm {norm:.6g})")
    return q / norm


def quaternion_from_rotation(R: np.ndarray) -> np.ndarray:
    """[4] unit quaternion (x, y, z, w), w >= 0, of a [3, 3] rotation matrix."""
    m = np.asarray(R, np.float64)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    else:
        i = int(np.argmax([m[0, 0], m[1, 1], m[2, 2]]))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + m[i, i] - m[j, j] - m[k, k], 1e-12))
        q = [0.0, 0.0, 0.0, (m[k, j] - m[j, k]) / s]
        q[i] = 0.25 * s
        q[j] = (m[j, i] + m[i, j]) / s
        q[k] = (m[k, i] + m[i, k]) / s
    out = np.array(q)
    out /= np.linalg.norm(out)
    return out if out[3] >= 0 else -out


def slerp(q0: np.ndarray, q1: np.ndarray, t: float) -> np.ndarray:
    """[4] spherical linear interpolation of unit quaternions (x, y, z, w) along the shorter arc.

    Args:
        q0, q1: [4] unit quaternions; t: 0 gives q0, 1 gives q1 (values outside extrapolate).
    """
    q0 = np.asarray(q0, np.float64)
    q1 = np.asarray(q1, np.float64)
    dot = float(q0 @ q1)
    if dot < 0:  # q and -q are the same rotation: take the shorter way round
        q1, dot = -q1, -dot
    if dot > 0.9999995:  # nearly parallel: normalised lerp is exact to float precision
        q = q0 + t * (q1 - q0)
        return cast("np.ndarray", q / np.linalg.norm(q))
    theta = math.acos(min(dot, 1.0))
    return (math.sin((1 - t) * theta) * q0 + math.sin(t * theta) * q1) / math.sin(theta)


# --- the attitude at a stamp ----------------------------------------------------------------------
@dataclass
class ImuBuffer:
    """Recent IMU orientations in stamp order, and the camera attitude at any stamp among them.

    Attributes:
        max_age_s: how far the asked stamp may lie beyond the first/last sample (nearest used).
        max_gap_s: two samples around the stamp may be at most this far apart.
        horizon_s: history kept behind the newest sample (``math.inf``: keep everything).
        jump_back_s: a sample this much older than the newest means the clock jumped back (a
            bag started again): the history is dropped and starts again from that sample.
        imu_to_camera_rpy_deg: camera body in the IMU body frame (roll, pitch, yaw degrees).
    """

    max_age_s: float = 0.1
    max_gap_s: float = 0.1
    horizon_s: float = 2.0
    jump_back_s: float = 1.0
    imu_to_camera_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        self._stamps: list[int] = []
        self._quats: list[np.ndarray] = []

    def __len__(self) -> int:
        return len(self._stamps)

    @property
    def newest_ns(self) -> int | None:
        """Stamp of the newest sample (None when empty)."""
        return self._stamps[-1] if self._stamps else None

    def clear(self) -> None:
        self._stamps.clear()
        self._quats.clear()

    def configure(self, config: ImuConfig, *, whole_history: bool = False) -> None:
        """Take ``config``'s rules, keeping the samples (also a parameter change at run time).

        Args:
            config: the IMU settings (``imu_max_age_s`` bounds both the age of the nearest sample
                and the gap between two samples).
            whole_history: keep every sample (a reader holding a whole recording) instead of the
                last ``imu_buffer_s``.
        """
        self.max_age_s = self.max_gap_s = config.max_age_s
        self.horizon_s = math.inf if whole_history else config.buffer_s
        self.imu_to_camera_rpy_deg = config.imu_to_camera_rpy_deg

    def add(self, stamp_ns: int, orientation_xyzw: Iterable[float]) -> None:
        """Add one sample (any order within ``jump_back_s``; a repeated stamp replaces the
        earlier sample).

        Raises:
            ImuError: see :func:`unit_quaternion`, or a stamp <= 0.
        """
        q = unit_quaternion(orientation_xyzw, "IMU orientation")
        if stamp_ns <= 0:
            raise ImuError("IMU sample has no stamp")
        if self._stamps and stamp_ns < self._stamps[-1] - int(self.jump_back_s * 1e9):
            self.clear()
        i = bisect.bisect_left(self._stamps, stamp_ns)
        if i < len(self._stamps) and self._stamps[i] == stamp_ns:
            self._quats[i] = q
        else:
            self._stamps.insert(i, stamp_ns)
            self._quats.insert(i, q)
        if math.isfinite(self.horizon_s):  # forget what is older than the horizon
            cut = bisect.bisect_left(self._stamps, self._stamps[-1] - int(self.horizon_s * 1e9))
            if cut:
                del self._stamps[:cut]
                del self._quats[:cut]

    def brackets(self, stamp_ns: int) -> bool:
        """Whether a sample at or after ``stamp_ns`` has arrived (the answer will not change)."""
        return bool(self._stamps) and self._stamps[-1] >= stamp_ns

    def orientation_at(self, stamp_ns: int) -> np.ndarray:
        """[4] IMU orientation (x, y, z, w) at ``stamp_ns``.

        Raises:
            ImuStale: no sample, a gap around the stamp, or the nearest sample too far away.
        """
        if not self._stamps:
            raise ImuStale("no IMU sample received")
        i = bisect.bisect_left(self._stamps, stamp_ns)
        if i < len(self._stamps) and self._stamps[i] == stamp_ns:
            return cast("np.ndarray", self._quats[i].copy())
        if i == 0 or i == len(self._stamps):
            nearest = 0 if i == 0 else -1
            age = abs(stamp_ns - self._stamps[nearest]) * 1e-9
            if age > self.max_age_s:
                where = "newer than" if i else "older than"
                raise ImuStale(
                    f"image stamp is {age:.3f} s {where} the IMU samples (limit {self.max_age_s} s)"
                )
            return cast("np.ndarray", self._quats[nearest].copy())
        t0, t1 = self._stamps[i - 1], self._stamps[i]
        gap = (t1 - t0) * 1e-9
        if gap > self.max_gap_s:
            raise ImuStale(f"IMU gap of {gap:.3f} s around the image stamp (limit {self.max_gap_s} s)")
        return slerp(self._quats[i - 1], self._quats[i], (stamp_ns - t0) / (t1 - t0))

    def attitude_at(self, stamp_ns: int) -> Attitude:
        """Camera roll/pitch at ``stamp_ns`` (IMU orientation rotated into the camera body).

        Raises:
            ImuStale: see :meth:`orientation_at`, or an attitude beyond +-90 deg pitch.
        """
        x, y, z, w = self.orientation_at(stamp_ns)
        try:
            return attitude_from_quaternion(x, y, z, w, self.imu_to_camera_rpy_deg)
        except GeometryError as exc:
            raise ImuStale(f"IMU attitude unusable: {exc}") from None

    def age_s(self, now_ns: int) -> float | None:
        """Seconds from the newest sample to ``now_ns`` (None when empty)."""
        return None if not self._stamps else (now_ns - self._stamps[-1]) * 1e-9


def imu_buffer(config: ImuConfig, *, whole_history: bool = False) -> ImuBuffer:
    """An empty buffer with ``config``'s rules (:meth:`ImuBuffer.configure`): how the pipeline,
    the bag readers and the labeller all build theirs."""
    buffer = ImuBuffer()
    buffer.configure(config, whole_history=whole_history)
    return buffer
