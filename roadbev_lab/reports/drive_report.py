"""The demo report's drive section: figures and HTML of a :class:`roadbev_lab.demo.drive.DriveSection`.

* ``drive_map.png``: the fused map over the drive (elevation, uncertainty, observations; every
  cell as the map last held it) with the true path of ``base_link`` and of the front wheels;
* ``drive_hazards.png``: the road's height above its own level (the hazard detector's residual)
  on the fused map and on the true road, the detections (boxes) and the true features (markers);
* ``drive_arrival.png``: per front wheel, the road height each preview promised where the wheel
  arrived (map on, map off) against the true road, and their errors, feature points shaded;
* ``drive_ride.png``: the quarter-car ride (ISO 2631-1 Wk-weighted RMS body acceleration, peak
  suspension travel, RMS dynamic tyre load) per preview source.

Maps are drawn in ``odom`` with x (the direction of the drive) to the right and y (left) up, at
true aspect. Pure plotting over arrays (matplotlib, Agg via :func:`roadbev_lab.reports.figures.new_figure`).
"""

from __future__ import annotations

import html
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, cast

import matplotlib
import numpy as np
from matplotlib import patches

from roadbev_core.hazards import detect_hazards, road_residual
from roadbev_lab.demo.drive import RIDE_ROWS, DriveSection, MapMosaic
from roadbev_lab.reports.figures import new_figure

__all__ = [
    "DRIVE_CAPTIONS",
    "DRIVE_FIGURE_NAMES",
    "drive_html",
    "format_cell",
    "plot_drive_arrival",
    "plot_drive_hazards",
    "plot_drive_map",
    "plot_drive_ride",
    "write_drive_figures",
]

DRIVE_FIGURE_NAMES: tuple[str, ...] = ("drive_map.png", "drive_hazards.png", "drive_arrival.png", "drive_ride.png")
_DPI = 110
_NO_DATA = "#d9d9d9"
_ON, _OFF, _TRUE = "tab:red", "tab:blue", "black"


def format_cell(value: Any, pattern: str) -> str:
    """A table cell: ``value`` formatted with ``pattern``, "–" for a missing or non-finite value."""
    if value is None:
        return "–"
    if isinstance(value, float) and not math.isfinite(value):
        return "–"
    try:
        return pattern.format(int(value) if pattern == "{:d}" else float(value))
    except (TypeError, ValueError):
        return html.escape(str(value))


def _top_down(layer: np.ndarray) -> np.ndarray:
    """A grid_map-order layer [R, C] (row 0 at the largest x, column 0 at the largest y) as an
    image with x to the right and y up: [C, R]."""
    return cast("np.ndarray", np.asarray(layer).T[:, ::-1])


def _map_axes(ax: Any, m: MapMosaic, layer: np.ndarray, title: str, cmap: str, unit: str,
              vmin: float | None = None, vmax: float | None = None) -> Any:

    x0, x1, y0, y1 = m.extent()
    cm = matplotlib.colormaps[cmap].with_extremes(bad=_NO_DATA)
    im = ax.imshow(_top_down(layer), extent=(x0, x1, y0, y1), origin="upper", cmap=cm, vmin=vmin, vmax=vmax,
                   interpolation="nearest", aspect="equal")
    ax.set_title(title, fontsize=9)
    ax.tick_params(labelsize=7)
    ax.set_ylabel("y (m)", fontsize=8)
    bar = ax.figure.colorbar(im, ax=ax, fraction=0.02, pad=0.01)
    bar.set_label(unit, fontsize=7)
    bar.ax.tick_params(labelsize=7)
    return im


def _paths(ax: Any, section: DriveSection) -> None:
    ax.plot(section.path_xy[:, 0], section.path_xy[:, 1], color="white", lw=1.2, ls="--", label="base_link (true)")
    for points in section.points_on:
        ax.plot(points.path.xy[:, 0], points.path.xy[:, 1], color="black", lw=0.8, alpha=0.8)
    x0, x1, y0, y1 = section.fused.extent()
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)


