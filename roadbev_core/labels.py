"""Ground-truth elevation labels from point clouds, and elevation <-> class bins.

The paper (section 3): points in the road frame are grouped into the 3 x 3 cm cells of the grid;
a cell's label is the mean z of its points; the mask marks cells with at least one point.
Vectorized with ``np.bincount``, far faster than a per-point loop (``benchmarks/bench_labels.py``
compares the two; figures in ``docs/results/tuning.md``).
"""

from __future__ import annotations

from typing import NamedTuple, cast

import numpy as np

from roadbev_core.config import GridSpec
from roadbev_core.geometry import Attitude, camera_to_road

__all__ = [
    "ElevationLabel",
    "cell_index",
    "cell_means",
    "class_to_elevation",
    "elevation_map",
    "elevation_map_from_camera",
    "elevation_to_class",
    "one_hot",
    "two_hot",
]


class ElevationLabel(NamedTuple):
    """A label map: elevation [n_rows, n_cols] float32 (NaN outside the mask), mask bool, count."""

    elevation: np.ndarray
    mask: np.ndarray
    # The field shadows tuple.count (a public name since the first release, kept for its users).
    count: np.ndarray  # type: ignore[assignment]


def cell_index(points_road: np.ndarray, grid: GridSpec, *, clip_z: bool = False) -> np.ndarray:
    """Flat cell index [N] (intp, ``row * n_cols + col``) of each road-frame point [N, 3+];
    ``n_rows * n_cols`` (one cell past the grid) for a point outside the grid, with a
    non-finite coordinate, or with ``clip_z`` outside ``[z_min, z_max]``."""
    pts = np.asarray(points_road)
    if pts.ndim != 2 or pts.shape[1] < 3:
        raise ValueError(f"points must be [N, 3], got {pts.shape}")
    x, y, z = pts[:, 0], pts[:, 1], pts[:, 2]
    # Row/col as in GridSpec.cell_index, fused here: this is the hot path for 1 M-point clouds.
    # Fractional indices are tested before truncation (truncation equals floor once >= 0), and
    # NaN coordinates fail every comparison, so they drop out without a separate pass.
    r = (grid.x_max - x) / grid.resolution  # [N] fractional row
    c = (grid.y_max - y) / grid.resolution  # [N] fractional col
    keep = (r >= 0) & (r < grid.n_rows) & (c >= 0) & (c < grid.n_cols) & np.isfinite(z)
    if clip_z:
        keep &= (z >= grid.z_min) & (z <= grid.z_max)
    # Points outside go to one extra "dump" cell rather than being compressed out: boolean
    # indexing would cost more than everything else together.
    with np.errstate(invalid="ignore"):  # NaN/inf casts are masked out by `keep`
        return np.where(keep, r.astype(np.intp) * grid.n_cols + c.astype(np.intp), grid.n_rows * grid.n_cols)


def cell_means(flat: np.ndarray, grid: GridSpec, *values: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """Point count [n_rows, n_cols] (int32) and, per ``values`` array [N], the mean of its points
    in each cell [n_rows, n_cols] (float32, NaN where no point fell), for points indexed by
    :func:`cell_index` (``flat`` [N]; those past the grid are left out)."""
    n_cells = grid.n_rows * grid.n_cols
    count = np.bincount(flat, minlength=n_cells + 1)[:n_cells]
    mask = count > 0
    means = []
    for value in values:
        # the dump cell's sum (where a left-out point's NaN may land) is cut off with it
        total = np.bincount(flat, weights=value, minlength=n_cells + 1)[:n_cells]
        mean = np.full(n_cells, np.nan, dtype=np.float64)
        mean[mask] = total[mask] / count[mask]
        means.append(mean.reshape(grid.shape).astype(np.float32))
    return count.reshape(grid.shape).astype(np.int32), means


def elevation_map(points_road: np.ndarray, grid: GridSpec, *, clip_z: bool = False) -> ElevationLabel:
    """Mean elevation of the road-frame points in each grid cell.

    Args:
        points_road: [N, 3] (x, y, z) in the road frame; extra columns are ignored.
        grid: the BEV grid.
        clip_z: drop points outside ``[z_min, z_max]`` before averaging.

    Returns:
        ElevationLabel with elevation NaN where no point fell.
    """
    flat = cell_index(points_road, grid, clip_z=clip_z)  # [N]
    count, (elevation,) = cell_means(flat, grid, np.asarray(points_road)[:, 2])
    return ElevationLabel(elevation=elevation, mask=count > 0, count=count)


def elevation_map_from_camera(
    points_cam: np.ndarray, attitude: Attitude, grid: GridSpec, *, clip_z: bool = False
) -> ElevationLabel:
    """:func:`elevation_map` for points [N, 3] in the left camera's optical frame."""
    road = camera_to_road(np.asarray(points_cam, dtype=np.float64)[:, :3], attitude, grid.base_height)
    return elevation_map(road, grid, clip_z=clip_z)


def elevation_to_class(elevation: np.ndarray, grid: GridSpec) -> np.ndarray:
    """Class index [...] (int64) of the bin holding each elevation, clipped to the range."""
    idx = np.floor((np.asarray(elevation, dtype=np.float64) - grid.z_min) / grid.class_resolution)
    return cast("np.ndarray", np.clip(np.nan_to_num(idx, nan=0.0), 0, grid.n_classes - 1).astype(np.int64))


def class_to_elevation(index: np.ndarray, grid: GridSpec) -> np.ndarray:
    """Elevation [...] of class-bin centres."""
    return grid.class_centres()[np.asarray(index, dtype=np.int64)]


def one_hot(elevation: np.ndarray, grid: GridSpec) -> np.ndarray:
    """[n_classes, ...] float32 one-hot label of the bin holding each elevation (paper eq. 3)."""
    idx = elevation_to_class(elevation, grid)
    out = np.zeros((grid.n_classes, *idx.shape), dtype=np.float32)
    np.put_along_axis(out, idx[None], 1.0, axis=0)
    return out


def two_hot(elevation: np.ndarray, grid: GridSpec) -> np.ndarray:
    """[n_classes, ...] float32 soft label split between the two nearest bin centres.

    Its expectation over the bin centres equals the elevation exactly (inside the range), so
    soft-argmin trained on it has no quantisation floor.
    """
    centres = grid.class_centres()
    e = np.clip(np.nan_to_num(np.asarray(elevation, dtype=np.float64)), centres[0], centres[-1])
    pos = (e - centres[0]) / grid.class_resolution  # fractional bin index
    lo = np.clip(np.floor(pos).astype(np.int64), 0, grid.n_classes - 2)
    w_hi = (pos - lo).astype(np.float32)
    out = np.zeros((grid.n_classes, *e.shape), dtype=np.float32)
    np.put_along_axis(out, lo[None], (1.0 - w_hi)[None], axis=0)
    np.put_along_axis(out, (lo + 1)[None], w_hi[None], axis=0)
    return out
