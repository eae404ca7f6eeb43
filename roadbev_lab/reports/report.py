"""The demo's visual report: matplotlib figures (Agg) and an HTML page that opens offline.

Pure plotting over arrays: :func:`write_report` takes a :class:`ReportData` (metrics per run,
a few frames with image, ground truth and estimate, wheel-track profiles, timing) and writes

* ``frames.png``: the paper's Fig. 7 layout, one row per frame: left image with the ROI (the
  voxel grid's footprint projected into it), ground truth, estimate, residual (GT - estimate),
  elevation in cm with one colour bar shared by GT and estimate and one for the residuals; with
  a recorded sigma also the 1-sigma map, and the confidently wrong cells (|residual| > 3 sigma
  and > 1 cm) dotted on the residual; cells the ground truth hides from the cameras hatched;
* ``surface.png``: a 3D surface render of one estimate;
* ``preview.png``: left and right wheel-track profiles (recorded) against ground-truth profiles;
* ``band_error.png``: absolute error against distance (15 bands) per run;
* ``reliability.png``: observed error quantiles against predicted sigma per run
  (:func:`roadbev_lab.reports.figures.reliability_figure`), when a run carries a ``reliability`` curve;
* ``timing.png``: latency and output rate over time;
* ``index.html`` (images referenced relatively) and ``report.json`` (every number shown).

BEV maps are drawn with true aspect (the default grid is 4.92 m long x 1.92 m wide), near at the
bottom and left on the left: the array's row 0 is the farthest row and column 0 the leftmost,
so ``imshow`` of the array as is, with the lateral axis running from +y (left) to -y (right).
"""

from __future__ import annotations

import html
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, cast

import matplotlib
import numpy as np
from matplotlib import colors as mcolors
from matplotlib.axes import Axes
from matplotlib.collections import PatchCollection
from matplotlib.figure import Figure
from matplotlib.image import AxesImage
from matplotlib.patches import Patch, Rectangle
from mpl_toolkits.mplot3d import Axes3D  # registers the 3d projection

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.errors import RoadbevError
from roadbev_core.geometry import Attitude, project_points, road_to_camera
from roadbev_lab.demo.drive import DriveSection
from roadbev_lab.evaluation.frames import to_json
from roadbev_lab.evaluation.metrics import CONFIDENT_WRONG_CM
from roadbev_lab.reports.drive_report import drive_html, format_cell, write_drive_figures
from roadbev_lab.reports.figures import RELIABILITY_MIN_CELLS, FigureError, new_figure, reliability_figure

__all__ = [
    "FIGURE_NAMES",
    "FrameView",
    "ReportData",
    "ReportError",
    "RunSummary",
    "TimingTrace",
    "TrackProfile",
    "band_centres_m",
    "mask_runs",
    "plot_band_error",
    "plot_frames",
    "plot_preview",
    "plot_surface",
    "plot_timing",
    "roi_outline_px",
    "write_report",
]

FIGURE_NAMES: tuple[str, ...] = (
    "frames.png", "surface.png", "preview.png", "band_error.png", "reliability.png", "timing.png",
)
_DPI = 110
_ELEVATION_CMAP = "turbo"
_RESIDUAL_CMAP = "RdBu_r"
_SIGMA_CMAP = "viridis"
_NO_DATA_COLOUR = "#d9d9d9"
_HIDDEN_HATCH = "////"
_HIDDEN_LABEL = "hidden from the cameras (GT)"


class ReportError(RoadbevError, ValueError):
    """Report input that cannot be drawn (no frames, mismatched shapes), with the reason."""


# --------------------------------------------------------------------------------------------
# inputs
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TrackProfile:
    """Elevation along one wheel track, nearest sample first.

    Attributes:
        name: ``left`` or ``right`` (or another track name).
        lateral_offset_m: y of the track centre in the road frame (left positive).
        distance_m: [n] x of each sample ahead of the camera.
        elevation_m: [n] road height (NaN = none).
        sigma_m: [n] 1-sigma uncertainty, or None.
        hidden: [n] bool, samples whose tyre footprint the road in front hides from the cameras
            (from the ground truth), or None when unknown.
    """

    name: str
    lateral_offset_m: float
    distance_m: np.ndarray
    elevation_m: np.ndarray
    sigma_m: np.ndarray | None = None
    hidden: np.ndarray | None = None