def plot_drive_map(section: DriveSection, path: str | Path) -> Path:
    """Elevation, uncertainty and observations of the fused map over the drive, with the paths."""
    m = section.fused
    x0, x1, y0, y1 = m.extent()
    width = 13.0
    panel_h = max(1.2, width * (y1 - y0) / max(x1 - x0, 1e-6)) + 0.5
    fig, axes = new_figure(3, 1, figsize=(width, 3 * panel_h + 0.6), dpi=_DPI, sharex=True)
    elev = m.elevation * 100.0
    lo, hi = (np.nanpercentile(elev, [1, 99]) if np.isfinite(elev).any() else (0.0, 1.0))
    _map_axes(axes[0], m, elev, "fused map: elevation in odom (/roadbev/map, layer elevation)", "turbo", "cm",
              float(lo), float(hi))
    _map_axes(axes[1], m, m.uncertainty * 100.0, "uncertainty (1-sigma)", "viridis", "cm", 0.0,
              float(np.nanpercentile(m.uncertainty * 100.0, 99)) if np.isfinite(m.uncertainty).any() else 1.0)
    _map_axes(axes[2], m, m.observations, "observations (frames fused per cell)", "magma", "count", 0.0, None)
    for ax in axes:
        _paths(ax, section)
    axes[0].legend(fontsize=7, loc="upper right")
    axes[-1].set_xlabel("x in odom (m): the drive runs left to right; black: the front wheels' true paths", fontsize=8)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out)
    return out


def _hazard_marks(ax: Any, section: DriveSection, detections: Sequence[Any]) -> None:
    for h in detections:
        colour = "tab:red" if h.kind == "bump" else "tab:blue"
        ax.add_patch(patches.Rectangle((h.x - 0.5 * h.length_m, h.y - 0.5 * h.width_m), h.length_m, h.width_m,
                                       fill=False, ec=colour, lw=1.3))
        ax.annotate(f"{h.height_m * 100:+.1f}", (h.x, h.y + 0.5 * h.width_m), fontsize=6, color=colour,
                    ha="center", va="bottom")
    for f in section.reference:
        marker = "^" if f.height_m > 0 else "v"
        ax.plot([f.x], [f.y], marker=marker, ms=7, mfc="none", mec="black", mew=1.2, ls="none")


def plot_drive_hazards(section: DriveSection, path: str | Path) -> Path:
    """The residual (height above the road's own level) of the fused map and of the true road
    over the same cells, detections as boxes (red bumps, blue potholes, height in cm), the
    reference features as triangles (up: bump, down: pothole)."""

    m = section.fused
    xs, ys = m.cell_centres()
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    true_z = section.truth.height(gx, gy).astype(np.float32)
    true_z[~np.isfinite(m.elevation)] = np.nan
    fused_res, _ = road_residual(m.elevation, m.resolution)
    true_res, _ = road_residual(true_z, m.resolution)
    true_found = detect_hazards(true_z, None, m.resolution, m.centre)
    x0, x1, y0, y1 = m.extent()
    width = 13.0
    panel_h = max(1.2, width * (y1 - y0) / max(x1 - x0, 1e-6)) + 0.5
    fig, axes = new_figure(2, 1, figsize=(width, 2 * panel_h + 0.8), dpi=_DPI, sharex=True)
    lim = 6.0
    _map_axes(axes[0], m, fused_res * 100.0, f"fused map: height above the road's level, {len(section.hazards)} "
              "hazard(s) detected (roadbev_core.hazards)", "RdBu_r", "cm", -lim, lim)
    _hazard_marks(axes[0], section, section.hazards)
    _map_axes(axes[1], m, true_res * 100.0, f"true road over the same cells, {len(true_found)} hazard(s) detected "
              "on it", "RdBu_r", "cm", -lim, lim)
    _hazard_marks(axes[1], section, true_found)
    for ax in axes:
        _paths(ax, section)
    axes[-1].set_xlabel(f"x in odom (m); triangles: features {section.reference_kind} (up: bump, down: pothole)",
                        fontsize=8)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out)
    return out


