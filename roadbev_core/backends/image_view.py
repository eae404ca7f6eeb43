"""``sgbm`` and ``bm``: the image-view baselines (the paper's comparison protocol).

What a user would build with ``stereo_image_proc`` today: OpenCV StereoSGBM / StereoBM on the
rectified grey pair, sub-pixel disparities -> 3-D points in the left optical frame -> road frame
-> :func:`roadbev_core.labels.elevation_map` (the very label code of the ground truth) ->
elevation map. Per-cell uncertainty is the 1-sigma of one of the cell's points: their spread
about the cell's mean combined with the disparity precision. Cells without points are NaN.

Speed: only the image window that can see the grid is matched (rows and columns from the
projection of the grid's volume, plus the matcher's margins), and the disparity search covers
exactly the disparities that volume can produce at the frame's attitude. Of the matched window
only the pixels whose rays can meet the grid's volume are turned into points
(:func:`grid_bands`: the volume's image is a convex polygon, narrower than the window where the
grid is far); the others could only land outside the grid.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import asdict, dataclass, fields
from typing import Any, NamedTuple, cast

import cv2
import numpy as np

from roadbev_core.backends.common import StageClock, grey_u8
from roadbev_core.config import ConfigError, GridSpec, StereoCamera
from roadbev_core.frame import Estimate, Frame, FrameError
from roadbev_core.geometry import Attitude, optical_from_road_rotation, project_points, ray_terms, road_to_camera
from roadbev_core.labels import cell_index, cell_means

__all__ = ["ImageViewParams", "ImageViewStereo", "MatchWindow", "PlaneParallaxPair", "cell_elevations", "create_bm",
           "create_sgbm", "disparity_height_sigma", "disparity_road_points", "grid_bands", "match_window",
           "parallax_disparity", "plane_disparity", "plane_parallax_pair", "refine_disparity", "road_points",
           "warped_bands"]

# grid_bands: row bands of the matched window, and the rounding margin (px) of the grid's image
_GRID_BANDS = 8
_GRID_BAND_MARGIN_PX = 2

_SGBM_MODES = {
    "sgbm": cv2.STEREO_SGBM_MODE_SGBM,
    "3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    "hh": cv2.STEREO_SGBM_MODE_HH,
    "hh4": cv2.STEREO_SGBM_MODE_HH4,
}


@dataclass(frozen=True)
class ImageViewParams:
    """Matcher settings (defaults chosen on the synthetic rig's tuning frames; each matcher's own
    are ``BM_DEFAULTS`` / ``SGBM_DEFAULTS``).

    Attributes:
        block_size: matching window side (odd; StereoBM needs >= 5).
        uniqueness_ratio: percent margin by which the best cost must beat the second best.
        speckle_window: largest blob of disparities (pixels) removed as speckle (0 = off).
        speckle_range: disparity variation (pixels) inside one connected blob.
        texture_threshold: StereoBM only: minimum texture of a window (sum of |x-derivative|).
        pre_filter_cap: clip of the pre-filtered image (both matchers).
        p1, p2: StereoSGBM smoothness penalties per channel x block area (P1 = p1*block^2...).
        disp12_max_diff: left-right consistency tolerance (pixels; -1 = off).
        mode: StereoSGBM mode: ``sgbm`` (5 paths), ``3way``, ``hh`` or ``hh4``.
        disparity_margin_px: extra disparities searched on either side of the grid's range.
        min_points: cells with fewer points are NaN.
        disparity_sigma_px: 1-sigma disparity precision used for the uncertainty floor.
        refine_width, refine_height: window (pixels, odd) of one Lucas-Kanade step that
            re-estimates each disparity's sub-pixel part (:func:`refine_disparity`); 0 = the
            matcher's own sub-pixel fit.
        plane_parallax_px: match the disparity relative to the reference plane's, searching this
            many pixels either side of it (a positive multiple of 8; :func:`plane_parallax_pair`);
            0 = match the disparity itself over the grid volume's range.
    """

    block_size: int = 5
    uniqueness_ratio: int = 10
    speckle_window: int = 100
    speckle_range: int = 2
    texture_threshold: int = 10
    pre_filter_cap: int = 31
    p1: int = 8
    p2: int = 32
    disp12_max_diff: int = 1
    mode: str = "sgbm"
    disparity_margin_px: int = 4
    min_points: int = 1
    disparity_sigma_px: float = 0.25
    refine_width: int = 0
    refine_height: int = 3
    plane_parallax_px: int = 0

    def __post_init__(self) -> None:
        for name in ("block_size", "speckle_window", "speckle_range", "pre_filter_cap", "min_points", "refine_width",
                     "refine_height", "plane_parallax_px"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 0:
                raise ConfigError(f"{name} must be a non-negative integer, got {value!r}")
        if self.block_size < 1 or self.block_size % 2 == 0:
            raise ConfigError(f"block_size must be odd and positive, got {self.block_size}")
        if not 1 <= self.pre_filter_cap <= 63:
            raise ConfigError(f"pre_filter_cap must be in 1..63, got {self.pre_filter_cap}")
        if self.mode not in _SGBM_MODES:
            raise ConfigError(f"unknown SGBM mode {self.mode!r}; choose from {', '.join(_SGBM_MODES)}")
        if not (math.isfinite(self.disparity_sigma_px) and self.disparity_sigma_px > 0):
            raise ConfigError(f"disparity_sigma_px must be positive, got {self.disparity_sigma_px}")
        if self.min_points < 1:
            raise ConfigError(f"min_points must be >= 1, got {self.min_points}")
        if self.plane_parallax_px % 8:
            raise ConfigError(f"plane_parallax_px must be a multiple of 8 (the matchers search multiples of 16 "
                              f"disparities), got {self.plane_parallax_px}")
        if self.refine_width and (self.refine_width % 2 == 0 or self.refine_height % 2 == 0):
            raise ConfigError(f"the refinement window must have odd sides, got {self.refine_width} x "
                              f"{self.refine_height}")

    @classmethod
    def from_options(cls, options: dict[str, Any], defaults: dict[str, Any]) -> ImageViewParams:
        """Parameters from keyword options over per-matcher defaults; unknown names raise."""
        known = {f.name for f in fields(cls)}
        unknown = set(options) - known
        if unknown:
            raise ConfigError(f"unknown option(s) {', '.join(sorted(unknown))}; known: {', '.join(sorted(known))}")
        return cls(**{**defaults, **options})


# Side (pixels) of the window over which each image is brought to zero mean and unit spread before
# the refinement: the two cameras' gains and offsets differ, the gradient step must not see it.
_NORMALISE_PX = 15
# A step longer than this is not a sub-pixel correction but another match; the matcher's stands.
_MAX_STEP_PX = 1.0


def _normalised(image: np.ndarray) -> np.ndarray:
    """[h, w] float32: ``image`` less its local mean, over its local spread (``_NORMALISE_PX``)."""
    grey = image.astype(np.float32)
    k = (_NORMALISE_PX, _NORMALISE_PX)
    mean = cv2.blur(grey, k)
    spread = np.sqrt(np.maximum(cv2.blur(grey * grey, k) - mean * mean, 1.0))
    return cast("np.ndarray", (grey - mean) / spread)


def refine_disparity(left: np.ndarray, right: np.ndarray, disparity: np.ndarray, valid: np.ndarray,
                     window: tuple[int, int]) -> np.ndarray:
    """Each valid disparity's sub-pixel part re-estimated by one Lucas-Kanade step.

    Block matchers fit a parabola to three matching costs, which pulls disparities towards whole
    pixels (pixel locking); on a road, whose disparity changes steadily down the image, that is
    a ripple in the heights. One Gauss-Newton step on the locally normalised images,
    ``d -= sum(r gx) / sum(gx^2)`` over ``window`` (width, height) with ``r`` the left image less the
    right one warped by ``d`` and ``gx`` the warped image's horizontal gradient, re-estimates it.
    A window wider than tall: the road's disparity changes down the image, not along a row.

    Args:
        left, right: [h, w] uint8 rectified crops.
        disparity: [h, w] float32 the matcher's disparities (pixels).
        valid: [h, w] bool, the disparities to refine.
        window: (width, height) of the sums, odd.

    Returns:
        [h, w] float32: refined where valid and the step is under ``_MAX_STEP_PX``, else ``disparity``.
    """
    h, w = disparity.shape
    start = np.where(valid, disparity, np.float32(0.0))
    map_x = np.arange(w, dtype=np.float32)[None, :] - start  # [h, w] where each left pixel lies in the right image
    map_y = np.broadcast_to(np.arange(h, dtype=np.float32)[:, None], (h, w))
    warped = cv2.remap(_normalised(right), map_x, np.ascontiguousarray(map_y), cv2.INTER_LINEAR)  # [h, w]
    gx = cv2.Sobel(warped, cv2.CV_32F, 1, 0, ksize=1) * np.float32(0.5)  # central difference
    residual = _normalised(left) - warped
    # left(u) = right(u - d - delta) ~ warped(u) - delta gx(u): delta = -sum(r gx) / sum(gx^2)
    num = cv2.boxFilter(residual * gx, -1, window, normalize=False)
    den = cv2.boxFilter(gx * gx, -1, window, normalize=False)
    with np.errstate(divide="ignore", invalid="ignore"):
        step = -num / den
    usable = valid & (den > 1e-3) & (np.abs(step) < _MAX_STEP_PX)
    return np.where(usable, disparity + step, disparity).astype(np.float32)


class MatchWindow(NamedTuple):
    """The part of the image pair to match and the disparities to search.

    Attributes:
        top, bottom: image rows [top, bottom) that see the grid (with the block margin).
        left, right: image columns [left, right) of the crop; it starts early enough that the
            matcher has the full disparity range for every column that sees the grid.
        min_disparity, num_disparities: search range (num a positive multiple of 16).
    """

    top: int
    bottom: int
    left: int
    right: int
    min_disparity: int
    num_disparities: int

    def crop(self, rows: slice, cols: slice) -> MatchWindow:
        """The part of this window at crop-relative ``rows`` and ``cols`` (bounded slices, step 1),
        with this window's disparity search."""
        return self._replace(top=self.top + rows.start, bottom=self.top + rows.stop,
                             left=self.left + cols.start, right=self.left + cols.stop)

    def valid(self, disparity: np.ndarray) -> np.ndarray:
        """[h, w] bool: the matcher's disparities [h, w] of this window that are matches."""
        # cv2 marks invalid pixels with (min_disparity - 1); zero disparity is at infinity. A search
        # below zero is one relative to a reference (plane_parallax_pair): its matches may be negative.
        low = self.min_disparity - 0.5 if self.min_disparity < 0 else max(self.min_disparity - 0.5, 0.5)
        return cast("np.ndarray", disparity > low)


