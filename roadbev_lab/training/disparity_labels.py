"""Dense disparity labels for the image-view matchers, from an elevation label.

Image-view stereo networks are supervised per pixel. A synthetic scene's label is its elevation
map on the grid (the mean of the road surface in each cell); every left-image pixel whose ray
meets that surface inside the grid gets the disparity of the point where it meets it. The surface
between cell centres is bilinear, and the ray is marched from where it enters the grid's height
range (``z_max``) to where it leaves it (``z_min``), the first crossing refined by bisection:
the first crossing, so a bump hides what is behind it as in the rendered image. Pixels whose ray
leaves the grid before meeting the surface, or meets it where the label is NaN, get NaN.

Pure numpy over arrays; shapes in the comments.
"""

from __future__ import annotations

from typing import cast

import numpy as np

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.geometry import Attitude, ray_terms

__all__ = ["surface_depth", "surface_height"]

# Steps of the march through the grid's height range, then of the bisection of the first crossing.
MARCH_STEPS = 48
BISECTION_STEPS = 8


def surface_height(elevation: np.ndarray, grid: GridSpec, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The label's surface at road-frame (x, y) [...]: bilinear between cell centres (clamped to
    the outer centres within the grid), NaN outside the grid or next to a NaN cell."""
    r = (grid.x_max - x) / grid.resolution - 0.5  # fractional row of the centres
    c = (grid.y_max - y) / grid.resolution - 0.5
    inside = (r > -0.5) & (r < grid.n_rows - 0.5) & (c > -0.5) & (c < grid.n_cols - 0.5)
    r = np.clip(np.where(inside, r, 0.0), 0.0, grid.n_rows - 1.0)
    c = np.clip(np.where(inside, c, 0.0), 0.0, grid.n_cols - 1.0)
    r0 = np.minimum(r.astype(np.intp), grid.n_rows - 2)
    c0 = np.minimum(c.astype(np.intp), grid.n_cols - 2)
    fr, fc = r - r0, c - c0
    z = elevation
    value = ((1 - fr) * ((1 - fc) * z[r0, c0] + fc * z[r0, c0 + 1])
             + fr * ((1 - fc) * z[r0 + 1, c0] + fc * z[r0 + 1, c0 + 1]))
    return np.where(inside, value, np.nan)


def surface_depth(elevation: np.ndarray, grid: GridSpec, camera: StereoCamera, attitude: Attitude,
                  rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Optical depth [h, w] float32 at which each pixel's ray (rows [h] x cols [w] of the left
    image) first meets the label's surface (elevation [n_rows, n_cols] metres on ``grid``); NaN
    where it does not meet it inside the grid. Disparity = ``fx * baseline / depth``."""
    ray = ray_terms(camera, attitude, rows, cols).rays()  # [h, w, 3]
    down = ray[..., 2] < -1e-6  # rays that descend
    rz = np.where(down, ray[..., 2], -1.0)
    z_top, z_bottom = grid.z_max - grid.base_height, grid.z_min - grid.base_height
    depth_in = z_top / rz  # [h, w] where the ray enters the height range
    depth_out = z_bottom / rz

    def above(depth: np.ndarray) -> np.ndarray:
        """Height of the ray above the surface at ``depth`` [h, w] (NaN off the grid)."""
        x, y = depth * ray[..., 0], depth * ray[..., 1]
        return cast("np.ndarray", grid.base_height + depth * ray[..., 2] - surface_height(elevation, grid, x, y))

    span = depth_out - depth_in
    found = np.zeros(rz.shape, bool)
    lo = np.full(rz.shape, np.nan)
    prev_depth, prev_above = depth_in, above(depth_in)
    for k in range(1, MARCH_STEPS + 1):
        depth = depth_in + span * (k / MARCH_STEPS)
        now = above(depth)
        # the first step at which the ray has gone from above the surface to on or below it
        crossed = ~found & down & (prev_above > 0) & (now <= 0)
        lo = np.where(crossed, prev_depth, lo)
        found |= crossed
        prev_depth, prev_above = depth, now
    hi = lo + span / MARCH_STEPS
    for _ in range(BISECTION_STEPS):
        mid = 0.5 * (lo + hi)
        below = above(np.where(found, mid, depth_in)) <= 0
        hi = np.where(found & below, mid, hi)
        lo = np.where(found & ~below, mid, lo)
    # the crossing between the last point above and the first below, linearly interpolated
    a_lo, a_hi = above(np.where(found, lo, depth_in)), above(np.where(found, hi, depth_in))
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.clip(a_lo / (a_lo - a_hi), 0.0, 1.0)
    depth = lo + t * (hi - lo)
    return np.where(found & np.isfinite(depth), depth, np.nan).astype(np.float32)