def plot_drive_arrival(section: DriveSection, path: str | Path) -> Path:
    """Per front wheel: the previews' road height at arrival (map on, map off) against the true
    road, and the errors, feature points shaded."""
    wheels = [p.path.name for p in section.points_on]
    off = {p.path.name: p for p in section.points_off}
    fig, axes = new_figure(2 * len(wheels), 1, figsize=(12.0, 2.4 * 2 * len(wheels) + 0.4), dpi=_DPI, sharex=True,
                           gridspec_kw={"height_ratios": [1.4, 1.0] * len(wheels)})
    lead = section.map_on["preview_at_arrival"]["lead_time_s"]
    for k, name in enumerate(wheels):
        on_p, off_p = section.points_on[k], off.get(name)
        ax_h, ax_e = axes[2 * k], axes[2 * k + 1]
        s = on_p.along_m
        feature = on_p.path.feature
        for ax in (ax_h, ax_e):
            _shade(ax, s, feature)
            ax.grid(True, alpha=0.3)
            ax.tick_params(labelsize=7)
        ax_h.plot(s, on_p.path.height * 100.0, color=_TRUE, lw=1.3, label="true road (tyre footprint)")
        if off_p is not None:
            ax_h.plot(off_p.along_m, off_p.preview_z * 100.0, color=_OFF, lw=1.0, label="per-frame preview (map off)")
            ax_e.plot(off_p.along_m, off_p.error * 100.0, color=_OFF, lw=0.9,
                      label=f"map off: {_mean_abs(off_p.error):.2f} cm mean |error|")
        ax_h.plot(s, on_p.preview_z * 100.0, color=_ON, lw=1.0, label="fused-map preview (map on)")
        ax_e.plot(s, on_p.error * 100.0, color=_ON, lw=0.9,
                  label=f"map on: {_mean_abs(on_p.error):.2f} cm mean |error|")
        ax_e.axhline(0.0, color="black", lw=0.6)
        ax_h.set_title(f"{name} wheel: road height in odom where the wheel arrived, from the latest preview "
                       f"stamped >= {lead:g} s before", fontsize=9)
        ax_h.set_ylabel("height (cm)", fontsize=8)
        ax_e.set_ylabel("error (cm)", fontsize=8)
        ax_h.legend(fontsize=7, loc="upper left", ncol=3)
        ax_e.legend(fontsize=7, loc="upper left", ncol=2)
    axes[-1].set_xlabel("distance along the wheel's true path (m); shaded: feature points "
                        "(docs/interface/evaluation.md)", fontsize=8)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out)
    return out


def _mean_abs(err: np.ndarray) -> float:
    e = np.abs(err[np.isfinite(err)])
    return float(e.mean()) * 100.0 if e.size else math.nan


def _shade(ax: Any, s: np.ndarray, mask: np.ndarray) -> None:
    """Shade runs of ``mask`` along ``s``."""
    if not mask.any():
        return
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        ax.axvspan(s[a], s[b - 1], color="orange", alpha=0.15, lw=0)


