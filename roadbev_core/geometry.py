"""Projection geometry: camera attitude, the road frame, voxel centres and their projection.

Frames (docs/interface/frames-and-grid.md):

* camera optical frame: z forward, x right, y down (OpenCV);
* camera body frame: x forward, y left, z up (REP-103), same origin;
* road frame: origin ``base_height`` straight below the left optical centre, z up along gravity,
  x forward (horizontal, with the camera's yaw), y left; no roll or pitch.

Attitude is roll/pitch of the camera body w.r.t. gravity, ZYX (yaw-pitch-roll) Euler angles with
yaw dropped; a camera pitched down has positive pitch (REP-103: a positive rotation about +y
turns +x toward -z).

All functions are pure and vectorized; shapes are in the comments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple, cast

import numpy as np

from roadbev_core.config import ConfigError, GridSpec, StereoCamera
from roadbev_core.errors import RoadbevError

__all__ = [
    "R_BODY_FROM_OPTICAL",
    "Attitude",
    "GeometryError",
    "ProjectedVoxels",
    "RayTerms",
    "attitude_from_quaternion",
    "attitude_from_rotation",
    "camera_to_road",
    "optical_from_road_rotation",
    "project_points",
    "project_voxels",
    "quaternion_to_rotation",
    "ray_terms",
    "road_frame_in_camera",
    "road_to_camera",
    "rotation_from_rpy",
    "rsrd_camera_attitude",
    "voxel_centres",
]


class GeometryError(RoadbevError, ValueError):
    """An attitude, quaternion or projection input that makes no geometric sense."""


# Optical (x right, y down, z fwd) -> body (x fwd, y left, z up): body = R @ optical.
R_BODY_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class Attitude:
    """Camera body attitude w.r.t. gravity, radians (pitch > 0: looking down)."""

    roll: float = 0.0
    pitch: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.roll) and math.isfinite(self.pitch)):
            raise GeometryError(f"attitude must be finite, got roll={self.roll}, pitch={self.pitch}")
        if abs(self.pitch) >= math.pi / 2:
            raise GeometryError(f"pitch {math.degrees(self.pitch):.1f} deg is beyond +-90 deg")

    @classmethod
    def from_degrees(cls, roll_deg: float, pitch_deg: float) -> Attitude:
        return cls(math.radians(roll_deg), math.radians(pitch_deg))

    @property
    def degrees(self) -> tuple[float, float]:
        """``(roll, pitch)`` in degrees."""
        return (math.degrees(self.roll), math.degrees(self.pitch))


def _rx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _ry(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_from_rpy(roll: float, pitch: float, yaw: float = 0.0) -> np.ndarray:
    """[3, 3] rotation Rz(yaw) @ Ry(pitch) @ Rx(roll) (REP-103 fixed-axis XYZ = ZYX Euler)."""
    return cast("np.ndarray", _rz(yaw) @ _ry(pitch) @ _rx(roll))


def attitude_from_rotation(R_world_body: np.ndarray) -> Attitude:
    """Roll and pitch (yaw dropped) of a body whose orientation in a z-up world frame is R.

    Args:
        R_world_body: [3, 3] rotation taking body coordinates to world coordinates.
    """
    R = np.asarray(R_world_body, dtype=np.float64)
    pitch = -math.asin(float(np.clip(R[2, 0], -1.0, 1.0)))
    roll = math.atan2(float(R[2, 1]), float(R[2, 2]))
    return Attitude(roll=roll, pitch=pitch)


def quaternion_to_rotation(x: float, y: float, z: float, w: float, *, tol: float = 1e-3) -> np.ndarray:
    """[3, 3] rotation of a unit quaternion (ROS order x, y, z, w).

    Raises:
        GeometryError: NaN/inf components or a norm further than ``tol`` from 1.
    """
    q = np.array([x, y, z, w], dtype=np.float64)
    if not np.all(np.isfinite(q)):
        raise GeometryError(f"quaternion has non-finite components {q.tolist()}")
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > tol:
        raise GeometryError(f"quaternion is not unit length (norm {norm:.6f})")
    x, y, z, w = q / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def attitude_from_quaternion(
    x: float,
    y: float,
    z: float,
    w: float,
    imu_to_camera_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> Attitude:
    """Camera attitude from an IMU orientation quaternion (IMU body relative to ENU).

    Args:
        x, y, z, w: the IMU orientation.
        imu_to_camera_rpy_deg: roll, pitch, yaw (degrees) of the camera body frame expressed in
            the IMU body frame (``R_imu_camera = rotation_from_rpy(...)``); zeros when the IMU
            is aligned with the camera body.
    """
    R_world_imu = quaternion_to_rotation(x, y, z, w)
    r, p, yw = (math.radians(v) for v in imu_to_camera_rpy_deg)
    R_world_camera = R_world_imu @ rotation_from_rpy(r, p, yw)
    return attitude_from_rotation(R_world_camera)


def rsrd_camera_attitude(
    lidar_roll_deg: float, lidar_pitch_deg: float, R_lidar_to_camera: np.ndarray
) -> Attitude:
    """Left-camera attitude of an RSRD sample from the LiDAR attitude and extrinsics.

    RSRD gives the LiDAR (INS) attitude as Euler angles in the order Z-X-Y (yaw about z, pitch
    about x, roll about y) and ``R`` taking LiDAR coordinates to the left optical frame
    (``p_cam = R @ p_lidar + T``). Yaw does not change roll or pitch, so it is left out.
    """
    R_level_lidar = _rx(math.radians(lidar_pitch_deg)) @ _ry(math.radians(lidar_roll_deg))
    R_level_optical = R_level_lidar @ np.asarray(R_lidar_to_camera, dtype=np.float64).T
    return attitude_from_rotation(R_level_optical @ R_BODY_FROM_OPTICAL.T)


def optical_from_road_rotation(attitude: Attitude) -> np.ndarray:
    """[3, 3] rotation taking road-frame directions to camera optical-frame directions."""
    R_level_body = rotation_from_rpy(attitude.roll, attitude.pitch)  # body -> level (road axes)
    return cast("np.ndarray", (R_level_body @ R_BODY_FROM_OPTICAL).T)


class RayTerms(NamedTuple):
    """The road-frame direction of pixel rays, split into a per-column and a per-row term: the ray
    of the pixel at row v, column u is ``per_col[u] + per_row[v]``, scaled so that the point at
    optical depth Z lies at ``(0, 0, base_height) + Z * ray``.

    Attributes:
        per_col: [w, 3] float64, ``R[0] * (u - cx) / fx + R[2]`` (the optical x and z parts).
        per_row: [h, 3] float64, ``R[1] * (v - cy) / fy`` (the optical y part).
    """

    per_col: np.ndarray
    per_row: np.ndarray

    def rays(self) -> np.ndarray:
        """[h, w, 3] float64: every pixel's ray."""
        return cast("np.ndarray", self.per_col[None, :, :] + self.per_row[:, None, :])


