"""What the camera can see of an estimated road: cells hidden behind a crest.

A camera ``base_height`` above the road origin sees a cell at height ``e`` only when its line of
sight passes above the road in front of it. Behind a speed bump the road drops out of view: an
estimator then reports what it *can* see there, the crest's edge, smeared over the strip behind
it (a phantom plateau, confidently wrong). These pure functions find such cells from the estimate
alone, for any backend:

* the estimate itself is **hidden** when its line of sight grazes or passes below the (hole-filled)
  estimated surface in front: what was matched there is the occluder, not the road;
* a cell that is seen but lies where a crest in front would hide the road's own level
  keeps its estimate with its height above the road as a term of its sigma
  (:mod:`roadbev_core.uncertainty`): a plateau at the crest's height cannot be told from a road
  that drops back out of view.

Road frame (docs/interface/frames-and-grid.md): x forward, y left, z up; the left camera at (0, 0, ``base_height``), the
right one ``baseline`` to its right at y = -baseline (roll ignored: a few mm at the grid's far
end). Grid order: row 0 farthest, col 0 leftmost.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache
from typing import NamedTuple

import cv2
import numpy as np

from roadbev_core.config import GridSpec

__all__ = [
    "CLEARANCE",
    "RoadPlane",
    "Sight",
    "Visibility",
    "analyse",
    "fill_holes",
    "fit_road_plane",
    "hidden_cells",
    "line_of_sight",
]

SAMPLES = 48  # points per line of sight (over the stretch that can hide the cell)
_SAMPLE_CHUNK = 4  # samples of every line of sight taken at once (line_of_sight)
# Samples stop this many cells before their target (its own neighbourhood is not an occluder).
_GAP_CELLS = 1.5
# Least clearance ratio of a visible line of sight (bev_sweep's occlusion_clearance defaults to it).
CLEARANCE = 0.3


class RoadPlane(NamedTuple):
    """z = offset + slope_x * x + slope_y * y (road frame, metres) fitted to an estimate."""

    offset: float
    slope_x: float
    slope_y: float
    cells: int  # cells the fit kept (0 = no fit: all fields 0)
    rms: float  # residual RMS of the kept cells (m)

    def heights(self, grid: GridSpec) -> np.ndarray:
        """[R, C] the plane's z at every cell centre."""
        x = grid.x_centres()[:, None]
        y = grid.y_centres()[None, :]
        return (self.offset + self.slope_x * x + self.slope_y * y).astype(np.float32)


def fit_road_plane(elevation: np.ndarray, grid: GridSpec, *, tolerance: float = 0.02, rounds: int = 3) -> RoadPlane:
    """Least-squares road plane through the estimated cells, bumps and potholes trimmed.

    Each round refits to the cells within ``tolerance`` (m) of the previous plane, so features
    a few per cent of the cells big do not tilt it.

    Args:
        elevation: [R, C] metres, NaN = no estimate.
        grid: the grid of ``elevation``.
        tolerance: residual (m) beyond which a cell is left out of the next round.
        rounds: refits after the first.

    Returns:
        The plane; ``cells == 0`` (a flat plane at 0) when fewer than 3 cells are estimated.
    """
    x = np.broadcast_to(grid.x_centres()[:, None], grid.shape)
    y = np.broadcast_to(grid.y_centres()[None, :], grid.shape)
    keep = np.isfinite(elevation)  # [R, C]
    coeffs = np.zeros(3)
    for _ in range(rounds + 1):
        if keep.sum() < 3:
            return RoadPlane(0.0, 0.0, 0.0, 0, 0.0)
        design = np.stack([np.ones(int(keep.sum())), x[keep], y[keep]], axis=1)  # [N, 3]
        coeffs, *_ = np.linalg.lstsq(design, elevation[keep].astype(np.float64), rcond=None)
        residual = elevation - (coeffs[0] + coeffs[1] * x + coeffs[2] * y)  # [R, C]
        keep = np.isfinite(elevation) & (np.abs(residual) <= tolerance)
    kept = residual[keep] if keep.any() else np.zeros(1)
    return RoadPlane(float(coeffs[0]), float(coeffs[1]), float(coeffs[2]), int(keep.sum()),
                     float(np.sqrt(np.mean(np.square(kept)))))


