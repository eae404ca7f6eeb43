"""KITTI frames as RoadBEV inputs: calibration files, disparity ground truth, the road pose.

Pure functions over numpy arrays (no file formats beyond KITTI's text calibration), used by the
real-frame benchmark (``benchmarks/bench_kitti.py``) and the tests that build bags from the three
KITTI frames (the ``kitti_dir`` fixture; they skip without the frames). Those frames are a *test
set*: nothing here or elsewhere is tuned on them.

* :func:`read_calib`: a KITTI calibration text file (``P0: ...``, ``R0_rect: ...``) -> arrays.
* :func:`stereo_camera`: the rectified pair of two projection matrices.
* :func:`velo_to_camera`: the Velodyne -> rectified camera extrinsic of the object format.
* :func:`disparity_points`: a KITTI disparity map (uint16 / 256) -> optical-frame points.
* :func:`fit_road_pose`: the camera's roll, pitch and height over the road, fitted robustly on
  ground-truth points, as a user would fit ``base_height`` from a LiDAR.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.geometry import R_BODY_FROM_OPTICAL, Attitude
from roadbev_lab.data.lidar_labels import LabelConfig, LabelError, fit_road_plane

__all__ = [
    "KittiFrame",
    "RoadPose",
    "disparity_points",
    "fit_road_pose",
    "load_frames",
    "read_calib",
    "stereo_camera",
    "velo_to_camera",
]


def read_calib(path: str | Path) -> dict[str, np.ndarray]:
    """``name -> values`` of a KITTI calibration file (``P2`` [3, 4], ``R0_rect`` [3, 3]...).

    Raises:
        ValueError: a line that is not ``NAME: numbers``.
    """
    out: dict[str, np.ndarray] = {}
    for n, line in enumerate(Path(path).read_text().splitlines(), 1):
        if not line.strip():
            continue
        name, sep, rest = line.partition(":")
        if not sep:
            raise ValueError(f"{path}:{n}: not 'NAME: values'")
        values = np.array([float(v) for v in rest.split()], dtype=np.float64)
        if values.size == 12:
            values = values.reshape(3, 4)
        elif values.size == 9:
            values = values.reshape(3, 3)
        out[name.strip()] = values
    return out


def stereo_camera(P_left: np.ndarray, P_right: np.ndarray, width: int, height: int) -> StereoCamera:
    """The rectified pair of two 3x4 projection matrices (baseline from their x offsets)."""
    fx = float(P_left[0, 0])
    baseline = (float(P_left[0, 3]) - float(P_right[0, 3])) / fx
    return StereoCamera(fx, float(P_left[1, 1]), float(P_left[0, 2]), float(P_left[1, 2]), baseline, width, height)


def velo_to_camera(calib: dict[str, np.ndarray], left: str = "P2") -> tuple[np.ndarray, np.ndarray]:
    """``(R, t)`` with ``p_cam = R @ p_velo + t`` into the rectified camera of ``left``."""
    tr = np.asarray(calib["Tr_velo_to_cam"]).reshape(3, 4)
    r0 = np.asarray(calib["R0_rect"]).reshape(3, 3)
    P = np.asarray(calib[left]).reshape(3, 4)
    offset = np.linalg.solve(P[:, :3], P[:, 3])  # camera `left` relative to the rectified cam 0
    return r0 @ tr[:, :3], r0 @ tr[:, 3] + offset


def disparity_points(disparity: np.ndarray, camera: StereoCamera) -> np.ndarray:
    """[N, 3] optical-frame points of the valid pixels of a disparity map (pixels, > 0)."""
    d = np.asarray(disparity, dtype=np.float64)
    v, u = np.nonzero(d > 0)
    z = camera.fx * camera.baseline / d[v, u]
    return np.stack([(u - camera.cx) * z / camera.fx, (v - camera.cy) * z / camera.fy, z], axis=1)


class RoadPose(NamedTuple):
    """The camera over the road: the attitude making the road level, and its height (m)."""

    attitude: Attitude
    base_height: float
    sigma_m: float
    inliers: int


def fit_road_pose(points_cam: np.ndarray, grid: GridSpec, config: LabelConfig | None = None) -> RoadPose:
    """Roll, pitch and height of the camera over the road plane under the grid.

    The points (optical frame, [N, 3]) over the grid's window are fitted with the labeller's
    robust plane (:func:`roadbev_lab.data.lidar_labels.fit_road_plane`); the attitude is the one that
    makes that plane horizontal and ``base_height`` the camera's distance from it.

    Raises:
        LabelError: too few points over the window.
    """
    config = config or LabelConfig()
    p = np.asarray(points_cam, dtype=np.float64)[:, :3]
    m = config.region_margin_m
    # A level "pseudo road frame": x = forward (optical z), y = left (-optical x), z = up.
    q = np.stack([p[:, 2], -p[:, 0], -p[:, 1]], axis=1)
    window = (
        (q[:, 0] >= grid.x_min - m)
        & (q[:, 0] <= grid.x_max + m)
        & (q[:, 1] >= grid.y_min - m)
        & (q[:, 1] <= grid.y_max + m)
    )
    if window.sum() < 10:
        raise LabelError(f"only {int(window.sum())} ground-truth point(s) over the window")
    h0 = -float(np.median(q[window, 2]))
    q = q[window]
    q[:, 2] += h0
    plane = fit_road_plane(q, config)
    # -y + h0 = a + b z - c x  <=>  y - c x + b z = h0 - a (normal m points down, +y).
    normal = np.array([-plane.slope_y, 1.0, plane.slope_x])
    norm = float(np.linalg.norm(normal))
    up_body = R_BODY_FROM_OPTICAL @ (-normal / norm)
    pitch = -math.asin(float(np.clip(up_body[0], -1.0, 1.0)))
    roll = math.atan2(float(up_body[1]), float(up_body[2]))
    return RoadPose(Attitude(roll, pitch), (h0 - plane.offset) / norm, plane.sigma, plane.inliers)


class KittiFrame(NamedTuple):
    """One real KITTI stereo frame of :func:`load_frames` with its ground truth.

    Attributes:
        name: short name of the frame.
        left, right: rectified RGB images [H, W, 3] uint8.
        camera: the rectified rig.
        points: [N, 3] ground-truth points in the ``points_frame`` (Velodyne or left optical).
        rotation, translation: ``points_frame`` -> left optical frame (identity for disparity GT).
        points_frame: "velodyne" or "stereo_left_optical_frame".
    """

    name: str
    left: np.ndarray
    right: np.ndarray
    camera: StereoCamera
    points: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    points_frame: str


def _rgb(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise FileNotFoundError(f"cannot read image {path}")
    return np.ascontiguousarray(image[:, :, ::-1])


def _disparity(path: Path) -> np.ndarray:
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise FileNotFoundError(f"cannot read disparity {path}")
    return raw.astype(np.float64) / 256.0


def load_frames(root: str | Path) -> list[KittiFrame]:
    """The three KITTI frames under ``root``, each in the folder and with the file names of its public
    source (``sttr_kitti2015``, ``rob501_kitti2012``, ``stereo_rcnn_demo/demo``).

    * ``kitti2015_000046``: colour pair, GT from ``disp_occ_0``; the calibration is the 2011_09_26
      one that ``stereo_rcnn_demo/demo/calib.txt`` carries (no calibration ships with the frame;
      1242 x 375 rectified is that raw date's size only).
    * ``kitti2012_000070``: the grey pair (the GT disparity belongs to cameras 0/1), P0/P1.
    * ``kitti_object_lidar``: colour pair and one raw Velodyne scan, ``Tr_velo_to_cam``.
    """
    root = Path(root)
    demo = root / "stereo_rcnn_demo" / "demo"
    demo_calib = read_calib(demo / "calib.txt")
    eye, zero = np.eye(3), np.zeros(3)
    frames = []
    k15 = root / "sttr_kitti2015" / "training"
    left = _rgb(k15 / "image_2" / "000046_10.png")
    camera = stereo_camera(demo_calib["P2"], demo_calib["P3"], left.shape[1], left.shape[0])
    pts = disparity_points(_disparity(k15 / "disp_occ_0" / "000046_10.png"), camera)
    frames.append(
        KittiFrame(
            "kitti2015_000046",
            left,
            _rgb(k15 / "image_3" / "000046_10.png"),
            camera,
            pts,
            eye,
            zero,
            "stereo_left_optical_frame",
        )
    )
    k12 = root / "rob501_kitti2012"
    calib12 = read_calib(k12 / "calib" / "000070.txt")
    left = _rgb(k12 / "image_0" / "000070_10.png")
    camera = stereo_camera(calib12["P0"], calib12["P1"], left.shape[1], left.shape[0])
    pts = disparity_points(_disparity(k12 / "disp_occ" / "000070_10.png"), camera)
    frames.append(
        KittiFrame(
            "kitti2012_000070",
            left,
            _rgb(k12 / "image_1" / "000070_10.png"),
            camera,
            pts,
            eye,
            zero,
            "stereo_left_optical_frame",
        )
    )
    left = _rgb(demo / "left.png")
    camera = stereo_camera(demo_calib["P2"], demo_calib["P3"], left.shape[1], left.shape[0])
    velo = np.fromfile(demo / "lidar.bin", dtype=np.float32).reshape(-1, 4)
    R, t = velo_to_camera(demo_calib)
    frames.append(
        KittiFrame(
            "kitti_object_lidar",
            left,
            _rgb(demo / "right.png"),
            camera,
            velo[:, :3].astype(np.float64),
            R,
            t,
            "velodyne",
        )
    )
    return frames
