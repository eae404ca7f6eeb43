"""What a stereo rig can resolve of the road beyond the grid: the physics behind the far-field grid.

The far-field grid (:class:`roadbev_core.config.FarFieldConfig`, docs/concepts/grid.md, "The far
field") is coarser than the paper's because the image is: a camera ``h`` above a level road,
pitched down by ``pitch``, sees the road ``x`` ahead along a ray ``atan(h / x)`` below the
horizon, and

* **ground sampling**: one image row covers ``1 / (dv/dx)`` metres of road along x, with
  ``dv/dx = fy * h / ((x^2 + h^2) cos^2(atan(h / x) - pitch))``: on the RSRD rig about 4.5 cm at
  the grid's far edge (7.08 m) and 19 cm at 15 m (a 3 cm cell there would hold a fifth of an
  image row);
* **height precision**: a disparity error ``sigma_d`` scales the point's range by
  ``sigma_d / d``, which moves a point ``h`` below the camera by ``h * sigma_d / d``, i.e.
  ``sigma_h = h * Z * sigma_d / (fx * B)`` (``Z`` the depth along the optical axis, ``B`` the
  baseline): 1.3 cm at 15 m for a tenth of a pixel;
* **view**: the image's top row looks ``pitch - atan(cy / fy)`` below the horizon, so the road
  is in view only up to ``h / tan(pitch - atan((cy + 0.5) / fy))`` (13.6 m on the RSRD rig at its
  mean pitch of 19.1 deg; 15 m needs a pitch of 18.7 deg or less).

:func:`road_sampling` computes these at any distances through the one projection
(:mod:`roadbev_core.geometry`); :func:`far_cell_size` turns them into the far grid's cell;
:func:`farthest_road_in_view` gives the view limit.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.geometry import Attitude, project_points, road_to_camera

__all__ = ["SUBPIXEL_PRECISION_PX", "RoadSampling", "cell_row_length", "far_cell_size", "farthest_road_in_view",
           "height_sigma", "road_sampling"]

# The disparity precision of a good sub-pixel matcher on textured, rectified images (about a
# tenth of a pixel): the physical limit the far field's errors are compared with.
SUBPIXEL_PRECISION_PX = 0.1
# Finite-difference step (m) of the rows-per-metre derivative.
_DX = 1e-3


class RoadSampling(NamedTuple):
    """How the rig sees a level road at distances ``x`` ahead (each [N], float64).

    Attributes:
        distance_m: x ahead of the camera (m).
        depth_m: depth along the optical axis Z (m).
        disparity_px: the stereo disparity ``fx * B / Z`` (px).
        rows_per_m: image rows per metre of road along x.
        row_length_m: metres of road along x one image row covers (``1 / rows_per_m``).
        cols_per_m: image columns per metre of road across (``fx / Z``).
        height_sigma_m: the 1-sigma height error of a disparity error ``sigma_d``
            (``h * Z * sigma_d / (fx * B)``).
        in_view: the road point projects inside the image's rows.
    """

    distance_m: np.ndarray
    depth_m: np.ndarray
    disparity_px: np.ndarray
    rows_per_m: np.ndarray
    row_length_m: np.ndarray
    cols_per_m: np.ndarray
    height_sigma_m: np.ndarray
    in_view: np.ndarray


def height_sigma(depth_m: np.ndarray, drop_m: np.ndarray | float, camera: StereoCamera,
                 disparity_sigma_px: float = SUBPIXEL_PRECISION_PX) -> np.ndarray:
    """The 1-sigma height error ``drop * Z * sigma_d / (fx * B)`` (m) of points at depths ``Z``
    (m) lying ``drop`` (m) below the camera, from a disparity error ``sigma_d`` (px)."""
    scale = disparity_sigma_px / (camera.fx * camera.baseline)
    return np.asarray(np.asarray(drop_m, np.float64) * np.asarray(depth_m, np.float64) * scale, np.float64)


def cell_row_length(camera: StereoCamera, attitude: Attitude, grid: GridSpec) -> np.ndarray:
    """[R, C] float32: the length of road along x (m) one image row covers at each cell's centre on
    the reference plane (the ground sampling of :class:`RoadSampling`, at every cell; 0 behind the
    camera or where the road is seen edge-on)."""
    x, y = np.meshgrid(grid.x_centres(), grid.y_centres(), indexing="ij")  # [R, C]

    def rows(at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        road = np.stack([at, y, np.zeros_like(at)], axis=-1).reshape(-1, 3)
        _, v, depth = project_points(road_to_camera(road, attitude, grid.base_height), camera)
        return v.reshape(grid.shape), depth.reshape(grid.shape)

    v_near, depth = rows(x - _DX)
    v_far, _ = rows(x + _DX)
    per_m = (v_near - v_far) / (2 * _DX)  # image rows per metre of road
    with np.errstate(divide="ignore", invalid="ignore"):
        length = np.where((depth > 0) & (per_m > 0), 1.0 / per_m, 0.0)
    return length.astype(np.float32)


def road_sampling(camera: StereoCamera, pitch_rad: float, base_height: float, distance_m: npt.ArrayLike,
                  disparity_sigma_px: float = SUBPIXEL_PRECISION_PX) -> RoadSampling:
    """Ground sampling and height precision of the road straight ahead (y = 0, z = 0, no roll).

    Args:
        camera: the rig (a stereo baseline > 0).
        pitch_rad: the camera's pitch below the horizon (rad).
        base_height: the camera's height above the road (m).
        distance_m: [N] distances ahead (m, > 0).
        disparity_sigma_px: the disparity's 1-sigma (px).

    Raises:
        ValueError: no baseline, or a distance not ahead of the camera.
    """
    if camera.baseline <= 0:
        raise ValueError("the height precision needs a stereo baseline > 0")
    x = np.atleast_1d(np.asarray(distance_m, np.float64))
    if not np.all(x > 0):
        raise ValueError("distances must be ahead of the camera (> 0 m)")
    attitude = Attitude(0.0, float(pitch_rad))

    def image_row(at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        road = np.stack([at, np.zeros_like(at), np.zeros_like(at)], axis=-1)  # [N, 3] on the reference plane
        _, v, depth = project_points(road_to_camera(road, attitude, base_height), camera)
        return v, depth

    v, depth = image_row(x)
    rows_per_m = (image_row(x - _DX)[0] - image_row(x + _DX)[0]) / (2 * _DX)  # rows grow towards the camera
    focal_baseline = camera.fx * camera.baseline
    in_view = (depth > 0) & (v >= -0.5) & (v <= camera.height - 0.5)
    return RoadSampling(x, depth, focal_baseline / depth, rows_per_m, 1.0 / rows_per_m, camera.fx / depth,
                        height_sigma(depth, base_height, camera, disparity_sigma_px), in_view)


def farthest_road_in_view(camera: StereoCamera, pitch_rad: float, base_height: float) -> float:
    """The farthest distance (m) at which a level road is inside the image: where the top row's
    upper edge meets it (inf when that edge looks at or above the horizon)."""
    depression = pitch_rad - math.atan2(camera.cy + 0.5, camera.fy)
    return base_height / math.tan(depression) if depression > 0 else math.inf


def far_cell_size(camera: StereoCamera, pitch_rad: float, base_height: float, x_min: float, x_max: float,
                  y_span: float, *, step: float = 0.01) -> float:
    """The far grid's cell: the length of road one image row covers at the window's middle,
    rounded up to the smallest multiple of ``step`` that cuts both the window's length
    (``x_max - x_min``) and its width (``y_span``) into whole cells.

    Nearer than the middle a cell holds more than one row, farther less: finer cells would be
    empty rows of the image over most of the window, coarser ones would average away what the
    nearer half resolves.

    Raises:
        ValueError: no such cell up to 1 m.
    """
    middle = road_sampling(camera, pitch_rad, base_height, 0.5 * (x_min + x_max))
    need = float(middle.row_length_m[0])
    for k in range(max(1, math.ceil(need / step - 1e-9)), int(round(1.0 / step)) + 1):
        size = k * step
        if all(abs(span / size - round(span / size)) < 1e-6 for span in (x_max - x_min, y_span)):
            return round(size, 10)
    raise ValueError(f"no cell of at most 1 m in steps of {step} m cuts {x_max - x_min:g} m by {y_span:g} m "
                     "into whole cells")