def _volume_corners(grid: GridSpec, camera: StereoCamera, attitude: Attitude
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Image columns, rows and optical depths (each [8]) of the eight corners of the grid's volume.

    Raises:
        FrameError: a corner behind (or nearly at) the camera.
    """
    xs, ys, zs = (grid.x_min, grid.x_max), (grid.y_min, grid.y_max), (grid.z_min, grid.z_max)
    corners = np.array([[x, y, z] for x in xs for y in ys for z in zs])  # [8, 3]
    cam = road_to_camera(corners, attitude, grid.base_height)
    if np.any(cam[:, 2] <= 0.05):
        raise FrameError("the grid reaches behind the camera at this attitude")
    return project_points(cam, camera)


def match_window(
    grid: GridSpec, camera: StereoCamera, attitude: Attitude, *, margin_px: int, block_size: int
) -> MatchWindow:
    """Image window and disparity range covering the grid's volume at ``attitude``.

    The grid volume is a box in the road frame; its image and its depths are bounded by its eight
    corners (all ahead of the camera), so the extremes are exact for a pinhole camera.
    """
    u, v, depth = _volume_corners(grid, camera, attitude)
    disparity = camera.fx * camera.baseline / depth
    d_min = max(0, int(math.floor(disparity.min())) - margin_px)
    d_max = int(math.ceil(disparity.max())) + margin_px
    num = max(16, int(math.ceil((d_max - d_min) / 16.0)) * 16)
    half = block_size // 2 + 1
    top = int(np.clip(math.floor(v.min()) - half, 0, camera.height - 1))
    bottom = int(np.clip(math.ceil(v.max()) + half + 1, top + 1, camera.height))
    # Matchers leave the first min_disparity + num_disparities columns without a result.
    right = int(np.clip(math.ceil(u.max()) + half + 1, 1, camera.width))
    left = int(np.clip(math.floor(u.min()) - half - d_min - num, 0, right - 1))
    if bottom - top < block_size or right - left <= d_min + num:
        raise FrameError("the grid does not fall inside the image at this attitude")
    return MatchWindow(top, bottom, left, right, d_min, num)


def grid_bands(window: MatchWindow, grid: GridSpec, camera: StereoCamera, attitude: Attitude, *,
               bands: int = _GRID_BANDS, margin_px: int = _GRID_BAND_MARGIN_PX) -> list[tuple[slice, slice]]:
    """Crop-relative (rows, cols) rectangles of ``window``, top to bottom, that hold every pixel of
    its crop whose ray can meet the grid's volume.

    A point of the volume (a box in the road frame, every corner ahead of the camera: see
    :func:`match_window`) projects inside the convex hull of the box's eight projected corners, so
    a pixel outside that polygon (by more than ``margin_px``, for rounding) only ever yields a
    point outside the grid, which the binning leaves out. The crop's rows are cut into ``bands``
    equal bands and each keeps the polygon's column extent over its rows; a band the polygon
    misses is left out. Points of the rectangles in this order are the crop's in row-major order,
    less the ones that cannot be in the grid, so per-cell sums come out the same.
    """
    h, w = window.bottom - window.top, window.right - window.left
    u, v, _ = _volume_corners(grid, camera, attitude)
    polygon = cv2.convexHull(np.stack([u - window.left, v - window.top], axis=1).astype(np.float32))  # [K, 1, 2]
    inside = np.zeros((h, w), np.uint8)  # [h, w] 1 inside the polygon
    cv2.fillConvexPoly(inside, np.round(polygon).astype(np.int32), 1)
    out: list[tuple[slice, slice]] = []
    edges = np.linspace(0, h, bands + 1).round().astype(int)
    for top, bottom in itertools.pairwise(edges):
        # the polygon's columns over the band's rows, both widened by the margin
        seen = np.flatnonzero(inside[max(top - margin_px, 0):bottom + margin_px].any(axis=0))  # [n]
        if bottom > top and seen.size:
            cols = slice(max(int(seen[0]) - margin_px, 0), min(int(seen[-1]) + 1 + margin_px, w))
            out.append((slice(int(top), int(bottom)), cols))
    return out


def plane_disparity(camera: StereoCamera, attitude: Attitude, base_height: float, rows: np.ndarray,
                    cols: np.ndarray) -> np.ndarray:
    """[h, w] float32: the disparity of the reference plane (the road frame's z = 0, ``base_height``
    below the camera) at the pixels ``rows`` [h] x ``cols`` [w]; 0 where the ray does not descend.

    A ray's road-frame direction per unit of optical depth has the height component ``r_z``; it
    meets the plane at depth ``-base_height / r_z``, so the disparity is ``-fx * B * r_z / base_height``:
    a column's term plus a row's (:func:`roadbev_core.geometry.ray_terms`)."""
    terms = ray_terms(camera, attitude, rows, cols)
    scale = -camera.fx * camera.baseline / base_height
    by_col = (scale * terms.per_col[:, 2]).astype(np.float32)  # [w]
    by_row = (scale * terms.per_row[:, 2]).astype(np.float32)  # [h]
    plane = by_col[None, :] + by_row[:, None]  # [h, w]: scale * r_z, positive where the ray descends
    return np.asarray(np.maximum(plane, np.float32(0.0)), np.float32)


class PlaneParallaxPair(NamedTuple):
    """A window's images warped so that the reference plane has no disparity (:func:`plane_parallax_pair`).

    Attributes:
        left, right: [h, w] uint8, the warped left and right images of the window's crop.
        plane: [h, w] float32, the reference plane's disparity at each warped pixel.
        slope: d(plane)/du, the plane's disparity change per column (px per px; a roll's).
    """

    left: np.ndarray
    right: np.ndarray
    plane: np.ndarray
    slope: float


def plane_parallax_pair(left: np.ndarray, right: np.ndarray, window: MatchWindow, camera: StereoCamera,
                        attitude: Attitude, base_height: float) -> PlaneParallaxPair:
    """The window's crop of a rectified pair (``left``, ``right``: [H, W] uint8, whole images)
    warped along its rows so that the reference plane has zero disparity (plane + parallax:
    Irani and Anandan, "Parallax geometry of pairs of points for 3D scene analysis", ECCV 1996).

    The road's disparity grows down the image by about ``B / h`` pixels per row, so a matching
    window on the road sees a slanted surface: its disparity differs across the window's rows, and
    a matcher that assumes one disparity per window is biased by however the texture weighs those
    rows. Shifting each pixel of the left image by half the plane's disparity ``p`` and each of the
    right by minus half (``L'(u) = L(u + p/2)``, ``R'(u) = R(u - p/2)``) leaves only the parallax of
    the road's relief to match, near zero everywhere; both images are resampled by the same
    fractional amounts (mirrored), so neither is smoothed more than the other.
    """
    rows = np.arange(window.top, window.bottom)
    cols = np.arange(window.left, window.right)
    plane = plane_disparity(camera, attitude, base_height, rows, cols)  # [h, w]
    u = cols.astype(np.float32)[None, :]  # [1, w]
    v = np.repeat(rows.astype(np.float32)[:, None], cols.size, axis=1)  # [h, w]
    half = np.float32(0.5) * plane
    warped_left = cv2.remap(left, u + half, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    warped_right = cv2.remap(right, u - half, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    R = optical_from_road_rotation(attitude)
    slope = float(-camera.baseline * R[0][2] / base_height)
    return PlaneParallaxPair(warped_left, warped_right, plane, slope)


def warped_bands(bands: list[tuple[slice, slice]], pair: PlaneParallaxPair) -> list[tuple[slice, slice]]:
    """:func:`grid_bands`' rectangles of a window's crop as rectangles of its warped pair: a warped
    pixel at column ``u`` is the left image's at ``u + p / 2`` (``p``, the plane's disparity, is
    never negative), so each band's first column moves left by the most half of ``p`` over its rows
    (its last stays). Points of these rectangles in order are the warped crop's in row-major order,
    less ones that cannot be in the grid, as :func:`grid_bands`' are the crop's."""
    out = []
    for rows, cols in bands:
        reach = math.ceil(0.5 * float(pair.plane[rows].max(initial=0.0)))
        out.append((rows, slice(max(cols.start - reach, 0), cols.stop)))
    return out


def parallax_disparity(residual: np.ndarray, pair: PlaneParallaxPair, cols: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """The disparities [h, w] and left-image columns [h, w] of a warped pair's matches.

    A match ``r`` at warped pixel ``u`` pairs the left image at ``u + p(u) / 2`` with the right at
    ``u - r - p(u - r) / 2``: the disparity is ``r + (p(u) + p(u - r)) / 2`` with
    ``p(u - r) = p(u) - slope * r``.

    Args:
        residual: [h, w] float32, the matcher's disparities of the warped pair.
        pair: the warped pair.
        cols: [w] the warped crop's columns.
    """
    disparity = residual + pair.plane - np.float32(0.5 * pair.slope) * residual
    left_cols = cols.astype(np.float32)[None, :] + np.float32(0.5) * pair.plane
    return disparity.astype(np.float32), left_cols.astype(np.float32)


def road_points(depth: np.ndarray, rows: np.ndarray, cols: np.ndarray, camera: StereoCamera, attitude: Attitude,
                base_height: float) -> np.ndarray:
    """Road-frame points [h * w, 3] (row-major) of the pixels at ``rows`` [h] x ``cols`` [w] (or
    each row's own columns, [h, w]) of the left image with optical depths ``depth`` [h, w] (NaN: no
    point, a NaN row).

    A pixel (u, v) with depth Z is at Z * ray(u, v) in the optical frame; in the road frame
    the ray's components are sums of a per-column and a per-row term. Pixels without a depth are
    kept as NaN (the binning leaves them out) rather than compressed out: picking the valid ones
    costs more than the arithmetic on them.
    """
    columns = np.asarray(cols)
    points = np.empty((depth.size, 3), dtype=np.float32)
    if columns.ndim == 2:  # [h, w]: a column's term is affine in the column, from the terms at 0 and 1
        ends = ray_terms(camera, attitude, rows, np.array([0.0, 1.0]))
        base, step = ends.per_col[0].astype(np.float32), (ends.per_col[1] - ends.per_col[0]).astype(np.float32)
        per_row = ends.per_row.astype(np.float32)  # [h, 3]
        for k in range(3):
            points[:, k] = (depth * (base[k] + step[k] * columns + per_row[:, None, k])).ravel()
    else:
        terms = ray_terms(camera, attitude, rows, columns)
        per_col, per_row = terms.per_col.astype(np.float32), terms.per_row.astype(np.float32)  # [w, 3], [h, 3]
        for k in range(3):
            points[:, k] = (depth * (per_col[None, :, k] + per_row[:, None, k])).ravel()
    points[:, 2] += base_height
    return points


def disparity_road_points(disparity: np.ndarray, valid: np.ndarray, window: MatchWindow, camera: StereoCamera,
                          attitude: Attitude, base_height: float, cols: np.ndarray | None = None
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Road-frame points [h * w, 3] of the disparities [h, w] of a window's crop (row-major), and
    their depths [h * w]; NaN for a pixel whose disparity is not ``valid`` [h, w]. ``cols`` [h, w]:
    each disparity's left-image column where it is not the crop's own (a warped pair's)."""
    depth = (camera.fx * camera.baseline) / np.where(valid, disparity, np.float32(np.nan))  # [h, w] float32
    columns = np.arange(window.left, window.right) if cols is None else cols
    points = road_points(depth, np.arange(window.top, window.bottom), columns, camera, attitude, base_height)
    return points, depth.ravel()