def ray_terms(camera: StereoCamera, attitude: Attitude, rows: np.ndarray, cols: np.ndarray) -> RayTerms:
    """The rays of the pixels at ``rows`` [h] x ``cols`` [w] of the left image (:class:`RayTerms`):
    a road-frame direction is ``sum_j R[j, k] * optical_j`` with ``optical = (x_n, y_n, 1)``, so
    it separates into a column's and a row's part."""
    R = optical_from_road_rotation(attitude)  # road -> optical; its rows map optical axes to road
    x_norm = (np.asarray(cols) - camera.cx) / camera.fx  # [w]
    y_norm = (np.asarray(rows) - camera.cy) / camera.fy  # [h]
    per_col = x_norm[:, None] * R[0][None, :] + R[2][None, :]  # [w, 3]
    per_row = y_norm[:, None] * R[1][None, :]  # [h, 3]
    return RayTerms(per_col.astype(np.float64), per_row.astype(np.float64))


def road_frame_in_camera(attitude: Attitude, base_height: float) -> tuple[np.ndarray, np.ndarray]:
    """The road frame's pose in the camera optical frame (the TF ``<camera> -> roadbev_road``):
    R [3, 3] taking road directions to optical ones and the road origin t [3] in optical
    coordinates, so that ``p_optical = R @ p_road + t``."""
    R = optical_from_road_rotation(attitude)
    return R, -R @ np.array([0.0, 0.0, float(base_height)])


def road_to_camera(points_road: np.ndarray, attitude: Attitude, base_height: float) -> np.ndarray:
    """Road-frame points [..., 3] -> camera optical-frame points [..., 3]."""
    p = np.asarray(points_road, dtype=np.float64)
    R = optical_from_road_rotation(attitude)
    shifted = p - np.array([0.0, 0.0, base_height])
    return cast("np.ndarray", shifted @ R.T)


