"""What the preview is worth: a preview suspension controller riding drives over bumps, potholes and rough road.

For every road kind, speed and seed a :class:`roadbev_lab.synth.RidingDrive` is built (the car
riding its road, camera at 10 Hz; the 5 Hz camera is every other frame of the same drive) and a
quarter car with the preview LQR of Bender (1968) / Tomizuka (1976)
(:mod:`roadbev_core.ride`) rides the true road under each front wheel, its force computed from
the true state and one preview source (rows):

* ``passive`` (no actuator), ``no_preview`` (the same controller, feedback only);
* ``true_road``: the true road under the wheel over the controller's whole 1 s horizon (the ceiling);
* ``window``: a perfect per-frame camera (the true road cut to the grid's window at each frame's
  stamp, held from stamp + ``--latency``): what the window alone allows;
* ``map_plane``: a perfect fused map's previews (contact-plane reference, from the front tyre
  contact to the window's far edge, one per frame), read without the plane's attitude, and
  ``map_plane_attitude``: the same with the true plane's slopes undone (what the
  contact-plane fields in ``RoadPreview`` are for);
* with ``--far-field``: ``window_far``, ``map_plane_far`` and ``map_plane_attitude_far``, the
  same perfect previews reaching the far-field grid's far edge (``far_field.x_max_m``, 15 m) instead of the grid's: the
  ceiling of a configuration with ``far_field.enabled``; and ``window_visible``, ``window_far_visible``: the perfect
  windows without the road the camera cannot see from where it is (behind a crest or a pothole's rim), bridged as the
  node's preview bridges gaps (:func:`roadbev_lab.ride.perfect_previews` with ``visible_only``): the ceiling of any
  camera at that mount;
* per **candidate** (``--candidates NAME=BACKEND[:PARAM=VALUE,...]``, a configuration of the
  node, :mod:`benchmarks.preview_budget`): its fused-map previews as the node makes them on the
  rendered frames (the drive's own drifting odometry and ``/tf_static`` mount), on the frames its
  measured time per frame lets it fuse, each used from when it is received (its measured
  latency, ``--node-results``: a ``bench_node --drive`` JSON), read with the contact plane each
  message carries (as the reference node does); with ``--budget`` also one row per stage of the
  error budget (``NAME:true_answered``, ...; for a far-field candidate the drives also carry the
  far-field grid's labels, and its label stages put the truth on both grids). Rendered drives
  only: ``--render-seeds`` drives, ``--render-duration`` s long, their frames kept in
  ``--frame-cache`` for the next run.

Each preview row's ``share`` is the share of the ceiling's gain over the no-preview controller
in Wk-weighted RMS body acceleration it delivers (:func:`roadbev_core.ride.gain_share`). Another
preview source is one more entry in :data:`PREVIEW_MAKERS`: a function of (drive, the rendered
frames, the frame step of the camera rate, the ride settings) returning a list of
:class:`roadbev_lab.evaluation.arrival.TimedPreview`.

Run: ``.venv/bin/python -m benchmarks.bench_ride [--duration 20] [--seeds 3] [--speeds 5 10 20]
[--rates 5 10] [--render-seeds 1] [--render-duration 6] [--candidates stereo_int8=stereo:...]
[--budget] [--far-field] [--jobs N | --ray ADDRESS]``; writes ``benchmarks/results/ride.json`` and ``ride.png``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from benchmarks.common import CACHE, RESULTS, add_executor_arguments, executor_from, machine_info, write_json
from benchmarks.preview_budget import (
    STAGE_SEPARATOR,
    Candidate,
    DriveFrames,
    add_candidate_arguments,
    budgeted,
    candidate_previews,
    candidates_from_args,
    far_label_grid,
    make_backend,
    stages_of,
)
from roadbev_core.config import FarFieldConfig, GridSpec

SEED_BASE = 310_000  # disjoint from training, test, tuning (200000+) and the map's tuning drives (300001+)
CAMERA_RATE_HZ = 10.0  # drives are rendered at 10 Hz; slower cameras take every k-th frame
TAIL_S = 1.5  # the drive goes on this long after its last frame (the wheels reach what it saw)
# The longest drive one road strip holds (roadbev_lab.synth.riding: 700 m of rasters, less the
# look-ahead), with room for the drive's speed to wander above its nominal value.
STRIP_DRIVE_M = 560.0
ROAD_KINDS = ("bumps", "potholes", "rough")
# (drive, rendered frames, frame step of the camera rate, ride settings) -> the row's messages
PreviewMaker = Callable[[Any, Sequence[Any], int, Any], list[Any]]
# the preview-at-arrival keys kept per row (against the reference each message declares)
ARRIVAL_SUMMARY = ("abs_err_cm", "features_abs_err_cm", "smooth_abs_err_cm", "coverage_pct",
                   "contact_plane_abs_err_cm", "points", "features_points", "sigma_points", "within_1sigma_pct",
                   "within_2sigma_pct", "confident_wrong_pct", "mean_sigma_cm")

def road_config(kind: str, rng: np.random.Generator) -> Any:
    """The road of one kind: speed bumps and humps on a smooth road (ISO 8608 A), potholes on a
    class B road, or a rough class D road without features; surface, slopes and noise drawn."""
    from dataclasses import replace

    from roadbev_lab.synth import REAL_ROAD_MIDDLE, RoadConfig

    if kind == "bumps":
        road = RoadConfig(road_class="A", features=("speed_bump", "hump"), feature_spacing_m=12.0)
    elif kind == "potholes":
        road = RoadConfig(road_class="B", features=("pothole", "pothole", "patch"), feature_spacing_m=6.0)
    elif kind == "rough":
        road = RoadConfig(road_class="D", features=())
    else:
        raise ValueError(f"unknown road kind {kind!r} (one of {ROAD_KINDS})")
    road = replace(road, surface=str(rng.choice(["asphalt", "concrete"], p=[0.8, 0.2])),
                   cross_slope=float(rng.uniform(-0.02, 0.02)), grade=float(rng.uniform(-0.005, 0.005)),
                   noise_sigma=float(rng.uniform(0.5, 2.0)))
    return REAL_ROAD_MIDDLE.apply(road)  # the pavement and camera of a road built by hand


class CandidateRows:
    """One candidate's rows on a drive: its estimates made once per drive and shared by its stages
    (and by every candidate with the same backend and backend options, and the same pace backend
    with its options where it is paced, through ``shared``)."""

    def __init__(self, candidate: Candidate, shared: dict[tuple[int, str, str], Any]) -> None:
        self.candidate = candidate
        self._shared = shared
        self._key = (candidate.backend, json.dumps(_estimated_by(candidate), sort_keys=True, default=str))

    def maker(self, stage: str) -> PreviewMaker:
        """The row of ``stage`` (:data:`benchmarks.preview_budget.STAGES`)."""

        def make(drive: Any, samples: Sequence[Any], step: int, settings: Any) -> list[Any]:
            key = (id(drive), *self._key)
            if key not in self._shared:
                for old in [k for k in self._shared if k[0] != id(drive)]:  # one drive at a time
                    del self._shared[old]
                self._shared[key] = make_backend(self.candidate, drive.config.grid)
            return candidate_previews(drive, samples, self.candidate, self._shared[key], stage, step=step,
                                      ride_settings=settings)

        return make


def _estimated_by(candidate: Candidate) -> dict[str, Any]:
    """What a candidate's estimates depend on beside its backend: its backend options and, where it
    is paced, its pace backend and that one's options (:func:`benchmarks.preview_budget.make_backend`)."""
    out: dict[str, Any] = {"options": candidate.backend_options()}
    if candidate.pace is not None:
        pace = candidate.pace_candidate()
        out["pace"] = {"backend": pace.backend, "options": pace.backend_options()}
    return out


