"""What flows through the pipeline: a :class:`Frame` in, an :class:`Estimate` out."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.errors import RoadbevError
from roadbev_core.geometry import Attitude

__all__ = ["Estimate", "Frame", "FrameError", "ImplausibleFrame", "implausible"]


class FrameError(RoadbevError, ValueError):
    """A frame whose images or calibration cannot be processed."""


class ImplausibleFrame(FrameError):
    """A frame whose rig or attitude no road camera has (a broken calibration or IMU): refused with
    the cause, instead of a grid that comes out empty without saying why."""


# What a road-facing camera on a car can be: wider limits than any rig the package was made for,
# so that only a broken calibration or attitude trips them.
HFOV_DEG = (10.0, 150.0)  # horizontal field of view
ASPECT = (0.8, 1.25)  # fx / fy (pixels nearly square)
BASELINE_M = (0.02, 2.0)  # stereo baseline
MAX_TILT_DEG = 30.0  # |roll| and |pitch| against gravity


def implausible(frame: Frame) -> str:
    """Why ``frame``'s rig or attitude is not a road camera's (the first reason), or ""."""
    cam = frame.camera
    hfov = math.degrees(2.0 * math.atan2(cam.width / 2.0, cam.fx))
    if not HFOV_DEG[0] <= hfov <= HFOV_DEG[1]:
        return (f"calibration: fx {cam.fx:g} px gives a {hfov:.1f} deg horizontal field of view on a {cam.width} px "
                f"image (plausible {HFOV_DEG[0]:g}-{HFOV_DEG[1]:g})")
    if not ASPECT[0] <= cam.fx / cam.fy <= ASPECT[1]:
        return f"calibration: fx / fy = {cam.fx / cam.fy:.2f} (plausible {ASPECT[0]:g}-{ASPECT[1]:g})"
    if not (0.0 <= cam.cx <= cam.width and 0.0 <= cam.cy <= cam.height):
        return (f"calibration: the principal point ({cam.cx:g}, {cam.cy:g}) lies outside the "
                f"{cam.width}x{cam.height} image")
    if frame.is_stereo and not BASELINE_M[0] <= cam.baseline <= BASELINE_M[1]:
        return f"calibration: stereo baseline {cam.baseline:g} m (plausible {BASELINE_M[0]:g}-{BASELINE_M[1]:g} m)"
    roll, pitch = math.degrees(frame.attitude.roll), math.degrees(frame.attitude.pitch)
    if max(abs(roll), abs(pitch)) > MAX_TILT_DEG:
        return (f"attitude: roll {roll:.1f} deg, pitch {pitch:.1f} deg against gravity (a road camera stays within "
                f"{MAX_TILT_DEG:g} deg: check the IMU and imu_to_camera_rpy_deg)")
    return ""


@dataclass(frozen=True)
class Frame:
    """One synchronised camera set with its calibration and attitude.

    Attributes:
        left: [H, W, 3] uint8 RGB (or [H, W] uint8 grey) rectified left image.
        right: the rectified right image, same size and type, or None for mono.
        camera: the rig; its width/height must match the images.
        attitude: camera roll/pitch at the image stamp.
        stamp_ns: the left image's stamp (nanoseconds).
    """

    left: np.ndarray
    right: np.ndarray | None
    camera: StereoCamera
    attitude: Attitude
    stamp_ns: int = 0

    def __post_init__(self) -> None:
        for name in ("left", "right"):
            img = getattr(self, name)
            if img is None:
                continue
            if not isinstance(img, np.ndarray) or img.ndim not in (2, 3) or img.size == 0:
                raise FrameError(f"{name} image must be a non-empty [H,W] or [H,W,3] array")
            if img.ndim == 3 and img.shape[2] != 3:
                raise FrameError(f"{name} image must have 3 channels (RGB), got {img.shape[2]}")
            h, w = img.shape[:2]
            if (w, h) != self.camera.size:
                raise FrameError(
                    f"{name} image is {w}x{h} but the camera calibration says "
                    f"{self.camera.width}x{self.camera.height}"
                )
        if self.right is not None and self.right.shape != self.left.shape:
            raise FrameError(f"left {self.left.shape} and right {self.right.shape} images differ")

    @property
    def is_stereo(self) -> bool:
        return self.right is not None


@dataclass
class Estimate:
    """A backend's answer for one frame, on the grid it was asked for.

    Attributes:
        elevation: [n_rows, n_cols] float32 metres (road frame z), NaN = no estimate.
        uncertainty: [n_rows, n_cols] float32 1-sigma metres, NaN where elevation is NaN.
        timings_ms: wall time per stage (``projection``, ``cost``, ``network``, ``post``...).
        out_of_distribution: the backend ran outside what it was made for (a learned backend on
            a rig or grid beyond its training, run on request): every cell is flagged with a
            large sigma and the calibration leaves it alone.
    """

    elevation: np.ndarray
    uncertainty: np.ndarray
    timings_ms: dict[str, float] = field(default_factory=dict)
    out_of_distribution: bool = False

    def __post_init__(self) -> None:
        if self.elevation.ndim != 2 or self.elevation.shape != self.uncertainty.shape:
            raise ValueError(
                f"elevation {self.elevation.shape} and uncertainty {self.uncertainty.shape} "
                "must be equal 2-D grids"
            )

    def check_grid(self, grid: GridSpec) -> None:
        if self.elevation.shape != grid.shape:
            raise ValueError(f"estimate is {self.elevation.shape}, grid is {grid.shape}")

    @property
    def coverage(self) -> float:
        """Share of cells with an estimate (0..1)."""
        return float(np.isfinite(self.elevation).mean())
