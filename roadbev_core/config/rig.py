"""The one source of truth for the camera rig (:class:`StereoCamera`, pinhole, rectified).

Pixel convention (docs/interface/frames-and-grid.md): the centre of pixel column i, row j is at (u, v) = (i, j).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from roadbev_core.config.grid import ConfigError

__all__ = ["RSRD_CROP_TOP", "StereoCamera"]


@dataclass(frozen=True)
class StereoCamera:
    """A rectified stereo pair (left camera is the reference; pinhole, no distortion).

    Pixel convention (docs/interface/frames-and-grid.md): the centre of pixel column i, row j is at (u, v) = (i, j).

    Attributes:
        fx, fy, cx, cy: intrinsics of the rectified left image (pixels).
        baseline: distance between the optical centres (metres, > 0; 0 for a mono camera).
        width, height: image size (pixels).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float
    width: int
    height: int
    extra: dict[str, Any] = field(default_factory=dict, compare=False, hash=False, repr=False)

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy", "baseline"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(f"camera {name} must be a finite number, got {value!r}")
        if self.fx <= 0 or self.fy <= 0:
            raise ConfigError(f"camera focal lengths must be positive (fx={self.fx}, fy={self.fy})")
        if self.baseline < 0:
            raise ConfigError(f"stereo baseline must be >= 0 m, got {self.baseline}")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ConfigError(f"image size must be positive, got {self.width}x{self.height}")

    @property
    def K(self) -> np.ndarray:
        """[3, 3] intrinsic matrix."""
        return np.array(
            [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=np.float64
        )

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)``."""
        return (int(self.width), int(self.height))

    def scaled(self, factor: float) -> StereoCamera:
        """The same rig for images resized by ``factor`` (pixel centres stay at integers)."""
        if factor <= 0:
            raise ConfigError(f"scale factor must be positive, got {factor}")
        # With centres at integer coordinates, u' = (u + 0.5) * s - 0.5.
        return replace(
            self,
            fx=self.fx * factor,
            fy=self.fy * factor,
            cx=(self.cx + 0.5) * factor - 0.5,
            cy=(self.cy + 0.5) * factor - 0.5,
            width=int(round(self.width * factor)),
            height=int(round(self.height * factor)),
        )

    def resized(self, width: int, height: int) -> StereoCamera:
        """The same rig for images resized to ``width`` x ``height`` (anisotropic allowed)."""
        sx, sy = width / self.width, height / self.height
        return replace(
            self,
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
            width=int(width),
            height=int(height),
        )

    def cropped(self, left: int, top: int, width: int, height: int) -> StereoCamera:
        """The rig for the window ``[top:top+height, left:left+width]`` of the image."""
        if left < 0 or top < 0 or left + width > self.width or top + height > self.height:
            raise ConfigError(
                f"crop {width}x{height}+{left}+{top} does not fit a {self.width}x{self.height} image"
            )
        return replace(self, cx=self.cx - left, cy=self.cy - top, width=int(width), height=int(height))

    def to_dict(self) -> dict[str, float]:
        return {
            "fx": float(self.fx),
            "fy": float(self.fy),
            "cx": float(self.cx),
            "cy": float(self.cy),
            "baseline": float(self.baseline),
            "width": int(self.width),
            "height": int(self.height),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> StereoCamera:
        try:
            return cls(
                fx=float(data["fx"]),
                fy=float(data["fy"]),
                cx=float(data["cx"]),
                cy=float(data["cy"]),
                baseline=float(data.get("baseline", 0.0)),
                width=int(data["width"]),
                height=int(data["height"]),
            )
        except KeyError as exc:
            raise ConfigError(f"camera description lacks {exc.args[0]!r}") from None

    @classmethod
    def from_K(cls, K: np.ndarray, baseline: float, width: int, height: int) -> StereoCamera:
        K = np.asarray(K, dtype=np.float64).reshape(3, 3)
        return cls(
            fx=float(K[0, 0]),
            fy=float(K[1, 1]),
            cx=float(K[0, 2]),
            cy=float(K[1, 2]),
            baseline=float(baseline),
            width=int(width),
            height=int(height),
        )

    @classmethod
    def rsrd_half(cls) -> StereoCamera:
        """The real RSRD half-resolution rig (calib_20230317_half.pkl), cropped to 960 x 528.

        The paper crops the 960 x 540 images to 960 x 528. We keep rows 0..527 (drop the bottom
        12, the bonnet edge): over all 1,581 real RSRD attitudes the default grid projects into
        rows 4.2..524.3 of the uncropped image, so dropping the top rows instead would cut the
        far field at the steepest pitches (tests/roadbev_core/test_geometry.py checks this).
        """
        full = cls(
            fx=1004.7787,
            fy=1004.7787,
            cx=498.2207,
            cy=259.5176,
            baseline=0.118809,
            width=960,
            height=540,
        )
        return full.cropped(0, RSRD_CROP_TOP, 960, 528)


# Rows removed from the top of RSRD half-resolution images (960x540 -> 960x528 drops the bottom).
RSRD_CROP_TOP = 0