def camera_to_road(points_cam: np.ndarray, attitude: Attitude, base_height: float) -> np.ndarray:
    """Camera optical-frame points [..., 3] -> road-frame points [..., 3]."""
    p = np.asarray(points_cam, dtype=np.float64)
    R = optical_from_road_rotation(attitude)
    return cast("np.ndarray", p @ R + np.array([0.0, 0.0, base_height]))


def voxel_centres(grid: GridSpec) -> np.ndarray:
    """[n_z, n_rows, n_cols, 3] road-frame centres of the voxels of interest (x, y, z)."""
    z = grid.z_centres()[:, None, None]
    x = grid.x_centres()[None, :, None]
    y = grid.y_centres()[None, None, :]
    shape = (grid.n_z, grid.n_rows, grid.n_cols)
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1).reshape(*shape, 3)


def project_points(
    points_cam: np.ndarray, camera: StereoCamera, *, right: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Project optical-frame points into the left (or right) rectified image.

    Args:
        points_cam: [..., 3] points in the LEFT camera's optical frame.
        camera: the stereo rig.
        right: project into the right image (its centre is ``baseline`` to the left's +x).

    Returns:
        u [...], v [...] pixel coordinates (pixel centres at integers), depth [...] (metres).
    """
    p = np.asarray(points_cam, dtype=np.float64)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    if right:
        if camera.baseline <= 0:
            raise ConfigError("projecting into a right image needs a stereo baseline > 0")
        x = x - camera.baseline
    with np.errstate(divide="ignore", invalid="ignore"):
        u = camera.fx * x / z + camera.cx
        v = camera.fy * y / z + camera.cy
    return u, v, z


class ProjectedVoxels(NamedTuple):
    """Voxel centres projected into one image at one feature stride.

    Attributes:
        u, v: [n_z, n_rows, n_cols] continuous feature-map coordinates (cell centres at
            integers), for bilinear sampling.
        iu, iv: [n_z, n_rows, n_cols] integer indices of the feature cell holding the projection
            (nearest-neighbour lookup, the paper's integer indexing), clipped into the map.
        inside: [n_z, n_rows, n_cols] bool, the voxel is in front of the camera and inside the map.
        width, height: the feature map's size.
    """

    u: np.ndarray
    v: np.ndarray
    iu: np.ndarray
    iv: np.ndarray
    inside: np.ndarray
    width: int
    height: int


def project_voxels(
    grid: GridSpec,
    camera: StereoCamera,
    attitude: Attitude,
    *,
    stride: int = 1,
    right: bool = False,
) -> ProjectedVoxels:
    """Project every voxel centre of ``grid`` into an image (or a feature map of ``stride``).

    A feature map at stride s has cell (i, j) covering pixels [s*i, s*i + s); with pixel centres
    at integers its centre is at pixel s*i + (s - 1) / 2, so a pixel coordinate u maps to the
    feature coordinate (u - (s - 1) / 2) / s.
    """
    if stride < 1:
        raise ConfigError(f"feature stride must be >= 1, got {stride}")
    pts = road_to_camera(voxel_centres(grid), attitude, grid.base_height)  # [Z, R, C, 3]
    u, v, depth = project_points(pts, camera, right=right)
    width = -(-camera.width // stride)
    height = -(-camera.height // stride)
    fu = (u - (stride - 1) / 2.0) / stride
    fv = (v - (stride - 1) / 2.0) / stride
    # Cell i covers pixel centres s*i .. s*i + s - 1, i.e. u in [s*i - 0.5, s*i + s - 0.5).
    iu = np.floor((u + 0.5) / stride)
    iv = np.floor((v + 0.5) / stride)
    inside = (depth > 0) & (u >= -0.5) & (u <= camera.width - 0.5) & (v >= -0.5) & (v <= camera.height - 0.5)
    inside &= np.isfinite(u) & np.isfinite(v)
    iu = np.clip(np.nan_to_num(iu), 0, width - 1).astype(np.int64)
    iv = np.clip(np.nan_to_num(iv), 0, height - 1).astype(np.int64)
    return ProjectedVoxels(
        u=fu.astype(np.float32),
        v=fv.astype(np.float32),
        iu=iu,
        iv=iv,
        inside=inside,
        width=int(width),
        height=int(height),
    )