@dataclass(frozen=True)
class FrameView:
    """One frame as the report shows it.

    Attributes:
        index: frame number in the drive (0-based).
        stamp_ns: the left image's stamp.
        left: [H, W, 3] RGB uint8 or [H, W] grey left image.
        camera: the rig (for the ROI overlay).
        attitude: camera attitude at the stamp.
        truth: [n_rows, n_cols] ground-truth elevation (m, NaN = no label), or None.
        estimate: [n_rows, n_cols] estimated elevation (m, NaN = none).
        tracks: estimated wheel-track profiles (as recorded from the node).
        truth_tracks: the same profiles computed from the ground truth.
        sigma: [n_rows, n_cols] the estimate's 1-sigma (m, NaN = none), or None.
        hidden: [n_rows, n_cols] bool, cells the ground truth hides from the cameras (behind a
            crest: no estimator can see them), or None when unknown.
    """

    index: int
    stamp_ns: int
    left: np.ndarray
    camera: StereoCamera
    attitude: Attitude
    truth: np.ndarray | None
    estimate: np.ndarray
    tracks: tuple[TrackProfile, ...] = ()
    truth_tracks: tuple[TrackProfile, ...] = ()
    sigma: np.ndarray | None = None
    hidden: np.ndarray | None = None


@dataclass(frozen=True)
class RunSummary:
    """Metrics of one backend run (the JSON keys of docs/interface/evaluation.md), labelled for the table."""

    label: str
    backend: str
    mode: str
    metrics: dict[str, Any]


@dataclass(frozen=True)
class TimingTrace:
    """When each output arrived, for the latency and rate plots.

    Attributes:
        stamp_s: [n] image stamp of each output, seconds since the first input stamp.
        latency_ms: [n] time from the input's publication to the output's reception.
        receive_s: [n] reception time of each output, seconds since the first publication.
    """

    stamp_s: np.ndarray
    latency_ms: np.ndarray
    receive_s: np.ndarray


@dataclass
class ReportData:
    """Everything the report shows."""

    title: str
    grid: GridSpec
    runs: list[RunSummary]
    frames: list[FrameView]
    timing: TimingTrace | None = None
    notes: list[str] = field(default_factory=list)
    settings: dict[str, Any] = field(default_factory=dict)
    stage_seconds: dict[str, float] = field(default_factory=dict)
    drive: DriveSection | None = None  # the drive section (roadbev_lab.reports.drive_report)


# --------------------------------------------------------------------------------------------
# geometry helpers
# --------------------------------------------------------------------------------------------
def _bev_extent(grid: GridSpec) -> tuple[float, float, float, float]:
    """imshow extent: lateral from +y (left, image left) to -y, x from near (bottom) to far."""
    return (grid.y_max, grid.y_min, grid.x_min, grid.x_max)


def band_centres_m(grid: GridSpec, n_bands: int = 15) -> np.ndarray:
    """[n_bands] mean x of the rows in each distance band, near to far."""
    bands = grid.band_of_rows(n_bands)
    x = grid.x_centres()
    return np.array([x[bands == b].mean() for b in range(n_bands)])


def roi_outline_px(
    grid: GridSpec, camera: StereoCamera, attitude: Attitude, z: float = 0.0, samples: int = 50
) -> np.ndarray:
    """The grid's rectangle at height ``z`` projected into the left image.

    Returns:
        [4 * samples + 1, 2] pixel coordinates (u, v) of the closed outline; NaN where a point
        lies behind the camera.
    """
    corners = [
        (grid.x_min, grid.y_max),
        (grid.x_max, grid.y_max),
        (grid.x_max, grid.y_min),
        (grid.x_min, grid.y_min),
    ]
    pts = []
    for (xa, ya), (xb, yb) in zip(corners, corners[1:] + corners[:1], strict=False):
        t = np.linspace(0.0, 1.0, samples, endpoint=False)
        pts.append(np.stack([xa + (xb - xa) * t, ya + (yb - ya) * t, np.full_like(t, z)], axis=1))
    road = np.concatenate([*pts, pts[0][:1]], axis=0)  # [4*samples+1, 3]
    u, v, depth = project_points(road_to_camera(road, attitude, grid.base_height), camera)
    uv = np.stack([u, v], axis=1)
    uv[depth <= 0] = np.nan
    return uv


def _project_line(
    grid: GridSpec, camera: StereoCamera, attitude: Attitude, y: float, samples: int = 40
) -> np.ndarray:
    """[samples, 2] pixels of the line at lateral ``y`` from x_min to x_max on the z = 0 plane."""
    x = np.linspace(grid.x_min, grid.x_max, samples)
    road = np.stack([x, np.full_like(x, y), np.zeros_like(x)], axis=1)
    u, v, _ = project_points(road_to_camera(road, attitude, grid.base_height), camera)
    return np.stack([u, v], axis=1)


# --------------------------------------------------------------------------------------------
# colour scales
# --------------------------------------------------------------------------------------------
def _elevation_limits_cm(maps: Sequence[np.ndarray]) -> tuple[float, float]:
    """Shared colour range (cm): 0.2nd..99.8th percentile of the maps, at least 2 cm wide.

    Callers pass the ground-truth maps when there are any, so that a pothole's full depth stays
    inside the scale and an estimate's outliers clip instead of washing out the colours.
    """
    values = np.concatenate([m[np.isfinite(m)].ravel() for m in maps if m is not None] or [np.zeros(1)])
    if values.size == 0:
        values = np.zeros(1)
    lo, hi = np.percentile(values * 100.0, [0.2, 99.8])
    if hi - lo < 2.0:
        mid = 0.5 * (hi + lo)
        lo, hi = mid - 1.0, mid + 1.0
    return float(lo), float(hi)


