"""IMU attitude at an image stamp: a short history of orientations, interpolated by slerp.

The IMU runs faster than the cameras and on its own clock ticks, so the attitude for an image is
interpolated between the two IMU samples around the image stamp (spherical linear interpolation
of the orientation quaternions, :func:`msg_bridge.imu.slerp`). The buffer refuses to guess rather
than hand a backend a wrong attitude: with no sample, with a gap in the IMU stream around the
stamp, or with the nearest sample older than ``max_age_s`` it raises :class:`ImuStale`.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass

import numpy as np

from msg_bridge.imu import slerp
from roadbev_core.geometry import Attitude, GeometryError, attitude_from_quaternion

__all__ = ["ImuBuffer", "ImuError", "ImuStale"]


class ImuError(ValueError):
    """An IMU sample that cannot be used (NaN, not a unit quaternion)."""


class ImuStale(RuntimeError):
    """No trustworthy attitude for the asked stamp (no IMU, a gap, or too old)."""


@dataclass
class ImuBuffer:
    """Recent IMU orientations, kept in stamp order.

    Attributes:
        max_age_s: the nearest sample may be at most this far from the asked stamp when the stamp
            lies outside the buffered interval (no extrapolation beyond it).
        max_gap_s: two samples around the stamp may be at most this far apart.
        horizon_s: history kept behind the newest sample.
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

    def add(self, stamp_ns: int, orientation_xyzw: tuple[float, float, float, float]) -> None:
        """Add one sample (any order within ``jump_back_s``; a repeated stamp replaces the
        earlier sample).

        Raises:
            ImuError: NaN/inf components or not a unit quaternion (within 1e-2), or a zero stamp.
        """
        q = np.asarray(orientation_xyzw, dtype=np.float64)
        if q.shape != (4,) or not np.all(np.isfinite(q)):
            raise ImuError(f"IMU orientation has non-finite components {q.tolist()}")
        norm = float(np.linalg.norm(q))
        if abs(norm - 1.0) > 1e-2:  # an all-zero quaternion means "no orientation" (REP-145)
            raise ImuError(f"IMU orientation is not a unit quaternion (norm {norm:.4f})")
        if stamp_ns <= 0:
            raise ImuError("IMU sample has no stamp")
        q = q / norm
        if self._stamps and stamp_ns < self._stamps[-1] - int(self.jump_back_s * 1e9):
            self.clear()
        i = bisect.bisect_left(self._stamps, stamp_ns)
        if i < len(self._stamps) and self._stamps[i] == stamp_ns:
            self._quats[i] = q
        else:
            self._stamps.insert(i, stamp_ns)
            self._quats.insert(i, q)
        # forget what is older than the horizon behind the newest sample
        cut = bisect.bisect_left(self._stamps, self._stamps[-1] - int(self.horizon_s * 1e9))
        if cut:
            del self._stamps[:cut]
            del self._quats[:cut]

    def orientation_at(self, stamp_ns: int) -> np.ndarray:
        """[4] IMU orientation (x, y, z, w) at ``stamp_ns``.

        Raises:
            ImuStale: no sample, a gap around the stamp, or the nearest sample too far away.
        """
        if not self._stamps:
            raise ImuStale("no IMU sample received")
        i = bisect.bisect_left(self._stamps, stamp_ns)
        if i < len(self._stamps) and self._stamps[i] == stamp_ns:
            return self._quats[i].copy()
        if i == 0 or i == len(self._stamps):
            nearest = 0 if i == 0 else -1
            age = abs(stamp_ns - self._stamps[nearest]) * 1e-9
            if age > self.max_age_s:
                where = "newer than" if i else "older than"
                raise ImuStale(
                    f"image stamp is {age:.3f} s {where} the IMU samples (limit {self.max_age_s} s)"
                )
            return self._quats[nearest].copy()
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
