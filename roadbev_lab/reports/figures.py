"""Figures: voxel columns over the left image (the paper's Fig. 4) and elevation maps in cm.

Pure matplotlib through its object API (:class:`matplotlib.figure.Figure`, no pyplot): no backend
is chosen and no global figure state is touched, so importing this module changes nothing, and
every function draws into a figure of its own and saves a PNG (safe in loops and headless runs).
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure

from roadbev_core.config import GridSpec
from roadbev_core.errors import RoadbevError
from roadbev_core.frame import Frame
from roadbev_core.geometry import project_points, road_to_camera

__all__ = [
    "RELIABILITY_MIN_CELLS",
    "FigureError",
    "elevation_figure",
    "new_figure",
    "reliability_figure",
    "voxel_column_segments",
    "voxel_columns_figure",
]

# Sigma bins of a reliability curve with fewer cells are left out: their quantiles are noise.
RELIABILITY_MIN_CELLS = 50


class FigureError(RoadbevError, ValueError):
    """Input a figure cannot be drawn from."""


def new_figure(*grid: int, figsize: tuple[float, float], dpi: float, **subplot_kw: Any) -> tuple[Figure, Any]:
    """A figure and its axes (``grid`` = rows, columns as for ``subplots``), outside pyplot: nothing
    to close, no backend to choose. ``subplot_kw`` go to :meth:`Figure.subplots` (``sharex``...)."""
    fig = Figure(figsize=figsize, dpi=dpi)
    return fig, fig.subplots(*grid, **subplot_kw)


def voxel_column_segments(
    frame: Frame, grid: GridSpec, *, row_step: int = 8, col_step: int = 8, right: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Image segments of the voxel columns of every ``row_step``-th row, ``col_step``-th column.

    A column is the vertical stack of voxels over one grid cell, from ``z_min`` to ``z_max``;
    its image is the segment between the projections of its bottom and top points.

    Returns:
        segments [M, 2, 2] (u, v) pixel coordinates (bottom, top) of the columns whose both ends
        are in front of the camera, and their distances x [M] (m).
    """
    if row_step < 1 or col_step < 1:
        raise FigureError(f"row_step and col_step must be >= 1, got {row_step}, {col_step}")
    xs = grid.x_centres()[::row_step]
    ys = grid.y_centres()[::col_step]
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    ends = []
    for z in (grid.z_min, grid.z_max):
        pts = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, z)], axis=1)
        u, v, depth = project_points(road_to_camera(pts, frame.attitude, grid.base_height), frame.camera, right=right)
        ends.append((u, v, depth))
    (u0, v0, d0), (u1, v1, d1) = ends
    ok = (d0 > 0) & (d1 > 0)
    segments = np.stack([np.stack([u0, v0], axis=1), np.stack([u1, v1], axis=1)], axis=1)[ok]
    return segments, gx.ravel()[ok]


def voxel_columns_figure(
    frame: Frame,
    grid: GridSpec,
    path: str | Path,
    *,
    row_step: int = 8,
    col_step: int = 8,
    title: str | None = None,
    dpi: int = 100,
) -> Path:
    """The left image with the grid's voxel columns drawn as line segments (paper Fig. 4).

    Columns are coloured by distance; the outline of the grid's footprint on the road
    reference plane (z = 0) is drawn too.
    """
    segments, dist = voxel_column_segments(frame, grid, row_step=row_step, col_step=col_step)
    img = frame.left
    h, w = img.shape[:2]
    fig, ax = new_figure(figsize=(w / dpi, h / dpi + 0.45), dpi=dpi)
    ax.imshow(img, cmap="gray" if img.ndim == 2 else None, interpolation="nearest")
    lines = LineCollection(list(segments), cmap="turbo", linewidths=1.4, alpha=0.95)  # [N, 2, 2] -> N segments
    lines.set_array(dist)
    lines.set_clim(grid.x_min, grid.x_max)
    ax.add_collection(lines)
    # bottom and top ends as dots so the direction of the columns reads at a glance
    ax.scatter(segments[:, 0, 0], segments[:, 0, 1], s=4, c="white", linewidths=0)
    # footprint outline on the reference plane
    x0, x1, y0, y1 = grid.x_min, grid.x_max, grid.y_min, grid.y_max
    n = 50
    border = np.concatenate(
        [
            np.stack([np.full(n, x0), np.linspace(y0, y1, n)], 1),
            np.stack([np.linspace(x0, x1, n), np.full(n, y1)], 1),
            np.stack([np.full(n, x1), np.linspace(y1, y0, n)], 1),
            np.stack([np.linspace(x1, x0, n), np.full(n, y0)], 1),
        ]
    )
    pts = np.concatenate([border, np.zeros((border.shape[0], 1))], axis=1)
    u, v, _ = project_points(road_to_camera(pts, frame.attitude, grid.base_height), frame.camera)
    ax.plot(u, v, color="yellow", linewidth=1.0, linestyle="--")
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_axis_off()
    roll, pitch = frame.attitude.degrees
    ax.set_title(
        title
        or f"voxel columns z in [{grid.z_min * 100:+.0f}, {grid.z_max * 100:+.0f}] cm, every {row_step}th row / "
        f"{col_step}th column; pitch {pitch:.1f} deg, roll {roll:.1f} deg",
        fontsize=9,
    )
    cbar = fig.colorbar(lines, ax=ax, fraction=0.025, pad=0.01)
    cbar.set_label("distance ahead x (m)", fontsize=8)
    cbar.ax.tick_params(labelsize=7)
    fig.tight_layout(pad=0.3)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    return out