def _residual_limit_cm(residuals: Sequence[np.ndarray]) -> float:
    """Symmetric residual colour range (cm): 99th percentile of |residual|, at least 0.5 cm."""
    values = np.concatenate([np.abs(r[np.isfinite(r)]).ravel() for r in residuals] or [np.zeros(1)])
    if values.size == 0:
        return 0.5
    return float(max(np.percentile(values * 100.0, 99.0), 0.5))


def _cmap(name: str) -> mcolors.Colormap:
    return matplotlib.colormaps[name].with_extremes(bad=_NO_DATA_COLOUR)


# --------------------------------------------------------------------------------------------
# figures
# --------------------------------------------------------------------------------------------
def _draw_roi(ax: Any, frame: FrameView, grid: GridSpec) -> None:
    """Left image with the voxel grid's footprint: the ROI at z = 0 (red) and z_min / z_max."""
    img = frame.left
    ax.imshow(img, cmap="gray" if img.ndim == 2 else None, vmin=0, vmax=255, interpolation="antialiased")
    for z, style in ((grid.z_min, dict(color="orange", lw=0.7, ls=":")),
                     (grid.z_max, dict(color="orange", lw=0.7, ls="--")),
                     (0.0, dict(color="red", lw=1.4, ls="-"))):
        uv = roi_outline_px(grid, frame.camera, frame.attitude, z)
        ax.plot(uv[:, 0], uv[:, 1], **style)
    for track in frame.tracks or frame.truth_tracks:
        uv = _project_line(grid, frame.camera, frame.attitude, track.lateral_offset_m)
        ax.plot(uv[:, 0], uv[:, 1], color="cyan", lw=0.9, ls="-.")
    ax.set_xlim(-0.5, frame.camera.width - 0.5)
    ax.set_ylim(frame.camera.height - 0.5, -0.5)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(f"frame {frame.index}: left image, ROI", fontsize=9)


def _style_bev_axes(ax: Any, grid: GridSpec, *, first: bool, last_row: bool) -> None:
    ax.set_aspect("equal")
    ax.tick_params(labelsize=7)
    ax.set_xticks([grid.y_max, 0.0, grid.y_min])
    ax.set_xticklabels([f"{grid.y_max:+.2f}", "0", f"{grid.y_min:+.2f}"])
    if last_row:
        ax.set_xlabel("lateral y (m, + left)", fontsize=7)
    if first:
        ax.set_ylabel("distance ahead x (m)", fontsize=7)
    else:
        ax.set_yticklabels([])


def mask_runs(mask: np.ndarray) -> list[tuple[int, int, int]]:
    """The set cells of ``mask`` [R, C] as horizontal runs (row, first col, last col + 1)."""
    runs = []
    padded = np.pad(np.asarray(mask, bool), ((0, 0), (1, 1))).astype(np.int8)  # [R, C + 2]
    for row in np.nonzero(padded.any(axis=1))[0]:
        edges = np.diff(padded[row])  # +1 where a run starts, -1 one past its end
        runs += [(int(row), int(a), int(b)) for a, b in zip(np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0],
                                                             strict=True)]
    return runs


def _hidden_boxes(hidden: np.ndarray | None, grid: GridSpec) -> list[Rectangle]:
    """One rectangle per row run of the cells of ``hidden`` [R, C], in the data coordinates of a
    BEV panel drawn with :func:`_bev_extent` (none when ``hidden`` is None)."""
    if hidden is None:
        return []
    res = grid.resolution
    return [Rectangle((grid.y_max - c0 * res, grid.x_max - (r + 1) * res), -(c1 - c0) * res, res)
            for r, c0, c1 in mask_runs(hidden)]


def _hatch(ax: Any, boxes: list[Rectangle]) -> None:
    """Hatch ``boxes`` (:func:`_hidden_boxes`) on a BEV panel."""
    if boxes:
        ax.add_collection(PatchCollection(boxes, facecolor="none", edgecolor="black", hatch=_HIDDEN_HATCH,
                                          linewidth=0.0, gid="hidden"))


def _confidently_wrong(frame: FrameView) -> np.ndarray | None:
    """[R, C] bool: cells whose residual exceeds both 3 sigma and the interface's 1 cm."""
    if frame.truth is None or frame.sigma is None:
        return None
    with np.errstate(invalid="ignore"):
        error = np.abs(frame.truth - frame.estimate)
        return np.asarray((error > 3.0 * frame.sigma) & (error > CONFIDENT_WRONG_CM / 100.0), bool)