def plot_drive_ride(section: DriveSection, path: str | Path) -> Path:
    """Bars per preview source: Wk-weighted RMS body acceleration, peak suspension travel, RMS
    dynamic tyre load (mean of the two front wheels), with each preview's share of the ceiling's gain."""
    rows = section.ride["rows"]
    share = section.ride["share"]
    names = [k for k, _ in RIDE_ROWS if k in rows]
    short = {"passive": "passive", "no_preview": "no\npreview", "per_frame": "per-frame\npreview",
             "fused": "fused-map\npreview", "true_road": "true road\n(ceiling)"}
    labels = [short.get(k, k) for k in names]
    colours = {"passive": "#999999", "no_preview": "#555555", "per_frame": _OFF, "fused": _ON, "true_road": "black"}
    fig, axes = new_figure(1, 3, figsize=(13.0, 3.8), dpi=_DPI)
    panels = (("wk_rms_mps2", "Wk-weighted RMS body acceleration (m/s²)", 1.0),
              ("peak_travel_m", "peak suspension travel (cm)", 100.0),
              ("tyre_load_rms_ratio", "RMS dynamic tyre load (% of static)", 100.0))
    for ax, (key, title, scale) in zip(axes, panels, strict=True):
        values = [rows[k]["mean"][key] * scale for k in names]
        bars = ax.bar(range(len(names)), values, color=[colours[k] for k in names])
        ax.set_xticks(range(len(names)), labels, fontsize=7)
        ax.set_title(title, fontsize=9)
        ax.tick_params(axis="y", labelsize=7)
        ax.grid(True, axis="y", alpha=0.3)
        if key == "wk_rms_mps2":
            for k, bar in zip(names, bars, strict=True):
                if k in share and share[k] is not None and math.isfinite(share[k]):
                    ax.annotate(f"{share[k]:.2f} of gain", (bar.get_x() + bar.get_width() / 2, bar.get_height()),
                                ha="center", va="bottom", fontsize=7)
    warm, scored = section.ride_span_s
    fig.suptitle(f"Quarter car with the preview LQR over the drive's true road (both front wheels, {scored:.1f} s "
                 f"scored after {warm:.1f} s warm-up, {section.map_on['preview_at_arrival']['lead_time_s']:g} s "
                 "latency)", fontsize=9)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out)
    return out


def write_drive_figures(section: DriveSection, out_dir: Path, tell: Callable[[str], Any]) -> dict[str, Path]:
    """Every drive figure into ``out_dir``."""
    written: dict[str, Path] = {}
    for name, draw in zip(DRIVE_FIGURE_NAMES, (plot_drive_map, plot_drive_hazards, plot_drive_arrival,
                                               plot_drive_ride), strict=True):
        tell(name)
        written[name] = draw(section, out_dir / name)
    return written


DRIVE_CAPTIONS: dict[str, str] = {
    "drive_map.png": "The fused map over the drive (roadbev eval --map on the drive bag): each cell as /roadbev/map "
    "last held it before it fell behind the car; grey: never seen. White dashed: the true path of base_link; black: "
    "the front wheels' true paths.",
    "drive_hazards.png": "Hazards: the road's height above its own level (roadbev_core.hazards) on the fused map "
    "and on the true road over the same cells; boxes: detections (red bumps, blue potholes, height in cm); "
    "triangles: the reference features.",
    "drive_arrival.png": "Preview at arrival (docs/interface/evaluation.md): at every 3 cm of each front wheel's "
    "true path, the road height the latest preview message stamped at least the lead time earlier promised there "
    "(its profile plus the true height of the reference it declares), map on and off, against the true road; below, "
    "the errors the metric averages.",
    "drive_ride.png": "What the preview is worth: the quarter car with the preview LQR (roadbev_core.ride) over the "
    "drive's true road, fed with nothing (passive, no preview), the per-frame previews, the fused map's previews "
    "(their contact plane's attitude undone, as RoadPreview carries it) and the true road (the ceiling).",
}

_ARRIVAL_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("abs_err_cm", "abs. error (cm)", "{:.3f}"),
    ("rmse_cm", "RMSE (cm)", "{:.3f}"),
    ("p95_abs_err_cm", "p95 (cm)", "{:.3f}"),
    ("coverage_pct", "coverage (%)", "{:.1f}"),
    ("features_abs_err_cm", "features (cm)", "{:.3f}"),
    ("smooth_abs_err_cm", "smooth (cm)", "{:.3f}"),
    ("contact_plane_abs_err_cm", "vs contact plane (cm)", "{:.3f}"),
)