def disparity_height_sigma(points: np.ndarray, depth: np.ndarray, disparity_sigma_px: float | np.ndarray,
                           camera: StereoCamera, base_height: float) -> np.ndarray:
    """[N] the height 1-sigma of points [N, 3] at depths [N] from a disparity 1-sigma (pixels, one
    value or [N]): a depth error moves a point along its ray, whose vertical share is (camera
    height above the point) / depth."""
    return depth * (disparity_sigma_px / (camera.fx * camera.baseline)) * (base_height - points[:, 2])


def cell_elevations(points: np.ndarray, point_sigma: np.ndarray, grid: GridSpec, min_points: int,
                    clock: StageClock | None = None) -> tuple[np.ndarray, np.ndarray]:
    """An image-view estimate's points binned into the grid as the labels are (the paper's
    protocol): per cell the mean height of its points, and as its 1-sigma one point's (their
    spread about the mean with each point's own height 1-sigma, ``point_sigma`` [N]).

    Args:
        points: [N, 3] road frame (NaN rows are left out).
        min_points: cells with fewer points are NaN.
        clock: laps ``projection`` and ``post`` on it when given.

    Returns:
        elevation and uncertainty [n_rows, n_cols] float32, NaN where no estimate.
    """
    # Points outside the height range are mismatches; the label code leaves them out.
    flat = cell_index(points, grid, clip_z=True)  # [N]
    if clock is not None:
        clock.lap("projection")
    z = points[:, 2]
    # Second moment per cell: E[z^2 + sigma^2] - E[z]^2 = spread + precision.
    count, (mean, second) = cell_means(flat, grid, z, np.square(z) + np.square(point_sigma))
    enough = count >= min_points
    elevation = np.where(enough, mean, np.nan).astype(np.float32)
    variance = np.maximum(second - np.square(mean), 0.0)
    uncertainty = np.where(enough, np.sqrt(variance), np.nan).astype(np.float32)
    if clock is not None:
        clock.lap("post")
    return elevation, uncertainty