def _sigma_limit_cm(sigmas: Sequence[np.ndarray]) -> float:
    """Upper end of the sigma colour range (cm): 99th percentile of the sigmas, at least 0.5 cm."""
    values = np.concatenate([s[np.isfinite(s)].ravel() for s in sigmas] or [np.zeros(1)])
    if values.size == 0:
        return 0.5
    return float(max(np.percentile(values * 100.0, 99.0), 0.5))


def plot_frames(frames: Sequence[FrameView], grid: GridSpec, path: str | Path) -> Path:
    """The paper's Fig. 7: image with ROI | GT | estimate | residual (GT - estimate), in cm.

    GT and estimate share one colour bar; residuals share another; both span all rows. When any
    frame has a sigma a fourth map shows it (its own colour bar) and the residual marks the
    confidently wrong cells with black dots: what a controller trusting sigma would get wrong.
    Cells the ground truth hides from the cameras (:attr:`FrameView.hidden`) are hatched on every
    map, so that an error there reads as occlusion, not as the estimator's fault. Axes are
    placed in inches so that every panel keeps its true aspect without wasted space.
    """
    if not frames:
        raise ReportError("no frames to draw")
    for frame in frames:
        for name, arr in (("estimate", frame.estimate), ("sigma", frame.sigma), ("hidden", frame.hidden)):
            if arr is not None and arr.shape != grid.shape:
                raise ReportError(f"frame {frame.index}: {name} {arr.shape} is not the grid {grid.shape}")
    truths = [f.truth for f in frames if f.truth is not None]
    residuals = [f.truth - f.estimate for f in frames if f.truth is not None]
    sigmas = [f.sigma for f in frames if f.sigma is not None]
    lo, hi = _elevation_limits_cm(truths or [f.estimate for f in frames])
    rlim = _residual_limit_cm(residuals)
    slim = _sigma_limit_cm(sigmas)
    n_maps = 4 if sigmas else 3
    cam = frames[0].camera
    h = 3.0  # height of every panel (in)
    w_img = h * cam.width / cam.height
    w_map = h * grid.length_y / grid.length_x
    margin, gap_img, gap_map, title_h, ticks_h, bar_h, bar_label_h = 0.15, 0.75, 0.35, 0.5, 0.5, 0.14, 0.75
    fig_w = margin + w_img + gap_img + n_maps * w_map + (n_maps - 1) * gap_map + 0.45
    row_h = title_h + h + ticks_h
    fig_h = 0.6 + row_h * len(frames) + bar_h + bar_label_h
    fig = Figure(figsize=(fig_w, fig_h), dpi=_DPI)

    def axes_at(left_in: float, bottom_in: float, width_in: float, height_in: float) -> Axes:
        return fig.add_axes((left_in / fig_w, bottom_in / fig_h, width_in / fig_w, height_in / fig_h))

    extent = _bev_extent(grid)
    elev_cmap, res_cmap, sigma_cmap = _cmap(_ELEVATION_CMAP), _cmap(_RESIDUAL_CMAP), _cmap(_SIGMA_CMAP)
    map_left = [margin + w_img + gap_img + k * (w_map + gap_map) for k in range(n_maps)]
    yy, xx = np.meshgrid(grid.y_centres(), grid.x_centres())  # [R, C] cell centres
    wrongs = [_confidently_wrong(f) for f in frames]  # [R, C] bool each, or None
    images: dict[str, AxesImage] = {}
    for i, frame in enumerate(frames):
        bottom = fig_h - 0.6 - (i + 1) * row_h + ticks_h
        _draw_roi(axes_at(margin, bottom, w_img, h), frame, grid)
        residual = None if frame.truth is None else frame.truth - frame.estimate
        panels: list[tuple[str, str, np.ndarray | None, mcolors.Colormap, float, float]] = [
            ("elevation", "ground truth", frame.truth, elev_cmap, lo, hi),
            ("elevation", "estimate", frame.estimate, elev_cmap, lo, hi),
            ("residual", "residual GT - est.", residual, res_cmap, -rlim, rlim),
        ]
        if n_maps == 4:
            panels.append(("sigma", "1-sigma", frame.sigma, sigma_cmap, 0.0, slim))
        wrong = wrongs[i]
        boxes = _hidden_boxes(frame.hidden, grid)  # the same boxes hatch every map of the row
        for j, (scale, title, arr, cmap, vmin, vmax) in enumerate(panels):
            ax = axes_at(map_left[j], bottom, w_map, h)
            shown = np.full(grid.shape, np.nan) if arr is None else arr * 100.0
            images[scale] = ax.imshow(shown, cmap=cmap, vmin=vmin, vmax=vmax, extent=extent,
                                      interpolation="nearest", origin="upper", aspect="equal")
            _hatch(ax, boxes)
            if arr is None:
                title = f"{title}: none"
            elif scale == "elevation" and j == 0 and frame.hidden is not None:
                title = f"{title}\n{int(frame.hidden.sum())} cells hidden"
            elif scale == "residual" and wrong is not None:
                ax.scatter(yy[wrong], xx[wrong], s=3, c="black", linewidths=0, gid="confidently_wrong")
                title = f"{title}\n{int(wrong.sum())} confidently wrong"
            ax.set_xlim(extent[0], extent[1])
            ax.set_ylim(extent[2], extent[3])
            ax.set_title(title, fontsize=9)
            _style_bev_axes(ax, grid, first=(j == 0), last_row=True)
    bars = [("elevation", "elevation (cm), GT and estimate", map_left[0], 2 * w_map + gap_map),
            ("residual", "residual (cm)", map_left[2], w_map)]
    if n_maps == 4:
        bars.append(("sigma", "1-sigma (cm)", map_left[3], w_map))
    for scale, label, left_in, width_in in bars:
        cbar = fig.colorbar(images[scale], cax=axes_at(left_in, bar_label_h, width_in, bar_h), orientation="horizontal")
        cbar.set_label(label, fontsize=8)
        cbar.ax.tick_params(labelsize=7)
    legend = ("Red: ROI at z = 0; orange: voxel range z_min (dotted) .. z_max (dashed); cyan: wheel tracks. "
              "Grey cells: no label / no estimate.")
    if any(f.hidden is not None for f in frames):
        legend += " Hatched: hidden from the cameras by the road in front (ground truth's lines of sight)."
    if any(w is not None for w in wrongs):
        legend += "\nBlack dots on the residual: confidently wrong, |GT - est.| > 3 sigma and > 1 cm."
    fig.text(margin / fig_w, 1.0 - 0.12 / fig_h, legend, fontsize=8, va="top")
    out = Path(path)
    fig.savefig(out)
    return out