def candidate_makers(candidates: Sequence[Candidate], budget: Sequence[str] | None,
                     grid: GridSpec) -> dict[str, PreviewMaker]:
    """The rows of one rendered drive on ``grid``: per candidate its fused-map previews as the node
    fuses them (``<name>``), and for the candidates named in ``budget`` (all when it is empty, none
    when None) one row per stage of its error budget (``<name>:<stage>``,
    :func:`benchmarks.preview_budget.stages_of`), plus :data:`PREVIEW_MAKERS`."""
    makers: dict[str, PreviewMaker] = {}
    shared: dict[tuple[int, str, str], Any] = {}
    for candidate in candidates:
        rows = CandidateRows(candidate, shared)
        for stage in stages_of(candidate, grid) if budgeted(candidate.name, budget) else ("shipped",):
            name = candidate.name if stage == "shipped" else f"{candidate.name}{STAGE_SEPARATOR}{stage}"
            makers[name] = rows.maker(stage)
    makers.update({name: factory(name) for name, factory in PREVIEW_MAKERS.items()})
    return makers


def scores(rows: dict[str, dict[str, Any]]) -> dict[str, float]:
    """Share of the ceiling's Wk gain over ``no_preview`` per preview row (needs ``no_preview`` and
    ``true_road``; the other rows but ``passive``)."""
    from roadbev_lab.ride import gain_share

    none, ceiling = rows["no_preview"]["mean"]["wk_rms_mps2"], rows["true_road"]["mean"]["wk_rms_mps2"]
    return {name: gain_share(none, ceiling, row["mean"]["wk_rms_mps2"]) for name, row in rows.items()
            if name not in ("passive", "no_preview")}