class ImageViewStereo:
    """OpenCV block matching (``bm``) or semi-global matching (``sgbm``) + binning into the grid.

    Any grid ahead of the camera works the same way, so the far-field grid too
    (:attr:`far_field`): its own window of the image and its own (smaller) disparities.
    """

    needs_stereo = True
    # answers a far-field grid (roadbev_core.pipeline.build_far_backend)
    far_field = True

    def __init__(self, name: str, grid: GridSpec, params: ImageViewParams) -> None:
        if name not in ("bm", "sgbm"):
            raise ConfigError(f"image-view matcher must be 'bm' or 'sgbm', got {name!r}")
        if name == "bm" and params.block_size < 5:
            raise ConfigError(f"StereoBM needs block_size >= 5, got {params.block_size}")
        self.name = name
        self.grid = grid
        self.params = params
        self._matchers: dict[tuple[int, int], cv2.StereoMatcher] = {}  # (min, num disparities) -> matcher

    def _matcher(self, min_disparity: int, num_disparities: int) -> cv2.StereoMatcher:
        """A matcher for the disparity range (cached: ranges repeat from frame to frame)."""
        key = (min_disparity, num_disparities)
        if key not in self._matchers:
            p = self.params
            m: cv2.StereoBM | cv2.StereoSGBM
            if self.name == "bm":
                m = cv2.StereoBM.create(numDisparities=num_disparities, blockSize=p.block_size)
                m.setMinDisparity(min_disparity)
                m.setTextureThreshold(p.texture_threshold)
                m.setPreFilterCap(p.pre_filter_cap)
            else:
                area = p.block_size * p.block_size
                m = cv2.StereoSGBM.create(
                    minDisparity=min_disparity,
                    numDisparities=num_disparities,
                    blockSize=p.block_size,
                    P1=p.p1 * area,
                    P2=p.p2 * area,
                    preFilterCap=p.pre_filter_cap,
                    mode=_SGBM_MODES[p.mode],
                )
            m.setUniquenessRatio(p.uniqueness_ratio)
            m.setSpeckleWindowSize(p.speckle_window)
            m.setSpeckleRange(p.speckle_range)
            m.setDisp12MaxDiff(p.disp12_max_diff)
            self._matchers[key] = m
        return self._matchers[key]

    def estimate(self, frame: Frame) -> Estimate:
        """Elevation and uncertainty of ``self.grid`` for one stereo frame."""
        if frame.right is None:
            raise FrameError(f"{self.name} needs a stereo frame (the right image is missing)")
        camera, grid, p = frame.camera, self.grid, self.params
        if camera.baseline <= 0:
            raise FrameError(f"{self.name} needs a stereo rig with a positive baseline")
        clock = StageClock()
        window = match_window(
            grid, camera, frame.attitude, margin_px=p.disparity_margin_px, block_size=p.block_size
        )
        pair: PlaneParallaxPair | None = None
        if p.plane_parallax_px:
            pair = plane_parallax_pair(grey_u8(frame.left), grey_u8(frame.right), window, camera, frame.attitude,
                                       grid.base_height)
            left, right = pair.left, pair.right
            search = window._replace(min_disparity=-p.plane_parallax_px, num_disparities=2 * p.plane_parallax_px)
        else:
            crop = (slice(window.top, window.bottom), slice(window.left, window.right))
            left = np.ascontiguousarray(grey_u8(frame.left)[crop])
            right = np.ascontiguousarray(grey_u8(frame.right)[crop])
            search = window
        clock.lap("preprocess")
        raw = self._matcher(search.min_disparity, search.num_disparities).compute(left, right)
        disparity = raw.astype(np.float32) * (1.0 / 16.0)  # fixed point, 4 fractional bits
        clock.lap("matching")
        if p.refine_width:
            disparity = refine_disparity(left, right, disparity, search.valid(disparity),
                                         (p.refine_width, p.refine_height))
            clock.lap("refinement")
        valid = search.valid(disparity)  # of the refined disparities, when refined
        cols = None
        if pair is not None:
            disparity, cols = parallax_disparity(disparity, pair, np.arange(window.left, window.right))
            valid &= disparity > 0.5  # ahead of the camera
        bands = grid_bands(window, grid, camera, frame.attitude)  # only the pixels that can see the grid
        if pair is not None:
            bands = warped_bands(bands, pair)
        parts = [self._points(disparity[rows, band], valid[rows, band], window.crop(rows, band), frame,
                              None if cols is None else cols[rows, band])
                 for rows, band in bands]
        points = np.concatenate([part[0] for part in parts]) if parts else np.empty((0, 3), np.float32)
        sigma = np.concatenate([part[1] for part in parts]) if parts else np.empty(0, np.float32)
        elevation, uncertainty = cell_elevations(points, sigma, grid, p.min_points, clock)
        return Estimate(elevation=elevation, uncertainty=uncertainty, timings_ms=clock.timings)

    def _points(self, disparity: np.ndarray, valid: np.ndarray, window: MatchWindow, frame: Frame,
                cols: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Road-frame points [h * w, 3] of a window's disparities [h, w] (NaN where not ``valid``)
        and their height 1-sigma [h * w]."""
        points, depth = disparity_road_points(disparity, valid, window, frame.camera, frame.attitude,
                                              self.grid.base_height, cols)
        return points, disparity_height_sigma(points, depth, self.params.disparity_sigma_px, frame.camera,
                                              self.grid.base_height)

    def describe(self) -> dict[str, Any]:
        """Parameters as a JSON-able dict (for benchmark records)."""
        return {"backend": self.name, **asdict(self.params)}


# Defaults per matcher, chosen on tuning frames (seeds 200,000+) of the clean appearance, before
# scene version 2; benchmarks/tune_bev_sweep.py compares them with other settings
# (docs/results/tuning.md). bm: block 11 with a stricter uniqueness was at least as accurate as
# block 9, at more coverage; block 15 covered more but was less accurate. sgbm: the 3-way mode
# with block 7 and a stricter uniqueness was far more accurate than the 5-path mode with block 5,
# at less coverage.
BM_DEFAULTS: dict[str, Any] = {"block_size": 11, "texture_threshold": 10, "uniqueness_ratio": 15}
SGBM_DEFAULTS: dict[str, Any] = {"block_size": 7, "mode": "3way", "uniqueness_ratio": 15}


def create_bm(grid: GridSpec, **options: Any) -> ImageViewStereo:
    """Backend factory for OpenCV StereoBM (options: see :class:`ImageViewParams`)."""
    return ImageViewStereo("bm", grid, ImageViewParams.from_options(options, BM_DEFAULTS))


def create_sgbm(grid: GridSpec, **options: Any) -> ImageViewStereo:
    """Backend factory for OpenCV StereoSGBM (options: see :class:`ImageViewParams`)."""
    return ImageViewStereo("sgbm", grid, ImageViewParams.from_options(options, SGBM_DEFAULTS))