def plot_surface(frame: FrameView, grid: GridSpec, path: str | Path) -> Path:
    """3D surface of one estimate (true horizontal aspect, elevation exaggerated and labelled)."""
    est_cm = frame.estimate.astype(np.float64) * 100.0
    if not np.isfinite(est_cm).any():
        raise ReportError(f"frame {frame.index}: the estimate is empty, nothing to render")
    yy, xx = np.meshgrid(grid.y_centres(), grid.x_centres())  # [R, C]
    lo, hi = _elevation_limits_cm([frame.truth if frame.truth is not None else frame.estimate])
    fig = Figure(figsize=(8.0, 6.0), dpi=_DPI)
    ax = cast("Axes3D", fig.add_axes((0.0, 0.02, 0.84, 0.9), projection="3d"))  # mplot3d: untyped
    surf = ax.plot_surface(
        yy, xx, np.ma.masked_invalid(est_cm), cmap=_cmap(_ELEVATION_CMAP), vmin=lo, vmax=hi,
        rstride=1, cstride=1, linewidth=0, antialiased=False,
    )
    z_span = max(hi - lo, 2.0)
    z_box = 0.5 * grid.length_y  # the elevation axis gets half the width
    exaggeration = z_box / (z_span / 100.0)
    ax.set_box_aspect((grid.length_y, grid.length_x, z_box), zoom=1.0)
    ax.set_xlim(grid.y_max, grid.y_min)  # left on the left when seen from behind the car
    ax.set_ylim(grid.x_min, grid.x_max)
    ax.set_zlim(lo, hi)
    ax.set_xticks([1.0, 0.5, 0.0, -0.5])
    ax.zaxis.set_major_locator(matplotlib.ticker.MaxNLocator(4))
    ax.view_init(elev=32, azim=-118)
    ax.set_xlabel("lateral y (m, + left)", fontsize=8, labelpad=6)
    ax.set_ylabel("distance ahead x (m)", fontsize=8, labelpad=8)
    ax.set_zlabel("elevation (cm)", fontsize=8, labelpad=4)
    ax.tick_params(labelsize=7)
    cbar = fig.colorbar(surf, cax=fig.add_axes((0.87, 0.25, 0.025, 0.5)))
    cbar.set_label("elevation (cm)", fontsize=8)
    cbar.ax.tick_params(labelsize=7)
    fig.suptitle(f"Estimated road surface, frame {frame.index} "
                 f"(elevation exaggerated about {exaggeration:.0f}x)", fontsize=10, y=0.97)
    out = Path(path)
    fig.savefig(out)
    return out


def _shade_hidden(ax: Any, track: TrackProfile) -> int:
    """Grey spans over the samples of ``track`` that the road in front hides from the cameras
    (half a sample spacing either side); returns how many spans."""
    if track.hidden is None or not track.hidden.any():
        return 0
    d = np.asarray(track.distance_m, np.float64)
    half = 0.5 * float(np.median(np.abs(np.diff(d)))) if d.size > 1 else 0.0
    runs = mask_runs(np.asarray(track.hidden, bool)[None])
    for k, (_, first, stop) in enumerate(runs):
        lo, hi = sorted((d[first], d[stop - 1]))
        ax.axvspan(lo - half, hi + half, color="0.6", alpha=0.35, lw=0, gid="hidden",
                   label=_HIDDEN_LABEL if k == 0 else None)
    return len(runs)


