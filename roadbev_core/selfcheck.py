"""Self-checks any user can see: coverage per frame and, when it is low, the likely causes.

A backend that answers few cells (or none) usually does so for one of three reasons that can be
measured from the frame and the estimate alone:

* **no texture**: the road region of the left image is too uniform to match (night, glare, fresh
  asphalt, a covered lens);
* **bad rectification**: the right image is shifted vertically against the left (a stale or wrong
  calibration): after rectification the same road row must lie on the same image row;
* **base_height inconsistent with the road seen**: the road plane fitted to the estimate lies far
  from z = 0 (the parameter ``base_height`` or the IMU mounting is off), or no height of the
  vertical range matched at all while texture and rectification are fine.

:func:`self_check` is pure (numpy and OpenCV); the node publishes its result on ``/diagnostics``
(WARN below ``min_coverage_pct``, with the causes; measured only on such frames) and ``roadbev
eval`` prints the same hint.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from roadbev_core.backends.common import grey_u8
from roadbev_core.config import GridSpec
from roadbev_core.frame import Estimate, Frame
from roadbev_core.visibility import fit_road_plane

__all__ = [
    "MAX_PLANE_OFFSET_M",
    "MAX_VERTICAL_OFFSET_PX",
    "MIN_COVERAGE_PCT",
    "MIN_TEXTURE",
    "SelfCheck",
    "road_texture",
    "self_check",
    "vertical_offset_px",
]

MIN_COVERAGE_PCT = 30.0  # below this share of the grid a frame is WARN
MIN_TEXTURE = 2.0  # grey levels: std of the high-passed road region below this is "no texture"
MAX_VERTICAL_OFFSET_PX = 0.5  # a rectified pair is off by more than this
MAX_PLANE_OFFSET_M = 0.05  # the fitted road plane's height at the grid centre beyond this
_SEARCH_PX = 12  # vertical offsets searched (+-)


@dataclass(frozen=True)
class SelfCheck:
    """The health of one frame's estimate.

    Attributes:
        coverage_pct: share of the grid's cells with an estimate.
        ok: coverage at least the threshold (else the node's /diagnostics says WARN).
        causes: the likely causes measured (empty when ok or when none was found).
        texture: std (grey levels) of the high-passed road region of the left image.
        vertical_offset_px: measured vertical shift of the right image against the left (None
            for mono).
        plane_offset_m: the fitted road plane's z at the grid centre (None without estimates).
    """

    coverage_pct: float
    ok: bool
    causes: tuple[str, ...]
    texture: float
    vertical_offset_px: float | None
    plane_offset_m: float | None

    @property
    def message(self) -> str:
        """One line: coverage and, when low, the likely causes."""
        head = f"coverage {self.coverage_pct:.1f} %"
        if self.ok:
            return head
        return f"{head} (low): " + ("; ".join(self.causes) if self.causes else "cause unknown")


def road_texture(image: np.ndarray) -> float:
    """Std (grey levels) of the lower half of ``image`` minus its Gaussian blur (sigma 4 px).

    Args:
        image: [H, W, 3] or [H, W] uint8.
    """
    grey = grey_u8(image).astype(np.float32)
    lower = grey[grey.shape[0] // 2 :]
    detail = lower - cv2.GaussianBlur(lower, (0, 0), 4.0)
    return float(detail.std())


def vertical_offset_px(left: np.ndarray, right: np.ndarray, search: int = _SEARCH_PX) -> float:
    """Vertical shift (px, + = the right image lower) between a rectified pair's road regions.

    Horizontal disparity moves the content along rows, so the mean of every row (over the central
    columns) is nearly the same in both images of a well-rectified pair; a vertical offset shifts
    that profile. The shift maximising the correlation of the row profiles' derivatives is
    refined by a parabola.

    Args:
        left, right: [H, W, 3] or [H, W] uint8, same size.
        search: shifts tried (+-px).
    """
    profiles = []
    for image in (left, right):
        grey = grey_u8(image).astype(np.float32)
        h, w = grey.shape
        profile = grey[h // 2 :, w // 8 : w - w // 8].mean(axis=1)  # [h/2] road rows
        profiles.append(np.diff(profile))
    a, b = profiles
    n = len(a) - 2 * search
    if n < 8:
        return 0.0
    centre = a[search : search + n] - a[search : search + n].mean()
    scores = []
    for shift in range(-search, search + 1):
        window = b[search + shift : search + shift + n]
        window = window - window.mean()
        denom = float(np.linalg.norm(centre) * np.linalg.norm(window)) or 1.0
        scores.append(float(centre @ window) / denom)
    best = int(np.argmax(scores))
    offset = float(best - search)
    if 0 < best < len(scores) - 1:
        lo, mid, hi = scores[best - 1], scores[best], scores[best + 1]
        curvature = lo - 2.0 * mid + hi
        if curvature < 0:
            offset += 0.5 * (lo - hi) / curvature
    return offset


def self_check(
    estimate: Estimate,
    frame: Frame,
    grid: GridSpec,
    *,
    min_coverage_pct: float = MIN_COVERAGE_PCT,
    min_texture: float = MIN_TEXTURE,
    max_vertical_offset_px: float = MAX_VERTICAL_OFFSET_PX,
    max_plane_offset_m: float = MAX_PLANE_OFFSET_M,
    measure_when_ok: bool = True,
) -> SelfCheck:
    """Coverage of ``estimate`` and, when it falls below ``min_coverage_pct``, the likely causes.

    The measurements are made on every call (cheap: a blur of half an image and a row profile)
    so a caller may also log them when coverage is fine.

    Args:
        estimate: the backend's answer for ``frame`` on ``grid``.
        frame: the frame (images and rig).
        grid: the grid.
        min_coverage_pct: WARN below this.
        min_texture: "no texture" below this (grey levels, :func:`road_texture`).
        max_vertical_offset_px: "bad rectification" beyond this (:func:`vertical_offset_px`).
        max_plane_offset_m: "base_height inconsistent" when the fitted road plane's height at the
            grid centre is further than this from z = 0.
        measure_when_ok: with False, a frame whose coverage is fine is not measured (texture NaN,
            offsets None): what the node does on every frame, so a healthy frame costs nothing.

    Returns:
        A :class:`SelfCheck`; its ``message`` is the one-line hint.
    """
    coverage = 100.0 * float(np.isfinite(estimate.elevation).mean())
    if not measure_when_ok and coverage >= min_coverage_pct:
        return SelfCheck(coverage, True, (), float("nan"), None, None)
    texture = road_texture(frame.left)
    offset = None if frame.right is None else vertical_offset_px(frame.left, frame.right)
    plane = fit_road_plane(estimate.elevation, grid)
    plane_offset = None
    if plane.cells:
        cx, cy = grid.centre
        plane_offset = plane.offset + plane.slope_x * cx + plane.slope_y * cy
    ok = coverage >= min_coverage_pct
    causes: list[str] = []
    if not ok:
        if texture < min_texture:
            causes.append(f"no texture (road detail {texture:.1f} grey levels < {min_texture})")
        if offset is not None and abs(offset) > max_vertical_offset_px:
            causes.append(f"bad rectification (the right image is {offset:+.1f} px off vertically)")
        if plane_offset is not None and abs(plane_offset) > max_plane_offset_m:
            causes.append(
                f"base_height inconsistent with the road seen (road plane at z = {100 * plane_offset:+.1f} cm, "
                f"expected 0; base_height {grid.base_height} m)"
            )
        elif plane_offset is None and not causes:
            causes.append(
                f"no height in z {grid.z_min:+.2f}..{grid.z_max:+.2f} m matched although texture and "
                f"rectification look fine: base_height ({grid.base_height} m) or the vertical range "
                "may be wrong for this rig"
            )
    return SelfCheck(coverage, ok, tuple(causes), texture, offset, plane_offset)