def run_cell(kind: str, speed: float, seed: int, duration: float, rates: Sequence[float], lead: float,
             makers: dict[str, PreviewMaker], frame_cache: Any = None, preview_gain: bool = True,
             far_x_max: float | None = None, far_labels: GridSpec | None = None) -> dict[str, Any]:
    """One drive: every source ridden at every camera rate (rendered only when ``makers``; its
    frames from ``frame_cache``, a :class:`benchmarks.preview_budget.DriveFrames`, when given);
    with ``far_x_max`` (m ahead of the camera) also the perfect rows reaching that far; with
    ``far_labels`` the rendered frames also carry that far-field grid's labels (the budget's label
    stages of a far-field candidate, :func:`benchmarks.preview_budget.far_label_grid`)."""
    from roadbev_lab.evaluation.arrival import ArrivalSettings, Trajectory, preview_at_arrival
    from roadbev_lab.ride import (
        RideSettings,
        carried_plane_slopes,
        perfect_map_previews,
        perfect_previews,
        ride,
        true_plane_slopes,
    )
    from roadbev_lab.synth import DriveConfig, RidingConfig, RidingDrive

    rng = np.random.default_rng(seed)
    frames = max(2, int(round(drive_duration(duration, speed) * CAMERA_RATE_HZ)))
    drive = RidingDrive(RidingConfig(drive=DriveConfig(frames=frames, speed_mps=speed, frame_rate_hz=CAMERA_RATE_HZ,
                                                       seed=seed, road=road_config(kind, rng),
                                                       far_grid=far_labels if makers else None), tail_s=TAIL_S))
    gt = drive.ground_truth_poses()
    truth = Trajectory(gt.stamp_ns, gt.position, gt.orientation_xyzw)
    road_map = drive.road_map()
    grid = drive.config.grid
    settings = RideSettings(latency_s=lead, arrival=ArrivalSettings(lead_time_s=lead, base_height=grid.base_height,
                                                                    camera_in_base=drive.base_to_camera),
                            preview_gain=preview_gain)
    stamps = drive.frame_stamps_ns
    start, end = stamps[0], int(truth.stamp_ns[-1])
    score_end = stamps[-1] + int(round(lead * 1e9))  # after the last message arrives the preview runs dry
    start_time = time.perf_counter()
    samples: list[Any] = []
    if makers:
        samples = frame_cache.samples(drive) if frame_cache is not None else list(drive)
    render_s = time.perf_counter() - start_time
    window = perfect_previews(truth, road_map, stamps, grid, settings)
    fused = perfect_map_previews(truth, road_map, stamps, grid, settings)
    perfect: dict[str, list[Any]] = {"window": window, "map_plane": fused, "map_plane_attitude": fused}
    if far_x_max is not None:
        reach = replace(grid, x_max=far_x_max)
        perfect["window_far"] = perfect_previews(truth, road_map, stamps, reach, settings)
        perfect["map_plane_far"] = perfect_map_previews(truth, road_map, stamps, reach, settings)
        perfect["map_plane_attitude_far"] = perfect["map_plane_far"]
        perfect["window_visible"] = perfect_previews(truth, road_map, stamps, grid, settings, visible_only=True)
        perfect["window_far_visible"] = perfect_previews(truth, road_map, stamps, reach, settings, visible_only=True)
    # contact-plane rows read with a plane: the true one for the perfect map, the one each
    # message carries for the rendered rows
    slopes = true_plane_slopes(truth, road_map, settings, stamps)
    attitude = {"map_plane_attitude": slopes, "map_plane_attitude_far": slopes,
                **{name: carried_plane_slopes for name in makers}}
    out: dict[str, Any] = {"road": kind, "speed_mps": speed, "seed": seed, "duration_s": frames / CAMERA_RATE_HZ,
                           "rendered": bool(makers), "render_s": round(render_s, 1), "rates": {}}
    base: dict[str, Any] | None = None
    for rate in rates:
        step = max(1, int(round(CAMERA_RATE_HZ / rate)))
        sources: dict[str, Any] = {name: previews[::step] for name, previews in perfect.items()}
        fused_frames: dict[str, int] = {}
        stream: dict[str, dict[str, int]] = {}
        for name, make in makers.items():
            sources[name] = make(drive, samples, step, settings)
            fused_frames[name] = len(sources[name])
            stream[name] = preview_stream(sources[name])
        if base is None:  # passive, no-preview and the ceiling do not depend on the camera
            base = ride(truth, road_map, {"passive": "passive", "no_preview": "none", "true_road": "true"},
                        settings, start, end, score_end)
        rows = {**base, **ride(truth, road_map, sources, settings, start, end, score_end, attitude)}
        arrival = {name: {k: v for k, v in preview_at_arrival(previews, truth, road_map, settings.arrival,
                                                              frame_stamps_ns=stamps[::step]).items()
                          if k in ARRIVAL_SUMMARY}
                   for name, previews in sources.items()}
        out["rates"][f"{rate:g}"] = {"rows": rows, "share": scores(rows), "arrival": arrival,
                                     "fused_frames": fused_frames, "camera_frames": len(stamps[::step]),
                                     "stream": stream}
        share = out["rates"][f"{rate:g}"]["share"]
        wk = {k: v["mean"]["wk_rms_mps2"] for k, v in rows.items()}
        print(f"  {kind:8s} {speed:4.0f} m/s seed {seed} {rate:4.0f} Hz: Wk passive {wk['passive']:.3f}, "
              f"no preview {wk['no_preview']:.3f}, true {wk['true_road']:.3f} m/s^2; share "
              + ", ".join(f"{k} {v:.2f}" for k, v in share.items() if k != "true_road"), file=sys.stderr, flush=True)
    return out