def plot_preview(frames: Sequence[FrameView], path: str | Path) -> Path:
    """Left and right wheel-track profiles (estimate with 1-sigma band) against ground truth;
    grey spans: where the road in front hides the track from the cameras (ground truth)."""
    rows = [f for f in frames if f.tracks or f.truth_tracks]
    if not rows:
        raise ReportError("no wheel-track profiles to draw")
    names: list[str] = []
    for f in rows:
        for t in (*f.tracks, *f.truth_tracks):
            if t.name not in names:
                names.append(t.name)
    fig, axes = new_figure(len(rows), len(names), figsize=(5.0 * len(names), 2.6 * len(rows) + 0.6),
                             dpi=_DPI, squeeze=False, sharex=True, sharey=True)
    shaded = 0
    for i, frame in enumerate(rows):
        est = {t.name: t for t in frame.tracks}
        gt = {t.name: t for t in frame.truth_tracks}
        for j, name in enumerate(names):
            ax = axes[i, j]
            if name in gt:
                t = gt[name]
                ax.plot(t.distance_m, t.elevation_m * 100.0, color="black", lw=1.4, label="ground truth")
                shaded += _shade_hidden(ax, t)
            if name in est:
                t = est[name]
                ax.plot(t.distance_m, t.elevation_m * 100.0, color="tab:red", lw=1.2,
                        label="estimate (/roadbev/preview)")
                if t.sigma_m is not None and np.isfinite(t.sigma_m).any():
                    ax.fill_between(t.distance_m, (t.elevation_m - t.sigma_m) * 100.0,
                                    (t.elevation_m + t.sigma_m) * 100.0, color="tab:red", alpha=0.2,
                                    lw=0, label="estimate ±1σ")
            track = est.get(name) or gt.get(name)  # None: this frame lacks a track another one has
            offset = "" if track is None else f" (y = {track.lateral_offset_m:+.2f} m)"
            ax.set_title(f"frame {frame.index}: {name} wheel track{offset}", fontsize=9)
            ax.grid(True, alpha=0.3)
            ax.tick_params(labelsize=7)
            ax.set_ylabel("elevation (cm)", fontsize=8)
            if i == len(rows) - 1:
                ax.set_xlabel("distance ahead x (m)", fontsize=8)
    # one legend, on the first panel; the hidden spans' entry even when that panel has none
    handles, labels = axes[0, 0].get_legend_handles_labels()
    if shaded and _HIDDEN_LABEL not in labels:
        handles.append(Patch(color="0.6", alpha=0.35, lw=0))
        labels.append(_HIDDEN_LABEL)
    axes[0, 0].legend(handles, labels, fontsize=7, loc="best")
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out)
    return out


def plot_band_error(runs: Sequence[RunSummary], grid: GridSpec, path: str | Path) -> Path:
    """Mean absolute error per distance band (15 bands, near to far), one line per run."""
    if not runs:
        raise ReportError("no runs to draw")
    fig, ax = new_figure(figsize=(7.0, 3.6), dpi=_DPI)
    markers = "osd^v<>"
    for k, run in enumerate(runs):
        bands = np.asarray(run.metrics.get("band_abs_err_cm", []), dtype=np.float64)
        if bands.size == 0:
            continue
        centres = band_centres_m(grid, bands.size)
        # earlier runs get larger hollow markers so that coinciding runs stay visible
        ax.plot(centres, bands, marker=markers[k % len(markers)], ms=max(9 - 3 * k, 4), mfc="none",
                mew=1.2, lw=1.3, ls="-" if k % 2 == 0 else "--", label=run.label)
    ax.set_xlabel("distance ahead x (m), band centre", fontsize=9)
    ax.set_ylabel("mean absolute error (cm)", fontsize=9)
    ax.set_title(f"Error against distance ({len(band_centres_m(grid))} bands of "
                 f"{grid.length_x / 15:.2f} m)", fontsize=10)
    ax.set_ylim(bottom=0.0)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out)
    return out