def _table(head: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    h = "".join(f"<th>{html.escape(t)}</th>" for t in head)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><tr>{h}</tr>{body}</table>"


def drive_html(section: DriveSection, figures: Sequence[str]) -> str:
    """The drive section of ``index.html``."""
    on, off = section.map_on, section.map_off
    arrival_rows = []
    runs = [("map on (roadbev eval --map)", on), ("map off (roadbev eval --no-map)", off)]
    if section.online is not None and "preview_at_arrival" in section.online:
        runs.insert(0, ("ROS 2 node (recorded outputs of this bag)", section.online))
    for label, m in runs:
        a = m["preview_at_arrival"]
        fused = m.get("map") or {}
        arrival_rows.append([html.escape(label), str(a["points"]),
                             *(format_cell(a.get(k), p) for k, _, p in _ARRIVAL_COLUMNS),
                             format_cell(fused.get("abs_err_cm"), "{:.3f}"),
                             format_cell(fused.get("coverage_pct"), "{:.1f}"),
                             format_cell(m.get("abs_err_cm"), "{:.3f}")])
    arrival = _table(["run", "points", *(t for _, t, _ in _ARRIVAL_COLUMNS), "map abs. error (cm)",
                      "map coverage (%)", "per-frame grid abs. error (cm)"], arrival_rows)
    hazard_rows = []
    for f, d in section.matches:
        hazard_rows.append([html.escape(f.name), f"{f.x:.2f}", f"{f.y:+.2f}", f"{f.height_m * 100:+.1f}",
                            "missed" if d is None else f"{d.kind} at x {d.x:.2f}, y {d.y:+.2f}",
                            "–" if d is None else f"{d.height_m * 100:+.1f} ± {d.height_sigma_m * 100:.1f}",
                            "–" if d is None else f"{d.confidence:.2f}"])
    hazards = _table(["feature", "x (m)", "y (m)", "height (cm)", "detection on the fused map",
                      "height (cm)", "confidence"], hazard_rows)
    found = sum(d is not None for _, d in section.matches)
    false = ", ".join(f"{h.kind} at x {h.x:.2f} ({h.height_m * 100:+.1f} cm)" for h in section.false_alarms) or "none"
    rows = section.ride["rows"]
    share = section.ride["share"]
    ride_rows = [[html.escape(label), f"{rows[k]['mean']['wk_rms_mps2']:.3f}",
                  f"{rows[k]['mean']['peak_travel_m'] * 100:.2f}",
                  f"{rows[k]['mean']['tyre_load_rms_ratio'] * 100:.1f}",
                  f"{rows[k]['mean']['force_rms_n']:.0f}", format_cell(share.get(k), "{:.2f}")]
                 for k, label in RIDE_ROWS if k in rows]
    ride = _table(["source", "Wk RMS (m/s²)", "peak travel (cm)", "tyre load RMS (%)", "force RMS (N)",
                   "share of the ceiling's gain"], ride_rows)
    figs = "".join(f'<figure><img src="{html.escape(n)}" alt="{html.escape(n)}">'
                   f"<figcaption>{html.escape(DRIVE_CAPTIONS.get(n, n))}</figcaption></figure>" for n in figures)
    what = (f"synthetic drive, seed {section.seed}" if section.seed is not None else "the given drive bag") + \
        (" (cached)" if section.reused else "")
    notes = "".join(f"<li>{html.escape(n)}</li>" for n in section.notes)
    warm, scored = section.ride_span_s
    return f"""<h2>Drive: the fused map, the preview at arrival, hazards, the ride</h2>
<p>{html.escape(what)}: {html.escape(str(section.bag))}. The same bag through the code of
<code>roadbev eval --map</code> and <code>--no-map</code> (no DDS); check:
<code>roadbev eval {html.escape(str(section.bag))} --map --json OUT.json</code>.</p>
<h3>Preview at arrival (lead {on['preview_at_arrival']['lead_time_s']:g} s) and the fused map</h3>
{arrival}
<h3>Hazards on the fused map</h3>
<p>{found} of {len(section.matches)} features of at least 3 cm that the map held found (within 0.5 m along x,
potholes also across); reference: features {html.escape(section.reference_kind)}. Detections matching no
feature: {html.escape(false)}.</p>
{hazards}
<h3>The ride (quarter car, preview LQR; {scored:.1f} s scored after {warm:.1f} s warm-up)</h3>
{ride}
<ul>{notes}</ul>
{figs}
"""