def elevation_figure(
    elevation: np.ndarray,
    grid: GridSpec,
    path: str | Path,
    *,
    title: str = "ground-truth elevation",
    limits_cm: tuple[float, float] | None = None,
    dpi: int = 120,
) -> Path:
    """An elevation map [n_rows, n_cols] (m; NaN = none) as a BEV image with a colour bar in cm.

    The far end is at the top, the vehicle's left on the left (grid_map's own order), axes in
    metres of the road frame; cells without a value are grey.
    """
    elev = np.asarray(elevation, dtype=np.float64)
    if elev.shape != grid.shape:
        raise FigureError(f"elevation map is {elev.shape}, the grid is {grid.shape}")
    cm = elev * 100.0
    finite = np.isfinite(cm)
    if limits_cm is None:
        if finite.any():
            lo, hi = np.percentile(cm[finite], [1, 99])
            span = max(abs(lo), abs(hi), 0.5)
            limits_cm = (-span, span)
        else:
            limits_cm = (-1.0, 1.0)
    cmap = matplotlib.colormaps["RdBu_r"].with_extremes(bad="0.6")
    aspect = grid.length_x / grid.length_y
    fig, ax = new_figure(figsize=(3.6, min(2.6 + 1.55 * aspect, 9.0)), dpi=dpi)
    extent = (grid.y_max, grid.y_min, grid.x_min, grid.x_max)  # left edge = +y (vehicle's left)
    im = ax.imshow(
        np.ma.masked_invalid(cm),
        cmap=cmap,
        vmin=limits_cm[0],
        vmax=limits_cm[1],
        extent=extent,
        origin="upper",
        interpolation="nearest",
        aspect="equal",
    )
    ax.set_xlabel("lateral y (m, left +)")
    ax.set_ylabel("distance ahead x (m)")
    valid = f"{finite.mean() * 100:.0f}% cells" if finite.any() else "no cells"
    rng = f", {np.nanmin(cm):+.1f}..{np.nanmax(cm):+.1f} cm" if finite.any() else ""
    ax.set_title("\n".join([*textwrap.wrap(title, 38), f"{valid}{rng}"]), fontsize=9)
    cbar = fig.colorbar(im, ax=ax, fraction=0.08, pad=0.04)
    cbar.set_label("elevation (cm)")
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi, bbox_inches="tight", pad_inches=0.1)
    return out


def reliability_figure(
    curves: Sequence[tuple[str, Sequence[Mapping[str, Any]]]],
    path: str | Path,
    title: str,
    *,
    min_cells: int = RELIABILITY_MIN_CELLS,
    dpi: int = 120,
) -> Path:
    """Observed error quantiles against predicted sigma, one colour per curve (a reliability plot).

    Each curve is a label and the entries of :func:`roadbev_lab.evaluation.metrics.reliability_curve` (the
    ``reliability`` key of ``roadbev eval``'s JSON). Per sigma bin with at least ``min_cells``
    cells: the 68.3 % quantile of |error| (solid) and half the 95.4 % quantile (dashed) against the
    bin's mean sigma. An honest Gaussian sigma puts both on the diagonal; a point above it is
    over-confident. Log axes, linear below 0.1 cm.

    Raises:
        FigureError: no curve has a bin with ``min_cells`` cells (nothing to draw).
    """
    kept = [(label, [b for b in curve if b["cells"] >= min_cells]) for label, curve in curves]
    kept = [(label, curve) for label, curve in kept if curve]
    if not kept:
        raise FigureError(f"no reliability curve has a sigma bin with {min_cells} cells or more")
    fig, ax = new_figure(figsize=(6.0, 5.0), dpi=dpi)
    top = 0.5
    for label, curve in kept:
        sigma = [float(b["mean_sigma_cm"]) for b in curve]
        q68 = [float(b["q68_abs_err_cm"]) for b in curve]
        (line,) = ax.plot(sigma, q68, marker="o", ms=3, lw=1.5, label=f"{label} (68 %)")
        ax.plot(sigma, [float(b["q95_abs_err_cm"]) / 2 for b in curve], ls="--", lw=1.0, color=line.get_color())
        top = max(top, *sigma, *q68)
    ax.plot([0, top], [0, top], color="grey", lw=0.8, label="honest sigma")
    ax.set_xscale("symlog", linthresh=0.1)
    ax.set_yscale("symlog", linthresh=0.1)
    ax.set_xlabel("predicted 1-sigma, bin mean (cm)")
    ax.set_ylabel("observed |error| quantile (cm): 68.3 % solid, 95.4 % / 2 dashed")
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    return out
