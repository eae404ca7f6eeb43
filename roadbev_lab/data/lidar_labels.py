"""Ground-truth labels from LiDAR scans: road-surface points, accumulation, the paper's cell mean.

The pipeline for one camera frame (all arrays float64 unless said otherwise):

1. Each scan is taken into the road frame at its own stamp: LiDAR -> left optical frame through
   the extrinsic, then :func:`roadbev_core.geometry.camera_to_road` with the attitude at that
   stamp and ``base_height`` (the road frame: gravity-aligned, ``base_height`` below the camera).
2. With odometry, scans within ``window_s`` of the frame are moved into the frame's road frame by
   the planar motion of the road frame between the two stamps (:func:`planar_transform`). The
   odometry is planar (docs/interface/topics.md: heave, pitch and roll of the body are never given), so every
   moved scan is then aligned vertically to the frame's own scan: the median height difference
   over the cells both hold is taken out (:func:`vertical_offset`).
3. :func:`road_points` keeps the points of the road surface only (the *road-surface test*):

   a. **Road plane**: a robust least-squares plane ``z = a + b x + c y`` over the grid and a
      margin around it, re-fitted three times on the points within ``max(3 * 1.4826 * MAD,
      plane_tolerance_m)`` of the previous fit (starting from the points within
      ``plane_search_m`` of the reference plane). It absorbs a few centimetres of
      ``base_height`` error or a slight tilt; it is used only to *select* points, the labels stay
      in the road frame.
   b. **Height band**: a point is a candidate when its height above the fitted plane lies in
      the grid's vertical range ``[z_min, z_max]``.
   c. **Obstacle columns**: the region is cut into square tiles of ``tile_m``; a tile holding at
      least ``obstacle_min_points`` points from ``obstacle_height_m`` to ``obstacle_top_m`` above
      the plane carries an obstacle (a car, a person, a pole, a wall, a bush): its points and
      those of the tiles within ``obstacle_margin_m`` are rejected (the road seen under a car's
      sill or next to its tyres is not trusted either). Overhangs higher than ``obstacle_top_m``
      (tree crowns, bridges) do not count.
   d. **Tile roughness**: a tile whose candidate heights spread by more than
      ``max_tile_spread_m`` between their 10th and 90th percentiles is not a road surface
      (kerb edges, grass and litter on kerb tops, gravel verges, clutter); its points are
      rejected. A smooth kerb top within the band is kept: it *is* a surface the wheels could
      touch.

4. :func:`roadbev_core.labels.elevation_map` (the project's one label code, the paper's per-cell
   mean and mask) turns the kept points into the label.

Everything is vectorised (``np.bincount`` and one sort per test); no per-point Python loop.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from typing import Any, NamedTuple

import cv2
import numpy as np

from roadbev_core.config import GridSpec
from roadbev_core.errors import RoadbevError
from roadbev_core.geometry import Attitude, camera_to_road
from roadbev_core.labels import ElevationLabel, elevation_map

__all__ = [
    "LabelConfig",
    "LabelError",
    "RoadPlane",
    "RoadSelection",
    "accumulate_label",
    "fit_road_plane",
    "planar_transform",
    "road_points",
    "scan_to_road",
    "vertical_offset",
]


class LabelError(RoadbevError, ValueError):
    """Inputs from which no trustworthy label can be made (no points, no road plane, bad config)."""


@dataclass(frozen=True)
class LabelConfig:
    """Settings of the LiDAR labeller (parameters ``label.<name>``).

    Attributes:
        window_s: scans within this many seconds of a frame (either side) are accumulated
            (needs odometry when > 0); 0 = the nearest scan alone.
        max_scan_gap_s: the nearest scan must lie this close to the frame.
        max_range_m: LiDAR returns farther than this from the sensor are ignored.
        region_margin_m: the plane fit and the tests cover the grid plus this margin.
        plane_search_m: the first plane fit uses points this close to the reference plane.
        plane_tolerance_m: smallest inlier band of the plane re-fits.
        tile_m: tile size of the obstacle and roughness tests.
        obstacle_height_m, obstacle_top_m: the heights above the plane that make a tile an
            obstacle.
        obstacle_min_points: points it takes in that height span.
        obstacle_margin_m: tiles this close to an obstacle tile are rejected too.
        max_tile_spread_m: largest 10-90 percentile spread of a road tile's heights.
        min_shared_cells: cells a moved scan must share with the frame's own scan to be aligned
            vertically (fewer: the scan is left out).
    """

    window_s: float = 0.0
    max_scan_gap_s: float = 0.1
    max_range_m: float = 80.0
    region_margin_m: float = 1.0
    plane_search_m: float = 0.4
    plane_tolerance_m: float = 0.03
    tile_m: float = 0.2
    obstacle_height_m: float = 0.25
    obstacle_top_m: float = 2.5
    obstacle_min_points: int = 3
    obstacle_margin_m: float = 0.3
    max_tile_spread_m: float = 0.10
    min_shared_cells: int = 20

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise LabelError(f"label.{f.name} must be a finite number, got {value!r}")
            if value < 0:
                raise LabelError(f"label.{f.name} must be >= 0, got {value}")
        if self.tile_m <= 0 or self.max_range_m <= 0:
            raise LabelError("label.tile_m and label.max_range_m must be positive")
        if self.obstacle_top_m <= self.obstacle_height_m:
            raise LabelError("label.obstacle_top_m must exceed label.obstacle_height_m")

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> LabelConfig:
        """The config from parameters named ``label.<field>``; other names are ignored.

        Raises:
            LabelError: an unknown ``label.*`` name or a bad value.
        """
        known = {f.name: f for f in fields(cls)}
        values: dict[str, Any] = {}
        for name, value in params.items():
            if not name.startswith("label."):
                continue
            key = name[len("label.") :]
            if key not in known:
                raise LabelError(f"unknown parameter {name!r}; label parameters: {', '.join(sorted(known))}")
            values[key] = int(value) if known[key].type in (int, "int") and not isinstance(value, bool) else value
        return replace(cls(), **values)

    def to_dict(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


class RoadPlane(NamedTuple):
    """``z = offset + slope_x * x + slope_y * y`` in the road frame, with its inlier scatter."""

    offset: float
    slope_x: float
    slope_y: float
    sigma: float  # 1.4826 * MAD of the inliers' residuals (m)
    inliers: int

    def height(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        """Plane height at road-frame (x, y) (arrays of any shape, or scalars)."""
        return (
            self.offset
            + self.slope_x * np.asarray(x, dtype=np.float64)
            + self.slope_y * np.asarray(y, dtype=np.float64)
        )


class RoadSelection(NamedTuple):
    """Which points passed the road-surface test, and why the others did not.

    Attributes:
        keep: [N] bool.
        plane: the fitted road plane.
        rejected: reason -> number of points of the region rejected for it.
    """

    keep: np.ndarray
    plane: RoadPlane
    rejected: dict[str, int]


def scan_to_road(
    points_lidar: np.ndarray,
    rotation: np.ndarray,
    translation: np.ndarray,
    attitude: Attitude,
    base_height: float,
    *,
    max_range_m: float = math.inf,
) -> np.ndarray:
    """LiDAR points [N, >=3] -> road-frame points [M, 3] (non-finite and far returns dropped).

    Args:
        points_lidar: x, y, z in the LiDAR frame (extra columns ignored).
        rotation, translation: the extrinsic, ``p_cam = rotation @ p_lidar + translation``
            (the left optical frame).
        attitude: the camera's attitude at the scan's stamp.
        base_height: the road frame's origin below the camera (m).
        max_range_m: returns farther from the LiDAR are dropped.
    """
    p = np.asarray(points_lidar, dtype=np.float64)[:, :3]  # [N, 3]
    ok = np.isfinite(p).all(axis=1)
    if math.isfinite(max_range_m):
        ok &= np.einsum("ij,ij->i", p, p) <= max_range_m**2
    p = p[ok]
    cam = p @ np.asarray(rotation, np.float64).T + np.asarray(translation, np.float64)  # [M, 3]
    return camera_to_road(cam, attitude, base_height)


def planar_transform(from_pose: Sequence[float], to_pose: Sequence[float], points: np.ndarray) -> np.ndarray:
    """Points [N, 3] in a road frame with planar pose ``from_pose`` -> the one at ``to_pose``.

    Poses are ``(x, y, yaw)`` of the road frame in a common planar frame (``odom``); z is kept.
    """
    x0, y0, a0 = (float(v) for v in from_pose)
    x1, y1, a1 = (float(v) for v in to_pose)
    p = np.asarray(points, dtype=np.float64)
    c0, s0 = math.cos(a0), math.sin(a0)
    wx = c0 * p[:, 0] - s0 * p[:, 1] + x0 - x1  # [N] in odom, relative to the target origin
    wy = s0 * p[:, 0] + c0 * p[:, 1] + y0 - y1
    c1, s1 = math.cos(a1), math.sin(a1)
    return np.stack([c1 * wx + s1 * wy, -s1 * wx + c1 * wy, p[:, 2]], axis=1)


def _in_region(points: np.ndarray, grid: GridSpec, margin: float) -> np.ndarray:
    x, y = points[:, 0], points[:, 1]
    return (
        (x >= grid.x_min - margin) & (x < grid.x_max + margin) & (y >= grid.y_min - margin) & (y < grid.y_max + margin)
    )


def fit_road_plane(points_road: np.ndarray, config: LabelConfig) -> RoadPlane:
    """Robust plane through the road points of a region (see the module docstring, step 3a).

    Raises:
        LabelError: fewer than 10 points near the reference plane.
    """
    p = np.asarray(points_road, dtype=np.float64)
    use = np.abs(p[:, 2]) <= config.plane_search_m
    if use.sum() < 10:
        raise LabelError(
            f"no road plane: {int(use.sum())} point(s) within {config.plane_search_m} m of the reference "
            "plane over the grid (is base_height right? is the extrinsic right?)"
        )
    # Start from the median height (a horizontal plane), then re-fit on the inliers.
    coef = np.array([float(np.median(p[use, 2])), 0.0, 0.0])
    sigma = config.plane_search_m
    for _ in range(3):
        design = np.stack([np.ones(p.shape[0]), p[:, 0], p[:, 1]], axis=1)  # [N, 3]
        residual = p[:, 2] - design @ coef
        inside = np.abs(residual[use]) if use.any() else np.abs(residual)
        mad = float(np.median(inside)) if inside.size else sigma
        band = max(3.0 * 1.4826 * mad, config.plane_tolerance_m)
        use = np.abs(residual) <= band
        if use.sum() < 10:
            break
        coef, *_ = np.linalg.lstsq(design[use], p[use, 2], rcond=None)
        sigma = 1.4826 * mad
    return RoadPlane(float(coef[0]), float(coef[1]), float(coef[2]), float(sigma), int(use.sum()))


def _tile_index(points: np.ndarray, grid: GridSpec, config: LabelConfig) -> tuple[np.ndarray, tuple[int, int]]:
    m, t = config.region_margin_m, config.tile_m
    n_x = int(math.ceil((grid.x_max - grid.x_min + 2 * m) / t))
    n_y = int(math.ceil((grid.y_max - grid.y_min + 2 * m) / t))
    ix = np.clip(((points[:, 0] - (grid.x_min - m)) / t).astype(np.intp), 0, n_x - 1)
    iy = np.clip(((points[:, 1] - (grid.y_min - m)) / t).astype(np.intp), 0, n_y - 1)
    return ix * n_y + iy, (n_x, n_y)


def _tile_spread(tile: np.ndarray, values: np.ndarray, n_tiles: int) -> np.ndarray:
    """[n_tiles] 90th - 10th percentile of ``values`` per tile (0 where fewer than 3 values)."""
    spread = np.zeros(n_tiles)
    if values.size == 0:
        return spread
    order = np.lexsort((values, tile))  # by tile, then value
    t_sorted, v_sorted = tile[order], values[order]
    counts = np.bincount(t_sorted, minlength=n_tiles)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    has = counts >= 3
    lo = starts[has] + np.floor(0.1 * (counts[has] - 1)).astype(np.intp)
    hi = starts[has] + np.ceil(0.9 * (counts[has] - 1)).astype(np.intp)
    spread[has] = v_sorted[hi] - v_sorted[lo]
    return spread


def road_points(points_road: np.ndarray, grid: GridSpec, config: LabelConfig) -> RoadSelection:
    """The road-surface test (module docstring, step 3) on road-frame points [N, >=3].

    Raises:
        LabelError: no points over the grid, or no road plane among them.
    """
    p = np.asarray(points_road, dtype=np.float64)[:, :3]
    region = _in_region(p, grid, config.region_margin_m) & np.isfinite(p).all(axis=1)
    n_region = int(region.sum())
    if n_region == 0:
        raise LabelError("no LiDAR point falls on the grid or near it (empty scan, or wrong extrinsic?)")
    pr = p[region]
    plane = fit_road_plane(pr, config)
    residual = pr[:, 2] - plane.height(pr[:, 0], pr[:, 1])  # [M] height above the plane
    in_band = (residual >= grid.z_min) & (residual <= grid.z_max)
    tile, (n_x, n_y) = _tile_index(pr, grid, config)
    n_tiles = n_x * n_y
    tall = (residual >= config.obstacle_height_m) & (residual <= config.obstacle_top_m)
    obstacle = np.bincount(tile[tall], minlength=n_tiles) >= max(int(config.obstacle_min_points), 1)
    reach = int(math.ceil(config.obstacle_margin_m / config.tile_m - 1e-9))
    if reach > 0 and obstacle.any():
        kernel = np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)
        obstacle = cv2.dilate(obstacle.reshape(n_x, n_y).astype(np.uint8), kernel).reshape(-1).astype(bool)
    spread = _tile_spread(tile[in_band], residual[in_band], n_tiles)
    rough = spread > config.max_tile_spread_m
    near_obstacle = obstacle[tile]
    is_rough = rough[tile]
    keep_region = in_band & ~near_obstacle & ~is_rough
    keep = np.zeros(p.shape[0], bool)
    keep[np.flatnonzero(region)[keep_region]] = True
    rejected = {
        "outside_band": int((~in_band).sum()),
        "obstacle": int((in_band & near_obstacle).sum()),
        "rough_tile": int((in_band & ~near_obstacle & is_rough).sum()),
    }
    return RoadSelection(keep=keep, plane=plane, rejected=rejected)


def vertical_offset(reference: ElevationLabel, other: ElevationLabel, min_shared_cells: int) -> float | None:
    """Median of ``other - reference`` over the cells both hold (None when too few)."""
    both = reference.mask & other.mask
    if int(both.sum()) < max(min_shared_cells, 1):
        return None
    return float(np.median(other.elevation[both].astype(np.float64) - reference.elevation[both]))


class AccumulatedLabel(NamedTuple):
    """A frame's label and how it was made.

    Attributes:
        label: the :class:`ElevationLabel` (elevation NaN outside the mask).
        selection: the road-surface test on the accumulated points.
        scans_used: scans that went in (the frame's own one included).
        offsets_m: vertical offsets taken out of the moved scans (m).
    """

    label: ElevationLabel
    selection: RoadSelection
    scans_used: int
    offsets_m: list[float]


def accumulate_label(
    own_scan: np.ndarray,
    moved_scans: Sequence[np.ndarray],
    grid: GridSpec,
    config: LabelConfig,
) -> AccumulatedLabel:
    """The label of one frame from its own scan and scans already moved into its road frame.

    Args:
        own_scan: [N, 3] road-frame points of the scan nearest the frame.
        moved_scans: [M_k, 3] road-frame points of other scans (planar motion applied).
        grid: the label grid.
        config: the labeller's settings.

    Raises:
        LabelError: the frame's own scan has no road on the grid.
    """
    own = np.asarray(own_scan, dtype=np.float64)
    own_sel = road_points(own, grid, config)
    own_label = elevation_map(own[own_sel.keep], grid, clip_z=True)
    if not moved_scans:
        return AccumulatedLabel(own_label, own_sel, 1, [])
    parts = [own]
    offsets: list[float] = []
    for scan in moved_scans:
        scan = np.asarray(scan, dtype=np.float64)
        try:
            sel = road_points(scan, grid, config)
        except LabelError:
            continue
        dz = vertical_offset(own_label, elevation_map(scan[sel.keep], grid, clip_z=True), config.min_shared_cells)
        if dz is None:
            continue
        shifted = scan.copy()
        shifted[:, 2] -= dz
        parts.append(shifted)
        offsets.append(dz)
    points = np.concatenate(parts, axis=0)  # [sum N, 3]
    selection = road_points(points, grid, config)
    label = elevation_map(points[selection.keep], grid, clip_z=True)
    return AccumulatedLabel(label, selection, len(parts), offsets)
