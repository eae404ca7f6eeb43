"""``gwcnet``: a learned image-view stereo matcher (GwcNet-lite) converted to the grid.

The image-view protocol of the paper's Table I with a learned matcher in place of OpenCV's: the
network (:class:`roadbev_core.models.gwcnet.GwcNetLite`) matches the window of the image pair
that sees the grid over the disparities its volume can produce (:func:`search_window`, the
``sgbm`` / ``bm`` window), and its disparities become an elevation map exactly as theirs do
(:func:`roadbev_core.backends.image_view.disparity_road_points`, then
:func:`~roadbev_core.backends.image_view.cell_elevations`: mean height per cell, the label
code's binning), with each pixel's disparity 1-sigma the spread of the network's disparity
distribution. The registry's calibration step then fits the sigma like every backend's.

Options:

* ``checkpoint``: a GwcNet-lite checkpoint (``roadbev train --kind gwcnet``); default the shipped
  ``checkpoints/gwcnet_lite.pt``.
* ``threads``: torch intra-op threads (default: torch's current setting).
* ``min_points``: cells with fewer points are NaN (default 1).
* ``max_sigma_px``: pixels whose disparity distribution is wider than this (1-sigma, pixels)
  are left out, as a matcher's uniqueness test leaves out an ambiguous match (0: none; the
  default is :data:`DEFAULT_MAX_SIGMA_PX`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch

from roadbev_core.backend_plugins import BackendError
from roadbev_core.backends.baseline import BaselineBackend, check_options
from roadbev_core.backends.common import StageClock
from roadbev_core.backends.image_view import (
    MatchWindow,
    cell_elevations,
    disparity_height_sigma,
    disparity_road_points,
    match_window,
)
from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.frame import Estimate, Frame, FrameError
from roadbev_core.geometry import Attitude
from roadbev_core.models.gwcnet import GwcNetLite, shift_right

__all__ = ["GwcNetBackend", "create_gwcnet", "gwcnet_inputs", "search_window"]

# Disparities searched beyond the grid volume's own range, on either side (the image-view
# matchers' default margin).
DISPARITY_MARGIN_PX = 4
# The widest disparity distribution kept, chosen on the tuning scenes (benchmarks/tune_gwcnet.py):
# the network's distributions are wide where it cannot match (the far rows, texture-less
# patches), and a limit keeps the image-view comparison of a matcher that declines such pixels.
DEFAULT_MAX_SIGMA_PX = 2.0


def search_window(grid: GridSpec, camera: StereoCamera, attitude: Attitude) -> MatchWindow:
    """The image window that sees the grid's volume and the disparities it can produce (the
    image-view matchers' window, without their block margin)."""
    return match_window(grid, camera, attitude, margin_px=DISPARITY_MARGIN_PX, block_size=1)


def gwcnet_inputs(frame: Frame, window: MatchWindow) -> tuple[np.ndarray, np.ndarray]:
    """The network's inputs [H, W, 3] uint8 (H, W the window's sides rounded up to the network's
    stride, zero-padded): the left image's window and the right image's, shifted by the window's
    first disparity. Grey images are repeated into three channels."""
    if frame.right is None:
        raise FrameError("gwcnet needs a stereo frame (the right image is missing)")
    s = GwcNetLite.stride
    h, w = window.bottom - window.top, window.right - window.left
    shape = (-(-h // s) * s, -(-w // s) * s, 3)

    def rgb(image: np.ndarray) -> np.ndarray:
        image = np.asarray(image)
        if image.dtype != np.uint8:
            raise FrameError(f"gwcnet needs 8-bit images, got {image.dtype}")
        return image if image.ndim == 3 else np.repeat(image[..., None], 3, axis=2)

    left = np.zeros(shape, np.uint8)
    right = np.zeros(shape, np.uint8)
    rows, cols = slice(window.top, window.bottom), slice(window.left, window.right)
    left[:h, :w] = rgb(frame.left)[rows, cols, :3]
    right[:h, :w] = shift_right(rgb(frame.right), window.min_disparity)[rows, cols, :3]
    return left, right


class GwcNetBackend(BaselineBackend):
    """GwcNet-lite behind the backend protocol (see the module docstring)."""

    name = "gwcnet"
    needs_stereo = True

    def __init__(self, grid: GridSpec, *, checkpoint: str | Path | None = None, threads: int | None = None,
                 min_points: int = 1, max_sigma_px: float = DEFAULT_MAX_SIGMA_PX) -> None:
        if not (math.isfinite(float(max_sigma_px)) and float(max_sigma_px) >= 0):
            raise BackendError(f"gwcnet backend: max_sigma_px must be >= 0 (0: off), got {max_sigma_px}")
        super().__init__(grid, checkpoint=checkpoint, threads=threads, min_points=min_points)
        self.max_sigma_px = float(max_sigma_px)
        self.model = cast("GwcNetLite", self.network)

    @torch.inference_mode()
    def estimate(self, frame: Frame) -> Estimate:
        """Elevation and uncertainty of ``self.grid`` for one stereo frame."""
        camera = frame.camera
        if camera.baseline <= 0:
            raise FrameError("gwcnet needs a stereo rig with a positive baseline")
        self.check_rig(camera)
        torch.set_flush_denormal(True)
        clock = StageClock()
        window = search_window(self.grid, camera, frame.attitude)
        left, right = gwcnet_inputs(frame, window)  # [H, W, 3]
        clock.lap("preprocess")
        disparity, sigma = self.model(torch.from_numpy(left).permute(2, 0, 1)[None],
                                      torch.from_numpy(right).permute(2, 0, 1)[None])
        clock.lap("network")
        h, w = window.bottom - window.top, window.right - window.left
        d = disparity[0, :h, :w].numpy() + np.float32(window.min_disparity)  # [h, w] pixels
        s = sigma[0, :h, :w].numpy()
        # a match must lie inside the right image
        cols = np.arange(window.left, window.right, dtype=np.float32)[None, :]
        valid = np.isfinite(d) & (d > 0.5) & (cols - d >= 0)
        if self.max_sigma_px:
            valid &= s <= self.max_sigma_px
        points, depth = disparity_road_points(d, valid, window, camera, frame.attitude, self.grid.base_height)
        sigma_h = disparity_height_sigma(points, depth, s.ravel(), camera, self.grid.base_height)
        elevation, uncertainty = cell_elevations(points, sigma_h, self.grid, self.min_points, clock)
        return Estimate(elevation=elevation, uncertainty=uncertainty, timings_ms=clock.timings)

    def describe(self) -> dict[str, Any]:
        """Settings as a JSON-able dict (for benchmark records)."""
        return {**super().describe(), "max_sigma_px": self.max_sigma_px}


def create_gwcnet(grid: GridSpec, **options: Any) -> GwcNetBackend:
    """Backend factory of GwcNet-lite (options: see the module docstring)."""
    check_options("gwcnet", options, frozenset({"max_sigma_px"}))
    return GwcNetBackend(grid, **options)