def drive_duration(duration: float, speed: float) -> float:
    """Seconds of camera frames of a drive asked ``duration`` s at ``speed`` m/s: at most what one
    road strip holds (:data:`STRIP_DRIVE_M`; 30 m/s: 17.1 s), whole frames."""
    fits = math.floor((STRIP_DRIVE_M / max(speed, 1e-3) - TAIL_S) * CAMERA_RATE_HZ) / CAMERA_RATE_HZ
    return min(duration, fits)


def preview_stream(previews: Sequence[Any]) -> dict[str, int]:
    """What a row's messages were: how many, how many against a contact plane (``base_link``),
    with a finite vehicle speed, with times of arrival, and with all three (the one stream)."""
    plane = [p.reference == "contact_plane" for p in previews]
    speed = [p.profiles.vehicle_speed is not None and math.isfinite(p.profiles.vehicle_speed) for p in previews]
    arrival = [p.profiles.time_of_arrival() is not None for p in previews]
    return {"messages": len(previews), "contact_plane": sum(plane), "with_speed": sum(speed),
            "with_arrival_times": sum(arrival),
            "in_one_stream": sum(a and b and c for a, b, c in zip(plane, speed, arrival, strict=True))}


def summarise(cells: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (rendered or not, speed, rate, row): share mean, std, min, max over roads and seeds,
    and the mean metrics of every row."""
    groups: dict[tuple[bool, float, str], list[dict[str, Any]]] = {}
    for cell in cells:
        for rate, data in cell["rates"].items():
            groups.setdefault((cell["rendered"], cell["speed_mps"], rate), []).append(data)
    table = []
    for (rendered, speed, rate), items in sorted(groups.items(), key=lambda g: (g[0][0], g[0][1], float(g[0][2]))):
        rows = sorted({r for d in items for r in d["rows"]}, key=_row_order)
        entry: dict[str, Any] = {"rendered": rendered, "speed_mps": speed, "rate_hz": float(rate), "drives": len(items),
                                 "rows": {}}
        for r in rows:
            metrics = [d["rows"][r]["mean"] for d in items if r in d["rows"]]
            shares = [d["share"][r] for d in items if r in d["share"] and math.isfinite(d["share"][r])]
            row: dict[str, Any] = {k: float(np.mean([m[k] for m in metrics])) for k in
                                   ("wk_rms_mps2", "peak_travel_m", "tyre_load_rms_ratio", "force_rms_n")}
            if shares:
                row.update(share_mean=float(np.mean(shares)), share_std=float(np.std(shares)),
                           share_min=float(np.min(shares)), share_max=float(np.max(shares)))
            arrivals = [d["arrival"][r] for d in items if r in d.get("arrival", {})]
            if arrivals:
                row["arrival"] = pooled_arrival(arrivals)
            entry["rows"][r] = row
        table.append(entry)
    return table


def pooled_arrival(items: Sequence[Mapping[str, Any]]) -> dict[str, float]:
    """The preview at arrival over several drives: errors weighted by the points each drive scored
    (feature errors by its feature points, the sigma's honesty by the points with a sigma),
    coverage over all points."""
    points = np.array([i["points"] for i in items], float)
    covered = points * np.array([i["coverage_pct"] for i in items]) / 100.0
    feature_points = np.array([i["features_points"] for i in items], float)

    def weighted(key: str, weights: np.ndarray) -> float:
        values = np.array([i.get(key, math.nan) for i in items], float)
        ok = np.isfinite(values) & (weights > 0)
        return float(np.sum(values[ok] * weights[ok]) / np.sum(weights[ok])) if ok.any() else math.nan

    sigma_points = np.array([i.get("sigma_points", 0) for i in items], float)  # a run before the preview's sigma
    honesty = {key: weighted(key, sigma_points) for key in
               ("within_1sigma_pct", "within_2sigma_pct", "confident_wrong_pct", "mean_sigma_cm")
               if any(key in i for i in items)}
    return {**honesty, "abs_err_cm": weighted("abs_err_cm", covered),
            "features_abs_err_cm": weighted("features_abs_err_cm", feature_points),
            "smooth_abs_err_cm": weighted("smooth_abs_err_cm", covered),
            "contact_plane_abs_err_cm": weighted("contact_plane_abs_err_cm", covered),
            "coverage_pct": float(100.0 * covered.sum() / points.sum()) if points.sum() else math.nan}


def _row_order(name: str) -> tuple[int, str]:
    order = {"passive": 0, "no_preview": 1, "true_road": 2, "window": 3, "map_plane": 4, "map_plane_attitude": 5,
             "window_far": 6, "map_plane_far": 7, "map_plane_attitude_far": 8}
    return (order.get(name, 9), name)


def plot(table: Sequence[dict[str, Any]], path: Path) -> None:
    """Wk RMS (truth-only drives) and the share of the ceiling's gain per preview row against speed:
    a colour per row, solid 10 Hz / dashed 5 Hz, circles truth-only / squares rendered drives."""
    from roadbev_lab.reports.figures import new_figure

    fig, axes = new_figure(1, 2, figsize=(12, 4.4), dpi=100)
    names = sorted({r for t in table for r in t["rows"]}, key=_row_order)
    colours = {name: f"C{i}" for i, name in enumerate(names)}
    rates = sorted({t["rate_hz"] for t in table})
    for rendered in (False, True):
        for rate in rates:
            items = sorted((t for t in table if t["rendered"] == rendered and t["rate_hz"] == rate),
                           key=lambda t: t["speed_mps"])
            if not items:
                continue
            speeds = [t["speed_mps"] for t in items]
            style = ("-" if rate == rates[-1] else "--") + ("s" if rendered else "o")
            tag = f"{rate:g} Hz{', rendered' if rendered else ''}"
            for name in names:
                rows = [t["rows"].get(name) for t in items]
                if any(r is None for r in rows):
                    continue
                if not rendered and (rate == rates[-1] or name not in ("passive", "no_preview", "true_road")):
                    axes[0].plot(speeds, [r["wk_rms_mps2"] for r in rows], style, color=colours[name],
                                 label=name if name in ("passive", "no_preview", "true_road") else f"{name} {tag}")
                if name not in ("passive", "no_preview", "true_road") and all("share_mean" in r for r in rows):
                    axes[1].errorbar(speeds, [r["share_mean"] for r in rows], yerr=[r["share_std"] for r in rows],
                                     fmt=style, color=colours[name], capsize=3, label=f"{name} {tag}")
    axes[0].set_ylabel("Wk-weighted RMS body acceleration (m/s^2)")
    axes[0].set_title("truth-only drives (20 s)")
    axes[1].set_ylabel("share of the true road's gain over no preview")
    axes[1].set_title("preview rows")
    axes[1].axhline(1.0, color="k", lw=0.5)
    axes[1].axhline(0.0, color="k", lw=0.5)
    for ax in axes:
        ax.set_xlabel("speed (m/s)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, ncol=2)
    fig.suptitle("preview LQR quarter car on drives over bumps, potholes, rough road (latency 0.1 s)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


class CellJob(NamedTuple):
    """One drive to ride: its road, speed, seed, duration and whether it is rendered."""

    kind: str
    speed: float
    seed: int
    duration: float
    rendered: bool


def _run_job(job: CellJob, *, rates: Sequence[float], latency: float, candidates: Sequence[Candidate],
             budget: Sequence[str] | None,
             frame_cache: str, preview_gain: bool, far_x_max: float | None = None) -> dict[str, Any]:
    """:func:`run_cell` of one job (a process of the pool builds its own makers and caches)."""
    what = "rendered" if job.rendered else "truth-only"
    print(f"{what} drive {job.kind} {job.speed:g} m/s seed {job.seed}, {job.duration:g} s", file=sys.stderr,
          flush=True)
    grid = GridSpec()  # the drives' grid
    makers = candidate_makers(candidates, budget, grid) if job.rendered else {}
    return run_cell(job.kind, job.speed, job.seed, job.duration, rates, latency, makers,
                    DriveFrames(frame_cache) if job.rendered else None, preview_gain, far_x_max,
                    far_label_grid(candidates, budget, grid))


def _cell_order(args: argparse.Namespace, base: int, rendered: bool,
                reused: dict[tuple[str, float, int], dict[str, Any]]) -> list[tuple[str, float, int]]:
    """The cells' keys in the benchmark's order (road, speed, truth-only seeds, rendered seeds)."""
    keys = []
    for k, kind in enumerate(args.roads):
        for i, speed in enumerate(args.speeds):
            keys += [(kind, speed, base + 1000 * k + 100 * i + s) for s in range(args.seeds)]
            if rendered:
                keys += [(kind, speed, base + 1000 * k + 100 * i + 50 + s) for s in range(args.render_seeds)]
    return keys


class BenchError(Exception):
    """An earlier run that cannot stand in for the drives asked for."""


def truth_cells_from(path: Path, wanted: Sequence[tuple[str, float, int]], duration: float, rates: Sequence[float],
                     latency: float) -> tuple[dict[tuple[str, float, int], dict[str, Any]], dict[str, Any]]:
    """The truth-only cells ``wanted`` ((road, speed, seed)) of an earlier run's JSON, and where
    they came from (that run's command, commit, time and wall time; an earlier reuse is carried
    through).

    Raises:
        BenchError: an unreadable file, another latency, or a wanted drive missing or ridden with
            another duration or camera rates.
    """
    import json

    try:
        data = json.loads(path.read_text())
        cells = {(c["road"], float(c["speed_mps"]), int(c["seed"])): c for c in data["cells"] if not c["rendered"]}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise BenchError(f"--truth-from {path}: not a bench_ride result ({type(exc).__name__}: {exc})") from None
    if not math.isclose(float(data.get("latency_s", math.nan)), latency):
        raise BenchError(f"--truth-from {path}: latency {data.get('latency_s')} s, not {latency} s")
    out = {}
    for key in wanted:
        cell = cells.get(key)
        if cell is None:
            raise BenchError(f"--truth-from {path}: no truth-only drive {key[0]} {key[1]:g} m/s seed {key[2]}")
        wanted_s = round(drive_duration(duration, key[1]) * CAMERA_RATE_HZ) / CAMERA_RATE_HZ
        if not math.isclose(cell["duration_s"], wanted_s) or \
                sorted(float(r) for r in cell["rates"]) != sorted(float(r) for r in rates):
            raise BenchError(f"--truth-from {path}: drive {key[0]} {key[1]:g} m/s seed {key[2]} was ridden "
                             f"{cell['duration_s']} s at {sorted(cell['rates'])} Hz")
        out[key] = cell
    provenance = data.get("truth_only_from") or {
        "path": str(path), "command": data.get("command"), "git_commit": data.get("machine", {}).get("git_commit"),
        "time_utc": data.get("machine", {}).get("time_utc"), "wall_s": data.get("wall_s")}
    return out, provenance


PREVIEW_MAKERS: dict[str, Callable[[str], PreviewMaker]] = {}  # extra preview rows by name (factory(name) -> maker)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--duration", type=float, default=20.0,
                        help="seconds of camera frames per truth-only drive (at most what one road strip holds at "
                             "the drive's speed: 17.1 s at 30 m/s)")
    parser.add_argument("--seeds", type=int, default=3, help="truth-only drives per road kind and speed")
    parser.add_argument("--speeds", type=float, nargs="+", default=[5.0, 10.0, 20.0])
    parser.add_argument("--rates", type=float, nargs="+", default=[5.0, 10.0])
    parser.add_argument("--roads", nargs="+", default=list(ROAD_KINDS), choices=ROAD_KINDS)
    parser.add_argument("--render-seeds", type=int, default=1, help="rendered drives per road kind and speed")
    parser.add_argument("--render-duration", type=float, default=6.0,
                        help="seconds of camera frames per rendered drive (capped as --duration)")
    add_candidate_arguments(parser, CACHE / "ride_frames", "configurations of the node to ride with (node "
                            "parameters after the colon; each needs a row in --node-results); none: truth rows only")
    parser.add_argument("--seed-base", type=int, default=SEED_BASE,
                        help="drive seeds start here (the benchmark's own by default; tuning runs take others)")
    parser.add_argument("--latency", type=float, default=0.1, help="latency of the truth rows (s)")
    add_executor_arguments(parser, "drives ridden")
    parser.add_argument("--far-field", action="store_true",
                        help="also the perfect rows reaching the far-field grid's far edge (window_far, "
                             "map_plane_far, map_plane_attitude_far): the ceiling of candidates with "
                             "far_field.enabled; and the perfect windows of only the road the camera sees "
                             "(window_visible, window_far_visible)")
    parser.add_argument("--no-preview-gain", action="store_true",
                        help="the controller applies all of every preview (no gain measured on the road ridden)")
    parser.add_argument("--out", default=str(RESULTS / "ride.json"))
    parser.add_argument("--truth-from", default=None, metavar="JSON",
                        help="take the truth-only drives from an earlier run's JSON (they depend on the "
                             "settings only, not on any backend: every one asked for must be there with the same "
                             "duration, rates and latency) instead of riding them again")
    args = parser.parse_args(argv)
    try:
        candidates = candidates_from_args(args)
    except ValueError as exc:
        parser.error(str(exc))
    unknown = set(args.budget or ()) - {c.name for c in candidates}
    if unknown:
        parser.error(f"--budget: no candidate named {', '.join(sorted(unknown))}")
    info = machine_info()
    start = time.perf_counter()
    base = args.seed_base
    wanted = [(kind, speed, base + 1000 * k + 100 * i + s) for k, kind in enumerate(args.roads)
              for i, speed in enumerate(args.speeds) for s in range(args.seeds)]
    reused: dict[tuple[str, float, int], dict[str, Any]] = {}
    provenance: dict[str, Any] | None = None
    if args.truth_from:
        try:
            reused, provenance = truth_cells_from(Path(args.truth_from), wanted, args.duration, args.rates,
                                                  args.latency)
        except BenchError as exc:
            parser.error(str(exc))
    jobs: list[CellJob] = []
    for k, kind in enumerate(args.roads):
        for i, speed in enumerate(args.speeds):
            for s in range(args.seeds):
                seed = base + 1000 * k + 100 * i + s
                if (kind, speed, seed) not in reused:
                    jobs.append(CellJob(kind, speed, seed, args.duration, False))
            if candidates:
                jobs += [CellJob(kind, speed, base + 1000 * k + 100 * i + 50 + s, args.render_duration, True)
                         for s in range(args.render_seeds)]
    work = partial(_run_job, rates=tuple(args.rates), latency=args.latency, candidates=tuple(candidates),
                   budget=args.budget, frame_cache=args.frame_cache, preview_gain=not args.no_preview_gain,
                   far_x_max=FarFieldConfig().x_max if args.far_field else None)
    with executor_from(args, parser) as pool:  # drives are independent and deterministic: the same cells anywhere
        done = pool.map(work, jobs)
        info["executor"] = pool.describe()
    computed = {(job.kind, job.speed, job.seed): cell for job, cell in zip(jobs, done, strict=True)}
    cells = [computed.get(key) or reused[key] for key in _cell_order(args, base, bool(candidates), reused)]
    table = summarise(cells)
    data = {
        "what": "preview LQR quarter car (roadbev_core.ride) over the true road of riding drives, per preview source; "
                "share = share of the true road's Wk-RMS gain over the controller without preview",
        "command": "python -m benchmarks.bench_ride " + " ".join(argv if argv is not None else sys.argv[1:]),
        "latency_s": args.latency,
        "preview_gain": not args.no_preview_gain,
        "far_field": args.far_field,
        "budget": args.budget,
        "candidates": [{"name": c.name, "backend": c.backend, "params": dict(c.params), "latency_s": c.latency_s,
                        "period_s": c.period_s, **({"pace_latency_s": c.pace[0], "pace_period_s": c.pace[1]}
                                                   if c.pace is not None else {})} for c in candidates],
        "node_results": args.node_results if candidates else None,
        "machine": info,
        "wall_s": round(time.perf_counter() - start, 1),
        "truth_only_from": provenance,
        "table": table,
        "cells": cells,
    }
    out = Path(args.out)
    write_json(out, data)
    plot(table, out.with_suffix(".png"))
    print(f"wrote {out} and {out.with_suffix('.png')} in {data['wall_s']} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
