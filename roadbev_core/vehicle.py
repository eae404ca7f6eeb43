"""The vehicle: ``base_link``, its wheels and where the left camera sits on it.

The vehicle's geometry is :class:`roadbev_core.config.VehicleConfig` (the config tree's section, the
one vehicle type). As docs/interface/frames-and-grid.md ("Frames and signs") defines it,
``base_link`` is the vehicle body in REP-103 axes (x forward, y left, z up) with its origin at the
centre of the rear axle on the road plane at static ride height. The parameters
``vehicle.wheelbase_m``, ``vehicle.track_width_m`` and ``vehicle.camera_position_m`` (the left
optical centre in ``base_link``) keep their interface names here (without the ``vehicle.`` prefix).

Poses are ``(position [3], R [3, 3])`` pairs taking ``base_link`` coordinates to the parent frame
(``p_parent = R @ p_base + position``). Pure numpy; shapes in the comments.
"""

from __future__ import annotations

from typing import cast

import numpy as np

from roadbev_core.config import VehicleConfig
from roadbev_core.geometry import R_BODY_FROM_OPTICAL, GeometryError, rotation_from_rpy

__all__ = [
    "WHEEL_NAMES",
    "camera_extrinsic",
    "contact_plane",
    "planar_yaw",
]

# Order of the wheels everywhere a [4, ...] array is per wheel.
WHEEL_NAMES: tuple[str, ...] = ("front_left", "front_right", "rear_left", "rear_right")


def camera_extrinsic(vehicle: VehicleConfig, mount_roll: float, mount_pitch: float) -> tuple[np.ndarray, np.ndarray]:
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
    return cast("np.ndarray", np.arctan2(R[..., 1, 0], R[..., 0, 0]))


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
