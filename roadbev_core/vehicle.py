"""The vehicle: ``base_link``, its wheels and where the left camera sits on it.

Contract, "Vehicle, odometry, TF and the fused road map": ``base_link`` is the vehicle body in
REP-103 axes (x forward, y left, z up) with its origin at the centre of the rear axle on the road
plane at static ride height. The parameters ``vehicle.wheelbase_m``, ``vehicle.track_width_m`` and
``vehicle.camera_position_m`` (the left optical centre in ``base_link``) keep their contract names
here (without the ``vehicle.`` prefix).

Poses are ``(position [3], R [3, 3])`` pairs taking ``base_link`` coordinates to the parent frame
(``p_parent = R @ p_base + position``). Pure numpy; shapes in the comments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from roadbev_core.geometry import R_BODY_FROM_OPTICAL, GeometryError, rotation_from_rpy

__all__ = [
    "WHEEL_NAMES",
    "VehicleError",
    "VehicleSpec",
    "camera_extrinsic",
    "contact_plane",
    "planar_yaw",
]

# Order of the wheels everywhere a [4, ...] array is per wheel.
WHEEL_NAMES: tuple[str, ...] = ("front_left", "front_right", "rear_left", "rear_right")


class VehicleError(ValueError):
    """Vehicle parameters that describe no car (non-positive wheelbase, camera off the body...)."""


@dataclass(frozen=True)
class VehicleSpec:
    """The vehicle's geometry (contract defaults).

    Attributes:
        wheelbase_m: front to rear axle (m).
        track_width_m: left to right tyre centre (m), the same on both axles.
        camera_position_m: (x, y, z) of the left optical centre in ``base_link`` (m).
    """

    wheelbase_m: float = 2.80
    track_width_m: float = 1.60
    camera_position_m: tuple[float, float, float] = (1.60, 0.0, 1.10)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.wheelbase_m) and 0.5 <= self.wheelbase_m <= 10.0):
            raise VehicleError(f"vehicle.wheelbase_m must be in [0.5, 10] m, got {self.wheelbase_m}")
        if not (math.isfinite(self.track_width_m) and 0.5 <= self.track_width_m <= 4.0):
            raise VehicleError(f"vehicle.track_width_m must be in [0.5, 4] m, got {self.track_width_m}")
        pos = tuple(float(v) for v in self.camera_position_m)
        if len(pos) != 3 or not all(math.isfinite(v) for v in pos):
            raise VehicleError(f"vehicle.camera_position_m must be 3 finite numbers, got {self.camera_position_m}")
        if pos[2] <= 0:
            raise VehicleError(f"the camera must sit above the road (z > 0), got z = {pos[2]}")
        object.__setattr__(self, "camera_position_m", pos)

    @property
    def front_axle_ahead_of_camera_m(self) -> float:
        """How far the front axle is ahead of the camera (m; 1.20 with the defaults)."""
        return self.wheelbase_m - self.camera_position_m[0]

    def wheel_positions(self) -> np.ndarray:
        """[4, 2] (x, y) of the tyre centres in ``base_link`` (order :data:`WHEEL_NAMES`)."""
        half = 0.5 * self.track_width_m
        L = self.wheelbase_m
        return np.array([[L, half], [L, -half], [0.0, half], [0.0, -half]])


def camera_extrinsic(vehicle: VehicleSpec, mount_roll: float, mount_pitch: float) -> tuple[np.ndarray, np.ndarray]:
    """``base_link`` -> left camera optical frame of a camera mounted with roll/pitch (rad).

    The camera body frame (x forward, y left, z up) is turned by ``rotation_from_rpy(roll,
    pitch)`` from ``base_link`` (pitch > 0: looking down), then the optical frame follows.

    Returns:
        position [3] of the optical centre in ``base_link`` and R [3, 3] taking optical
        coordinates to ``base_link`` coordinates.
    """
    R_base_body = rotation_from_rpy(float(mount_roll), float(mount_pitch), 0.0)
    return np.array(vehicle.camera_position_m, np.float64), R_base_body @ R_BODY_FROM_OPTICAL


def planar_yaw(R: np.ndarray) -> np.ndarray:
    """Yaw (rad, ZYX Euler) of rotations [..., 3, 3]: the heading of their x axis."""
    R = np.asarray(R, np.float64)
    return np.arctan2(R[..., 1, 0], R[..., 0, 0])


def contact_plane(points: np.ndarray) -> np.ndarray:
    """Least-squares plane ``z = a + b x + c y`` through contact points (heights vertical).

    Args:
        points: [..., N, 3] (N >= 3 points not on one line), e.g. the four tyre contacts.

    Returns:
        [..., 3] coefficients (a, b, c).

    Raises:
        GeometryError: fewer than three points, non-finite points, or points on one line.
    """
    p = np.asarray(points, np.float64)
    if p.ndim < 2 or p.shape[-1] != 3 or p.shape[-2] < 3:
        raise GeometryError(f"a plane needs [..., N>=3, 3] points, got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise GeometryError("contact points must be finite")
    A = np.stack([np.ones(p.shape[:-1]), p[..., 0], p[..., 1]], axis=-1)  # [..., N, 3]
    AtA = np.swapaxes(A, -1, -2) @ A  # [..., 3, 3]
    if np.any(np.abs(np.linalg.det(AtA)) < 1e-12):
        raise GeometryError("contact points lie on one line: no plane")
    Atz = np.swapaxes(A, -1, -2) @ p[..., 2:3]  # [..., 3, 1]
    return np.linalg.solve(AtA, Atz)[..., 0]
