"""Discrete road hazards in a road height map: speed bumps and humps, potholes, steps (issue 22).

A pure function over a map array, so it runs on the fused map (``/roadbev/map``, ``odom``) and on
a drive's true road map alike (grid_map order: row 0 at the largest x, column 0 at the largest
y; NaN = unknown):

1. **The road's own level.** Block medians over ``block_m`` cells (robust to texture and single
   outliers), then a masked box mean over ``level_window_m`` (along x, across y) that drops the
   blocks already found off the level and repeats (``passes``): the level is the least-squares
   plane through the window's blocks (box-filtered moments), which follows grade and cross
   slope exactly up to the map's edges, and masking keeps a bump from lifting its own reference.
   The window must be longer than the longest feature (humps are up to 4.5 m long).
2. **Residual** = height - level, on the full-resolution cells; cells with ``|residual| >=
   seed_fraction * min_height_m`` form candidates (8-connected, bumps and dips separately).
3. **A hazard** is a candidate whose peak reaches ``min_height_m``, whose area reaches
   ``min_area_m2``, whose extent along x stays within ``max_length_m`` (longer ones are
   kerbs, ruts or the road's edge, not discrete features) and whose height reaches
   ``min_significance`` of its 1-sigma (below, the map cannot tell it from its own noise: the
   far field's coarse cells, a backend unsure of a cell): kind ``bump`` (positive: speed bumps,
   humps, a step up) or ``pothole`` (negative), position (residual-weighted centroid in the map's
   frame), extent along x and y (a longer component is split by thresholding it again at twice
   the level, until its parts are short enough), height or depth (signed; the 75th percentile of |residual| over
   the cells above half the peak: the crest or floor without the single roughest cell), its
   1-sigma (the map's sigma on the road around it, the median over a ring of ``ring_m`` outside
   the hazard, with the residual's noise floor: the median absolute residual of the level cells,
   x 1.4826; the sigma on the hazard itself is no measure of whether it is there: a calibrated
   sigma grows with the estimate's own relief, so it is largest exactly on a real bump), and a
   confidence ``clip((|h| / sigma - 2) / 4, 0, 1)`` (0 at a 2-sigma peak, 1 from 6 sigma up: a
   documented heuristic, not a probability).

:func:`severity_cost` turns the residual into a ``nav_msgs/OccupancyGrid``-style cost (0-100,
-1 unknown) a planner can use. Pure numpy and OpenCV (box filter, connected components).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import NamedTuple, cast

import cv2
import numpy as np

from roadbev_core.errors import RoadbevError

__all__ = ["Hazard", "HazardError", "HazardSettings", "band", "detect_hazards", "hazards_in_residual", "road_residual",
           "severity_cost"]


class HazardError(RoadbevError, ValueError):
    """A map or settings the detector cannot use."""


@dataclass(frozen=True)
class HazardSettings:
    """Detector settings (SI units).

    Attributes:
        min_height_m: a hazard's peak |residual| (the issue's target: features >= 3 cm; at 2 cm an
            ISO 8608 class C road's own undulations give a few false alarms per km).
        min_area_m2: smallest area of a hazard.
        seed_fraction: cells above this share of ``min_height_m`` grow a hazard.
        block_m: the level's block size.
        level_window_m: (along x, across y) window of the level.
        passes: masking passes of the level.
        max_length_m: longest extent along x of a discrete hazard.
        min_significance: least height of a hazard in units of its 1-sigma (its confidence is 0
            there).
        ring_m: width of the ring of road around a hazard whose sigma is the hazard's.
    """

    min_height_m: float = 0.025
    min_area_m2: float = 0.01
    seed_fraction: float = 0.5
    block_m: float = 0.1
    level_window_m: tuple[float, float] = (8.0, 3.0)
    passes: int = 3
    max_length_m: float = 6.0
    min_significance: float = 2.0
    ring_m: float = 0.3

    def __post_init__(self) -> None:
        ok = (0.001 <= self.min_height_m <= 1.0 and 0.0 <= self.min_area_m2 <= 100.0
              and 0.0 <= self.min_significance <= 10.0 and 0.0 < self.ring_m <= 5.0
              and 0.05 <= self.seed_fraction <= 1.0 and 0.01 <= self.block_m <= 1.0 and 1 <= self.passes <= 10
              and all(math.isfinite(w) and w >= 2 * self.block_m for w in self.level_window_m))
        if not ok:
            raise HazardError(f"bad hazard settings {self}")


class Hazard(NamedTuple):
    """One detected hazard.

    Attributes:
        kind: ``bump`` or ``pothole``.
        x, y: centroid in the map's frame (m).
        length_m, width_m: extent along x and y (m).
        height_m: signed peak residual (m; a pothole is negative).
        height_sigma_m: 1-sigma of ``height_m``.
        confidence: 0..1 (see the module docstring).
        area_m2: area above the seed threshold.
    """

    kind: str
    x: float
    y: float
    length_m: float
    width_m: float
    height_m: float
    height_sigma_m: float
    confidence: float
    area_m2: float


def _cell_centres(shape: tuple[int, int], resolution: float,
                  centre: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """x [R] of the rows and y [C] of the columns (grid_map order)."""
    n_rows, n_cols = shape
    x = centre[0] + 0.5 * n_rows * resolution - (np.arange(n_rows) + 0.5) * resolution
    y = centre[1] + 0.5 * n_cols * resolution - (np.arange(n_cols) + 0.5) * resolution
    return x, y


def band(elevation: np.ndarray, resolution: float, centre: tuple[float, float], y_min: float,
         y_max: float) -> tuple[np.ndarray, tuple[float, float]]:
    """The columns of a map with y in [y_min, y_max] (e.g. the corridor a fused map covers) and
    the new centre: ([R, C'] view, (x, y))."""
    _, ys = _cell_centres(np.shape(elevation), resolution, centre)
    keep = np.flatnonzero((ys >= y_min) & (ys <= y_max))
    if keep.size == 0:
        raise HazardError(f"no column of the map lies in y [{y_min}, {y_max}]")
    return elevation[:, keep[0]: keep[-1] + 1], (centre[0], 0.5 * float(ys[keep[0]] + ys[keep[-1]]))


def road_residual(elevation: np.ndarray, resolution: float, settings: HazardSettings | None = None,
                  ) -> tuple[np.ndarray, float]:
    """Height above the road's own level [R, C] (NaN where unknown) and the noise floor (m).

    Raises:
        HazardError: not a 2-D map, a bad resolution, or no known cell.
    """
    s = settings or HazardSettings()
    e = np.asarray(elevation, np.float32)
    if e.ndim != 2 or not (math.isfinite(resolution) and resolution > 0):
        raise HazardError(f"need a [rows, cols] map and a positive resolution, got {e.shape}, {resolution}")
    known = np.isfinite(e)
    if not known.any():
        raise HazardError("the map holds no known cell")
    b = max(1, int(round(s.block_m / resolution)))
    R, C = e.shape
    Rb, Cb = -(-R // b), -(-C // b)
    padded = np.full((Rb * b, Cb * b), np.nan, np.float32)
    padded[:R, :C] = e
    blocks = padded.reshape(Rb, b, Cb, b).transpose(0, 2, 1, 3).reshape(Rb, Cb, b * b)
    with warnings.catch_warnings():  # all-NaN blocks
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(blocks, axis=2).astype(np.float32)  # [Rb, Cb]
    valid = np.isfinite(med)
    wr = 2 * int(round(0.5 * s.level_window_m[0] / (b * resolution))) + 1
    wc = 2 * int(round(0.5 * s.level_window_m[1] / (b * resolution))) + 1
    use = valid.copy()
    level = np.full(med.shape, np.nan)
    X, Y = np.meshgrid(np.arange(Rb, dtype=np.float64), np.arange(Cb, dtype=np.float64), indexing="ij")
    med64 = med.astype(np.float64)
    for _ in range(s.passes):
        level = _local_plane(np.where(use, med64, 0.0), use.astype(np.float64), X, Y, (wc, wr))
        off = np.abs(med64 - level) >= s.seed_fraction * s.min_height_m
        use = valid & ~off
    fine = np.repeat(np.repeat(level, b, axis=0), b, axis=1)[:R, :C]
    residual = e - fine
    calm = np.repeat(np.repeat(use, b, axis=0), b, axis=1)[:R, :C] & np.isfinite(residual)
    noise = 1.4826 * float(np.median(np.abs(residual[calm]))) if calm.any() else 0.0
    return residual, noise


def _local_plane(values: np.ndarray, weights: np.ndarray, X: np.ndarray, Y: np.ndarray,
                 window: tuple[int, int]) -> np.ndarray:
    """[Rb, Cb] the weighted least-squares plane through each cell's window, at the cell (NaN
    without any weight in the window; the window mean where a plane is not determined)."""

    def box(a: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(a, cv2.CV_64F, window, normalize=False, borderType=cv2.BORDER_CONSTANT)

    w, wx, wy = box(weights), box(weights * X), box(weights * Y)
    A = np.stack([np.stack([w, wx, wy], -1), np.stack([wx, box(weights * X * X), box(weights * X * Y)], -1),
                  np.stack([wy, box(weights * X * Y), box(weights * Y * Y)], -1)], -2)  # [Rb, Cb, 3, 3]
    rhs = np.stack([box(values), box(values * X), box(values * Y)], -1)  # [Rb, Cb, 3]
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(w > 0.5, rhs[..., 0] / w, np.nan)
    det = np.linalg.det(A)
    ok = (w > 0.5) & (np.abs(det) > 1e-6 * np.maximum(w, 1.0) ** 3)
    level = mean.copy()
    if ok.any():
        coef = np.linalg.solve(A[ok], rhs[ok][..., None])[..., 0]  # [N, 3]
        level[ok] = coef[:, 0] + coef[:, 1] * X[ok] + coef[:, 2] * Y[ok]
    return cast("np.ndarray", level)


def detect_hazards(elevation: np.ndarray, sigma: np.ndarray | None, resolution: float, centre: tuple[float, float],
                   settings: HazardSettings | None = None) -> list[Hazard]:
    """The hazards in a height map (see the module docstring), largest |height| first.

    Args:
        elevation: [R, C] heights (m), NaN = unknown, grid_map order.
        sigma: [R, C] 1-sigma (m) or None.
        resolution: cell size (m).
        centre: (x, y) of the map's centre in its frame (m).

    Raises:
        HazardError: as :func:`road_residual`, or a sigma of another shape.
    """
    s = settings or HazardSettings()
    residual, noise = road_residual(elevation, resolution, s)
    return hazards_in_residual(residual, noise, sigma, resolution, centre, s)


def hazards_in_residual(residual: np.ndarray, noise: float, sigma: np.ndarray | None, resolution: float,
                        centre: tuple[float, float], settings: HazardSettings | None = None) -> list[Hazard]:
    """:func:`detect_hazards` on a residual already computed by :func:`road_residual` (so a
    caller that also needs the residual, e.g. for :func:`severity_cost`, computes it once).

    Raises:
        HazardError: a sigma of another shape than the residual.
    """
    s = settings or HazardSettings()
    if sigma is not None and np.shape(sigma) != residual.shape:
        raise HazardError(f"sigma {np.shape(sigma)} does not match the map {residual.shape}")
    sig = np.zeros(residual.shape, np.float32) if sigma is None else np.nan_to_num(np.asarray(sigma, np.float32))
    xs, ys = _cell_centres(residual.shape, resolution, centre)
    out: list[Hazard] = []
    r = np.nan_to_num(residual, nan=0.0)
    for sign, kind in ((1.0, "bump"), (-1.0, "pothole")):
        v = (sign * r).astype(np.float32)
        _components(v, np.ones(v.shape, bool), s.seed_fraction * s.min_height_m, kind, sign, sig, noise, xs, ys,
                    resolution, s, out)
    return sorted(out, key=lambda hz: -abs(hz.height_m))


def _components(v: np.ndarray, region: np.ndarray, threshold: float, kind: str, sign: float, sig: np.ndarray,
                noise: float, xs: np.ndarray, ys: np.ndarray, resolution: float, s: HazardSettings,
                out: list[Hazard]) -> None:
    """Hazards among the cells of ``region`` with v >= ``threshold``; a component longer than
    ``max_length_m`` (features joined by rough road, or an edge) is split at twice the threshold."""
    mask = ((v >= threshold) & region).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    cell_area = resolution * resolution
    for k in range(1, n):
        area = float(stats[k, cv2.CC_STAT_AREA]) * cell_area
        if area < s.min_area_m2:
            continue
        top, left = int(stats[k, cv2.CC_STAT_TOP]), int(stats[k, cv2.CC_STAT_LEFT])
        h, w = int(stats[k, cv2.CC_STAT_HEIGHT]), int(stats[k, cv2.CC_STAT_WIDTH])
        sub = labels[top: top + h, left: left + w] == k
        vals = v[top: top + h, left: left + w]
        peak_idx = np.unravel_index(np.argmax(np.where(sub, vals, -np.inf)), sub.shape)
        peak = float(vals[peak_idx])
        if peak < s.min_height_m:
            continue
        if h * resolution > s.max_length_m:
            if 2 * threshold <= peak:
                inner = np.zeros(v.shape, bool)
                inner[top: top + h, left: left + w] = sub
                _components(v, inner, 2 * threshold, kind, sign, sig, noise, xs, ys, resolution, s, out)
            continue
        height = float(np.percentile(vals[sub & (vals >= 0.5 * peak)], 75))
        weights = np.where(sub, vals, 0.0)
        cx = float((weights.sum(axis=1) @ xs[top: top + h]) / weights.sum())
        cy = float((weights.sum(axis=0) @ ys[left: left + w]) / weights.sum())
        height_sigma = math.hypot(_ring_sigma(sub, sig, top, left, max(1, round(s.ring_m / resolution))), noise)
        z = height / max(height_sigma, 1e-4)
        if z < s.min_significance:
            continue
        out.append(Hazard(kind, cx, cy, h * resolution, w * resolution, sign * height, height_sigma,
                          float(np.clip((z - 2.0) / 4.0, 0.0, 1.0)), area))


def _ring_sigma(component: np.ndarray, sig: np.ndarray, top: int, left: int, reach: int) -> float:
    """The median sigma (> 0) of the cells within ``reach`` cells around a component (``component``
    [h, w] bool, its box at (top, left) of ``sig`` [R, C]), outside it; 0 where none is known."""
    r0, c0 = max(top - reach, 0), max(left - reach, 0)
    r1 = min(top + component.shape[0] + reach, sig.shape[0])
    c1 = min(left + component.shape[1] + reach, sig.shape[1])
    inside = np.zeros((r1 - r0, c1 - c0), np.uint8)
    inside[top - r0: top - r0 + component.shape[0], left - c0: left - c0 + component.shape[1]] = component
    kernel = np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)
    ring = (cv2.dilate(inside, kernel) > 0) & (inside == 0)
    values = sig[r0:r1, c0:c1][ring]
    values = values[values > 0]
    return float(np.median(values)) if values.size else 0.0


def severity_cost(residual: np.ndarray, full_cost_height_m: float = 0.10) -> np.ndarray:
    """[R, C] int8 cost 0..100 (``nav_msgs/OccupancyGrid`` values; -1 = unknown): |residual| over
    ``full_cost_height_m``, saturating at 100 (a 10 cm bump or pothole by default)."""
    if not (math.isfinite(full_cost_height_m) and full_cost_height_m > 0):
        raise HazardError(f"full_cost_height_m must be positive, got {full_cost_height_m}")
    r = np.asarray(residual, np.float64)
    cost = np.clip(np.rint(np.abs(np.nan_to_num(r)) / full_cost_height_m * 100.0), 0, 100).astype(np.int8)
    cost[~np.isfinite(r)] = -1
    return cost