def fill_holes(surface: np.ndarray, known: np.ndarray, fallback: np.ndarray | float = 0.0) -> np.ndarray:
    """[R, C] float32 ``surface`` with the cells not ``known`` filled from known neighbours.

    Normalised box filtering with a growing reach (5, 9, 17, 33, 65 cells) until every cell has a
    value; cells with no known cell within 32 get ``fallback`` (a scalar or [R, C]).
    """
    values = np.where(known, surface, 0.0).astype(np.float32)
    weight = known.astype(np.float32)
    filled, have = values.copy(), known.copy()
    for reach in (2, 4, 8, 16, 32):
        if have.all():
            break
        size = (2 * reach + 1, 2 * reach + 1)
        num = cv2.boxFilter(values, -1, size, normalize=False, borderType=cv2.BORDER_CONSTANT)
        den = cv2.boxFilter(weight, -1, size, normalize=False, borderType=cv2.BORDER_CONSTANT)
        fresh = ~have & (den > 0.5)
        filled[fresh] = num[fresh] / den[fresh]
        have |= fresh
    return np.where(have, filled, np.broadcast_to(np.asarray(fallback, np.float32), filled.shape)).astype(np.float32)


class Sight(NamedTuple):
    """Lines of sight from the camera(s) to every cell over a hole-free surface."""

    clearance: np.ndarray  # [R, C] least (ray - surface) / (ray over a flat road): 1 flat, < 0 below
    lowest_visible: np.ndarray  # [R, C] the lowest height at which the cell would still be seen (m)


class _Rays(NamedTuple):
    """The fixed geometry of the rays of one camera over one grid (see :func:`_rays`)."""

    fractions: np.ndarray  # [F, R, 1] share of the way from the camera to the cell, float32
    inverse: np.ndarray  # [F, R, 1] 1 / fractions
    untested: np.ndarray  # [F, R, 1] 0 where the sample lies over the grid in front of the cell, else inf
    map_cols: np.ndarray  # [F * R, C] float32 cv2.remap column coordinates
    map_rows: np.ndarray  # [F * R, C] float32 cv2.remap row coordinates


@lru_cache(maxsize=16)
def _rays(grid: GridSpec, origin_y: float) -> _Rays:
    """Sample points of every cell's line of sight from a camera at lateral ``origin_y``.

    Only the last stretch before a cell can hide it: a point at most ``z_max - z_min`` above the
    cell shadows at most (z_max - z_min) x / (H - z_min) behind itself, so the samples cover that
    stretch (bounded by the grid's near edge), :data:`SAMPLES` of them, ending 1.5 cells before the
    cell (its own neighbourhood is not an occluder).
    """
    n_rows, n_cols = grid.shape
    x = grid.x_centres()[None, :, None]  # [1, R, 1]
    y = grid.y_centres()[None, None, :]  # [1, 1, C]
    far_end = x - _GAP_CELLS * grid.resolution  # [1, R, 1]
    shadow = (grid.z_max - grid.z_min) * x / (grid.base_height - grid.z_min)  # [1, R, 1]
    near_end = np.maximum(grid.x_min, far_end - shadow)
    px = near_end + np.linspace(0.0, 1.0, SAMPLES)[:, None, None] * (far_end - near_end)  # [F, R, 1]
    fractions = px / x  # [F, R, 1]
    tested = np.broadcast_to(far_end > grid.x_min, (SAMPLES, n_rows, 1))  # [F, R, 1]
    py = origin_y + fractions * (y - origin_y)  # [F, R, C]
    map_cols = ((grid.y_max - py) / grid.resolution - 0.5).reshape(SAMPLES * n_rows, n_cols)
    map_rows = np.broadcast_to((grid.x_max - px) / grid.resolution - 0.5, (SAMPLES, n_rows, n_cols))
    return _Rays(
        fractions.astype(np.float32),
        (1.0 / np.maximum(fractions, 1e-6)).astype(np.float32),
        np.where(tested, 0.0, np.inf).astype(np.float32),
        np.ascontiguousarray(map_cols, dtype=np.float32),
        np.ascontiguousarray(map_rows.reshape(SAMPLES * n_rows, n_cols), dtype=np.float32),
    )