def plot_timing(timing: TimingTrace, path: str | Path) -> Path:
    """Latency per output and output rate over time (two panels)."""
    if timing.receive_s.size == 0:
        raise ReportError("no outputs were received: nothing to time")
    fig, (ax_l, ax_r) = new_figure(2, 1, figsize=(7.0, 5.0), dpi=_DPI, sharex=True)
    ax_l.plot(timing.receive_s, timing.latency_ms, marker="o", ms=3, lw=1.0, color="tab:blue")
    med = float(np.median(timing.latency_ms))
    ax_l.axhline(med, color="tab:blue", ls=":", lw=1.0, label=f"median {med:.0f} ms")
    ax_l.set_ylabel("latency (ms)", fontsize=9)
    ax_l.set_ylim(0.0, 1.2 * float(np.nanmax(timing.latency_ms)) + 1.0)
    ax_l.set_title("Latency: input image published -> /roadbev/elevation received", fontsize=10)
    ax_l.legend(fontsize=8)
    ax_l.grid(True, alpha=0.3)
    if timing.receive_s.size >= 2:
        dt = np.diff(timing.receive_s)
        rate = 1.0 / np.maximum(dt, 1e-6)
        ax_r.plot(timing.receive_s[1:], rate, marker="o", ms=3, lw=1.0, color="tab:green",
                  label="1 / interval between outputs")
        span = timing.receive_s[-1] - timing.receive_s[0]
        mean_rate = (timing.receive_s.size - 1) / span if span > 0 else float("nan")
        ax_r.axhline(mean_rate, color="tab:green", ls=":", lw=1.0, label=f"mean {mean_rate:.1f} Hz")
        ax_r.legend(fontsize=8, loc="lower right")
        ax_r.set_ylim(0.0, 1.25 * float(np.nanmax(rate)))
    ax_r.set_ylabel("output rate (Hz)", fontsize=9)
    ax_r.set_xlabel("time since the first input was published (s)", fontsize=9)
    ax_r.set_title("Output rate (lockstep: each image is sent when the previous answer arrived)", fontsize=10)
    ax_r.grid(True, alpha=0.3)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out)
    return out


# --------------------------------------------------------------------------------------------
# HTML + JSON
# --------------------------------------------------------------------------------------------
_TABLE_KEYS: tuple[tuple[str, str, str], ...] = (
    ("frames", "frames", "{:d}"),
    ("cells", "cells compared", "{:d}"),
    ("abs_err_cm", "abs. error (cm)", "{:.3f}"),
    ("rmse_cm", "RMSE (cm)", "{:.3f}"),
    ("gt_0p5cm_pct", "> 0.5 cm (%)", "{:.1f}"),
    ("coverage_pct", "coverage (%)", "{:.1f}"),
    ("within_2sigma_pct", "within 2σ (%)", "{:.1f}"),
    ("confident_wrong_pct", "confidently wrong (%)", "{:.2f}"),
    ("mean_sigma_cm", "mean σ (cm)", "{:.3f}"),
    ("fps", "rate (Hz)", "{:.2f}"),
    ("latency_ms_median", "latency median (ms)", "{:.0f}"),
)


def _metrics_table(runs: Sequence[RunSummary]) -> str:
    head = "".join(f"<th>{html.escape(t)}</th>" for _, t, _ in _TABLE_KEYS)
    rows = []
    for run in runs:
        cells = "".join(f"<td>{format_cell(run.metrics.get(k), p)}</td>" for k, _, p in _TABLE_KEYS)
        rows.append(f"<tr><th>{html.escape(run.label)}</th>{cells}</tr>")
    return f"<table><tr><th>run</th>{head}</tr>{''.join(rows)}</table>"


_CAPTIONS: dict[str, str] = {
    "frames.png": "Left image with the ROI (the grid's footprint on the z = 0 plane, red; the voxel "
    "range z_min..z_max, orange; the wheel tracks, cyan), ground truth, estimate and residual "
    "(GT - estimate) in cm, as in the paper's Fig. 7, and the recorded 1-sigma. Black dots on the "
    "residual: confidently wrong cells (error beyond 3 sigma and 1 cm). Hatched: cells the ground "
    "truth hides from the cameras (behind a crest), which no estimator can see. Maps are drawn with "
    "true aspect, near at the bottom, left on the left.",
    "surface.png": "3D surface of the estimate (horizontal axes to scale, elevation exaggerated).",
    "preview.png": "Wheel-track preview profiles as published on /roadbev/preview (with their 1-sigma "
    "band) against the same profiles computed from the ground truth (roadbev_core.preview). Grey "
    "spans: stretches of the track that the road in front (the ground truth) hides from the cameras.",
    "band_error.png": "Mean absolute error in 15 distance bands along x, near to far (paper Fig. 9).",
    "reliability.png": "Reliability of the reported sigma: per bin of predicted 1-sigma, the 68.3 % "
    "quantile of the observed |error| (solid) and half its 95.4 % quantile (dashed), against the "
    "bin's mean sigma. An honest sigma lies on the grey diagonal; points above it are over-confident. "
    f"Bins with fewer than {RELIABILITY_MIN_CELLS} cells are left out.",
    "timing.png": "Latency (input image published by the replay until its elevation map was "
    "received by the recorder) and output rate over time.",
}


