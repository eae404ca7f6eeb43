"""``adabins``: a learned monocular depth network (AdaBins-lite) converted to the grid.

The image-view protocol of the paper's Table I for monocular methods: the network
(:class:`roadbev_core.models.adabins.AdaBinsLite`) estimates the left image's depth, which is
resampled to the image's pixels in the window that sees the grid, turned into road-frame points
(:func:`roadbev_core.backends.image_view.road_points`) and binned into the grid as the labels are
(:func:`~roadbev_core.backends.image_view.cell_elevations`), each point's height 1-sigma from
the spread of the network's depth distribution. The registry's calibration step then fits the
sigma like every backend's.

Options:

* ``checkpoint``: an AdaBins-lite checkpoint (``roadbev train --kind adabins``); default the shipped
  ``checkpoints/adabins_lite.pt``.
* ``threads``: torch intra-op threads (default: torch's current setting).
* ``min_points``: cells with fewer points are NaN (default 1).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, cast

import cv2
import numpy as np
import torch

from roadbev_core.backends.baseline import BaselineBackend, check_options
from roadbev_core.backends.common import StageClock
from roadbev_core.backends.image_view import cell_elevations, match_window, road_points
from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.frame import Estimate, Frame, FrameError
from roadbev_core.geometry import Attitude
from roadbev_core.models.adabins import AdaBinsConfig, AdaBinsLite
from roadbev_core.models.roadbev import prepare_image

__all__ = ["AdaBinsBackend", "create_adabins", "depth_pixels", "grid_window", "network_image"]


def grid_window(grid: GridSpec, camera: StereoCamera, attitude: Attitude) -> tuple[slice, slice]:
    """Rows and columns of the image that see the grid's volume."""
    window = match_window(grid, camera, attitude, margin_px=0, block_size=1)
    # a monocular rig has no disparities: the window's columns need no room for a search
    left = window.left + window.min_disparity + window.num_disparities
    return slice(window.top, window.bottom), slice(min(left, window.right - 1), window.right)


def network_image(image: np.ndarray, config: AdaBinsConfig) -> np.ndarray:
    """RGB (or grey) uint8 [H, W(, 3)] -> uint8 [3, h, w] at the network's input size (area resize)."""
    image = np.asarray(image)
    if image.dtype != np.uint8:
        raise FrameError(f"adabins needs 8-bit images, got {image.dtype}")
    return prepare_image(np.ascontiguousarray(image[:, :, :3]) if image.ndim == 3 else image, config)


def depth_pixels(config: AdaBinsConfig, camera: StereoCamera) -> tuple[np.ndarray, np.ndarray]:
    """The image coordinates (rows [h], columns [w]) of the network's output pixels' centres."""
    h, w = config.input_height // 2, config.input_width // 2
    rows = (np.arange(h) + 0.5) * (camera.height / h) - 0.5
    cols = (np.arange(w) + 0.5) * (camera.width / w) - 0.5
    return rows, cols


class AdaBinsBackend(BaselineBackend):
    """AdaBins-lite behind the backend protocol (see the module docstring)."""

    name = "adabins"
    needs_stereo = False

    def __init__(self, grid: GridSpec, *, checkpoint: str | Path | None = None, threads: int | None = None,
                 min_points: int = 1) -> None:
        super().__init__(grid, checkpoint=checkpoint, threads=threads, min_points=min_points)
        self.model = cast("AdaBinsLite", self.network)

    @torch.inference_mode()
    def estimate(self, frame: Frame) -> Estimate:
        """Elevation and uncertainty of ``self.grid`` from the left image."""
        camera = frame.camera
        self.check_rig(camera)
        torch.set_flush_denormal(True)
        clock = StageClock()
        image = torch.from_numpy(network_image(frame.left, self.model.config))[None]
        clock.lap("preprocess")
        depth, sigma, _ = self.model(image)  # [1, h, w] each
        clock.lap("network")
        rows, cols = grid_window(self.grid, camera, frame.attitude)
        # the half-input-size maps resampled to the image's pixels (pixel centres aligned)
        full = (camera.width, camera.height)
        z = cv2.resize(depth[0].numpy(), full, interpolation=cv2.INTER_LINEAR)[rows, cols]  # [h, w]
        s = cv2.resize(sigma[0].numpy(), full, interpolation=cv2.INTER_LINEAR)[rows, cols]
        points = road_points(z, np.arange(rows.start, rows.stop), np.arange(cols.start, cols.stop), camera,
                             frame.attitude, self.grid.base_height)
        # a depth error moves a point along its ray: its vertical share is (camera height above it) / depth
        point_sigma = (s / z).ravel() * (self.grid.base_height - points[:, 2])
        elevation, uncertainty = cell_elevations(points, point_sigma, self.grid, self.min_points, clock)
        return Estimate(elevation=elevation, uncertainty=uncertainty, timings_ms=clock.timings)


def create_adabins(grid: GridSpec, **options: Any) -> AdaBinsBackend:
    """Backend factory of AdaBins-lite (options: see the module docstring)."""
    check_options("adabins", options)
    return AdaBinsBackend(grid, **options)