def line_of_sight(
    surface: np.ndarray, targets: np.ndarray, grid: GridSpec, camera_y: Sequence[float] = (0.0,)
) -> Sight:
    """Clearance of the rays to ``targets`` over ``surface``, the worst over the cameras.

    The ray from a camera centre (``base_height`` above the road, lateral position ``camera_y``)
    to a cell at height ``targets`` is sampled at :data:`SAMPLES` points over the stretch in front
    of the cell that could hide it (:func:`_rays`). At each sample the ray's height above
    ``surface`` (bilinear) is divided by its height over a flat road, (H - target)(1 - f) at
    fraction f of the way: about 1 over a plane, near 0 when the ray grazes a crest, negative
    when it passes below the surface.

    Args:
        surface: [R, C] metres, no NaN (see :func:`fill_holes`).
        targets: [R, C] heights of the cells the rays aim at (metres).
        grid: the grid of both.
        camera_y: lateral positions (road-frame y, m) of the cameras that must see the cell.

    Returns:
        A :class:`Sight`; cells with no sample in front (the nearest rows) have clearance inf
        and lowest_visible -inf.
    """
    n_rows, n_cols = grid.shape
    height = np.float32(grid.base_height)
    e = targets.astype(np.float32)[None]  # [1, R, C]
    plane = np.ascontiguousarray(surface, dtype=np.float32)
    clearance = np.full((n_rows, n_cols), np.inf, np.float32)
    lowest = np.full((n_rows, n_cols), -np.inf, np.float32)
    cameras = [_rays(grid, float(origin_y)) for origin_y in camera_y]
    if not cameras:
        return Sight(clearance, lowest)
    # The samples go in chunks small enough to stay in cache; the ray's height and its height
    # over a flat road depend on the fraction only, not on the camera.
    for start in range(0, SAMPLES, _SAMPLE_CHUNK):
        samples = slice(start, min(start + _SAMPLE_CHUNK, SAMPLES))
        f = cameras[0].fractions[samples]  # [F', R, 1]
        ray_z = height + f * (e - height)  # [F', R, C]
        flat = np.maximum((height - e) * (1.0 - f), 1e-6)  # [F', R, C]
        sampled = slice(samples.start * n_rows, samples.stop * n_rows)  # the samples' rows of the remap tables
        for rays in cameras:
            ground = cv2.remap(plane, rays.map_cols[sampled], rays.map_rows[sampled], cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REPLICATE).reshape(-1, n_rows, n_cols)  # [F', R, C]
            ratio = (ray_z - ground) / flat + rays.untested[samples]
            np.minimum(clearance, ratio.min(axis=0), out=clearance)
            # A ray to (x, y, h) clears a sample at fraction f iff h > H - (H - ground) / f.
            shadow = height - (height - ground) * rays.inverse[samples] - rays.untested[samples]  # [F', R, C]
            np.maximum(lowest, shadow.max(axis=0), out=lowest)
    return Sight(clearance, lowest)


class Visibility(NamedTuple):
    """What :func:`analyse` found for one estimate."""

    plane: RoadPlane  # fitted to the estimate
    road: np.ndarray  # [R, C] the plane's heights
    surface: np.ndarray  # [R, C] the estimate, holes filled (the occluding surface)
    sight: Sight  # lines of sight to the surface
    hidden: np.ndarray  # [R, C] bool: estimated cells whose line of sight is blocked or grazing


def analyse(
    elevation: np.ndarray, grid: GridSpec, camera_y: Sequence[float] = (0.0,), *, clearance: float = CLEARANCE
) -> Visibility:
    """Road plane, hole-filled surface, lines of sight and hidden cells of one estimate.

    The occluding surface is the estimate with its holes filled from neighbours (the road plane
    where none is near). A cell is hidden when its own line of sight, to its estimated height, has
    less than ``clearance`` of the flat-road clearance at some point in front: behind a bump or a
    kerb what an estimator finds there is the occluder's edge, not the road. (Cells that are seen
    but lie in a crest's shadow, where the road may drop out of view, keep their estimate and get
    the ``shadow`` term of :mod:`roadbev_core.uncertainty` in their sigma.)

    Args:
        elevation: [R, C] metres, NaN = no estimate (never flagged).
        grid: the grid of ``elevation``.
        camera_y: lateral positions (road-frame y, m) of the cameras that must see a cell:
            ``(0.0,)`` for mono, ``(0.0, -baseline)`` for stereo.
        clearance: least clearance ratio of a visible line of sight (0 = only rays below the
            surface count as hidden).
    """
    known = np.isfinite(elevation)
    plane = fit_road_plane(elevation, grid)
    road = plane.heights(grid)
    surface = fill_holes(elevation, known, road)
    sight = line_of_sight(surface, surface, grid, camera_y)
    return Visibility(plane, road, surface, sight, known & (sight.clearance < clearance))


def hidden_cells(
    elevation: np.ndarray, grid: GridSpec, camera_y: Sequence[float] = (0.0,), *, clearance: float = CLEARANCE
) -> np.ndarray:
    """[R, C] bool: estimated cells whose line of sight grazes or passes below the road in front
    (:func:`analyse`)."""
    return analyse(elevation, grid, camera_y, clearance=clearance).hidden