def _html_page(data: ReportData, figures: list[str], drive_figures: Sequence[str] = ()) -> str:
    settings = "".join(
        f"<tr><th>{html.escape(str(k))}</th><td>{html.escape(str(v))}</td></tr>" for k, v in data.settings.items()
    )
    stages = "".join(
        f"<tr><th>{html.escape(k)}</th><td>{v:.1f} s</td></tr>" for k, v in data.stage_seconds.items()
    )
    notes = "".join(f"<li>{html.escape(n)}</li>" for n in data.notes)
    figs = "".join(
        f'<figure><img src="{html.escape(name)}" alt="{html.escape(name)}">'
        f"<figcaption>{html.escape(_CAPTIONS.get(name, name))}</figcaption></figure>"
        for name in figures
    )
    drive = ""
    if data.drive is not None:

        drive = drive_html(data.drive, drive_figures)
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(data.title)}</title>
<style>
body {{ font-family: sans-serif; margin: 1.5em auto; max-width: 1400px; color: #222; }}
table {{ border-collapse: collapse; margin: 0.5em 0 1em; }}
th, td {{ border: 1px solid #bbb; padding: 0.25em 0.6em; text-align: right; font-size: 0.9em; }}
th {{ background: #f0f0f0; text-align: left; }}
figure {{ margin: 1.2em 0; }} img {{ max-width: 100%; border: 1px solid #ddd; }}
figcaption {{ font-size: 0.9em; color: #444; }}
</style></head><body>
<h1>{html.escape(data.title)}</h1>
<h2>Metrics</h2>
{_metrics_table(data.runs)}
<ul>{notes}</ul>
<h2>Figures</h2>
{figs}
{drive}<h2>Settings</h2><table>{settings}</table>
<h2>Stage times</h2><table>{stages}</table>
<p>Numbers: <a href="report.json">report.json</a>.</p>
</body></html>
"""


def write_report(
    data: ReportData, out_dir: str | Path, *, progress: Callable[[str], Any] | None = None
) -> dict[str, Path]:
    """Draw every figure the data allows and write ``index.html`` and ``report.json``.

    Args:
        data: what to show.
        out_dir: the report folder (created).
        progress: called with each file's name before it is drawn.

    Returns:
        File name -> path of everything written.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if not data.frames:
        raise ReportError("the report needs at least one frame")
    written: dict[str, Path] = {}
    tell = progress or (lambda name: None)
    tell("frames.png")
    written["frames.png"] = plot_frames(data.frames, data.grid, out / "frames.png")
    # The 3D render shows a frame with much relief in its ground truth and few holes in its
    # estimate (a hole-riddled surface reads badly in 3D): relief (cm) x coverage^3.
    def render_score(f: FrameView) -> float:
        coverage = float(np.isfinite(f.estimate).mean())
        if f.truth is None or not np.isfinite(f.truth).any():
            return coverage
        lo, hi = np.nanpercentile(f.truth, [0.5, 99.5])
        return float(hi - lo) * 100.0 * coverage**3

    render = max(data.frames, key=render_score)
    tell("surface.png")
    written["surface.png"] = plot_surface(render, data.grid, out / "surface.png")
    if any(f.tracks or f.truth_tracks for f in data.frames):
        tell("preview.png")
        written["preview.png"] = plot_preview(data.frames, out / "preview.png")
    def scored(run: RunSummary) -> bool:  # a bag without ground truth has no error to draw
        return any(b is not None and math.isfinite(b) for b in run.metrics.get("band_abs_err_cm", []))

    if any(scored(r) for r in data.runs):
        tell("band_error.png")
        written["band_error.png"] = plot_band_error(data.runs, data.grid, out / "band_error.png")
    curves = [(r.label, r.metrics.get("reliability") or []) for r in data.runs]
    if any(curve for _, curve in curves):
        tell("reliability.png")
        try:
            written["reliability.png"] = reliability_figure(curves, out / "reliability.png",
                                                            "Reliability of the reported sigma")
        except FigureError as exc:  # every bin under the cell count: say so on the page
            data = replace(data, notes=[*data.notes, f"No reliability plot: {exc}."])
    if data.timing is not None and data.timing.receive_s.size:
        tell("timing.png")
        written["timing.png"] = plot_timing(data.timing, out / "timing.png")
    figures = [name for name in FIGURE_NAMES if name in written]
    drive_figures: list[str] = []
    if data.drive is not None:

        drawn = write_drive_figures(data.drive, out, tell)
        written.update(drawn)
        drive_figures = list(drawn)
    payload = {
        "title": data.title,
        "runs": [{"label": r.label, "backend": r.backend, "mode": r.mode, "metrics": r.metrics} for r in data.runs],
        "notes": data.notes,
        "settings": data.settings,
        "stage_seconds": data.stage_seconds,
        "grid": data.grid.to_dict(),
        "frames_shown": [f.index for f in data.frames],
        "figures": figures + drive_figures,
    }
    if data.drive is not None:
        payload["drive"] = data.drive.to_json()
    if data.timing is not None:
        payload["timing"] = {
            "stamp_s": data.timing.stamp_s, "latency_ms": data.timing.latency_ms, "receive_s": data.timing.receive_s,
        }
    json_path = out / "report.json"
    json_path.write_text(to_json(payload))
    written["report.json"] = json_path
    html_path = out / "index.html"
    html_path.write_text(_html_page(data, figures, drive_figures))
    written["index.html"] = html_path
    return written
