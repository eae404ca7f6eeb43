"""Preview at arrival of node configurations on drives where the car rides on its road, with an error budget.

For every speed, camera rate and seed one :class:`roadbev_lab.synth.RidingDrive` (the full
960x528 rig, a random road of the test-scene distribution plus speed bumps and potholes, a
feature every 3 m, the body on its suspension, S-curves, the ``real-road`` look) is rendered once
(its frames kept in ``--frame-cache``). Each **candidate** (``--candidates``, a configuration of
the node with its latency and time per frame measured in the node, ``--node-results``; see
:mod:`benchmarks.preview_budget`) runs over it as ``roadbev eval --map`` does (the drive's own
drifting odometry and ``/tf_static`` mount), on the frames the node's schedule lets it fuse, each
preview used from when it is received:

* ``<name>``: its fused-map previews (contact-plane reference, the stream the node publishes);
  its map is scored against the true road too (:func:`roadbev_lab.evaluation.arrival.map_accuracy`,
  against the road under the car);
* ``<name>:per_frame``: the same frames through the per-frame pipeline (``--no-map``);
* with ``--budget`` one row per stage of the error budget (``<name>:true_answered``, ...).

Every row is scored at the front wheels' arrival (:func:`roadbev_lab.evaluation.arrival.preview_at_arrival`,
against the true counterpart of the reference each message declares, and against the true contact
plane). The per-frame grid metrics of each candidate's estimates on the drive frames are kept too.

Run: ``.venv/bin/python -m benchmarks.bench_arrival [--duration 10] [--seeds 1] [--speeds 5 10 20 30]
[--rates 5 10] [--candidates stereo ...] [--budget] [--jobs N | --ray ADDRESS]``; writes
``benchmarks/results/arrival.json`` and ``arrival.png``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
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
from roadbev_core.config import GridSpec
from roadbev_core.fusion import MapWindow
from roadbev_lab.evaluation.arrival import TimedPreview, map_accuracy, preview_at_arrival
from roadbev_lab.evaluation.metrics import MetricAccumulator
from roadbev_lab.ride import RideSettings

SEED_BASE = 310_000  # disjoint from training (< 1e5), test (1e5+), tuning (2e5+) and the map's tuning drive (300001)
FEATURES = ("speed_bump", "pothole")  # added to each drive's random features: the feature points a controller needs


def make_drive(speed: float, rate: float, duration: float, seed: int, far_grid: Any = None) -> Any:
    """The benchmark's drive (a :class:`roadbev_lab.synth.RidingDrive`, not yet rendered): a
    random road of the test-scene distribution plus FEATURES, a feature every 3 m (its frames also
    labelled on ``far_grid`` when given)."""
    from roadbev_lab.synth import DriveConfig, RidingConfig, RidingDrive
    from roadbev_lab.synth.drive import random_road

    road = random_road(np.random.default_rng(seed))  # class, surface, slopes, noise as the test scenes
    road = replace(road, features=tuple(dict.fromkeys((*FEATURES, *road.features))), feature_spacing_m=3.0)
    frames = max(2, int(round(duration * rate)))
    return RidingDrive(RidingConfig(drive=DriveConfig(frames=frames, speed_mps=speed, frame_rate_hz=rate,
                                                      seed=seed, road=road, far_grid=far_grid)))


class DriveTruth(NamedTuple):
    """What scoring a rendered drive needs (the truth the drive bag would carry).

    Attributes:
        trajectory: the true ``base_link`` poses (``/ground_truth/odom``).
        road_map: the true road (``/ground_truth/road_map``).
        settings: the preview-at-arrival settings for the drive's rig and lead time.
        odometry: the drive's own (noisy, drifting) planar odometry (``/odom``).
        odometry_poses: the same as a trajectory (the frame the map is kept in).
    """

    trajectory: Any
    road_map: Any
    settings: Any
    odometry: list[Any]
    odometry_poses: Any


def drive_truth(drive: Any, lead: float) -> DriveTruth:
    """The truth and odometry of a :class:`roadbev_lab.synth.RidingDrive`."""
    from roadbev_lab.evaluation.arrival import ArrivalSettings, Trajectory
    from roadbev_lab.synth.riding import planar_odometry

    gt = drive.ground_truth_poses()
    grid = drive.config.grid
    settings = ArrivalSettings(lead_time_s=lead, base_height=grid.base_height, camera_in_base=drive.base_to_camera)
    odometry = drive.odometry()
    return DriveTruth(Trajectory(gt.stamp_ns, gt.position, gt.orientation_xyzw), drive.road_map(), settings,
                      list(planar_odometry(odometry)),
                      Trajectory(odometry.stamp_ns, odometry.position, odometry.orientation_xyzw))


def evaluate_on_drive(drive: Any, samples: list[Any], backend: str, fused: bool, odometry: list[Any]) -> Any:
    """``backend`` through the pipeline over a drive's rendered samples, map on or off, as
    ``roadbev eval --map`` / ``--no-map`` run it (an :class:`~roadbev_lab.evaluation.frames.EvalResult`
    with the outputs kept)."""
    from roadbev_core.config import RoadbevConfig
    from roadbev_core.pipeline import Pipeline, check_config
    from roadbev_lab.evaluation.frames import evaluate

    grid = drive.config.grid
    config = check_config(RoadbevConfig.from_params({**grid.to_dict(), "backend": backend, "map.enabled": fused}))
    pipeline = Pipeline(config, configure_process=False)
    pipeline.set_camera_mount(*drive.base_to_camera)
    return evaluate(pipeline, samples, keep_estimates=True, odometry=odometry)


def run_drive(speed: float, rate: float, duration: float, seed: int, candidates: Sequence[Candidate],
              budget: Sequence[str] | None, lead: float, frame_cache: DriveFrames) -> dict[str, Any]:
    """Render one drive (or read it back), run every candidate on it, score its rows at arrival."""
    drive = make_drive(speed, rate, duration, seed, far_label_grid(candidates, budget, GridSpec()))
    road, frames = drive.config.road, drive.config.frames
    start = time.perf_counter()
    samples = frame_cache.samples(drive)
    render_s = time.perf_counter() - start
    truth, road_map, settings, _, odometry = drive_truth(drive, lead)
    ride_settings = RideSettings(latency_s=lead, arrival=settings)
    stamps = drive.frame_stamps_ns
    out: dict[str, Any] = {"speed_mps": speed, "rate_hz": rate, "frames": frames, "seed": seed,
                           "road": {"class": road.road_class, "features": list(road.features),
                                    "surface": road.surface}, "render_s": round(render_s, 1), "rows": {},
                           "grid": {}, "map": {}, "fused_frames": {}}

    def score(previews: Sequence[TimedPreview]) -> dict[str, Any]:
        arrival = preview_at_arrival(previews, truth, road_map, settings, frame_stamps_ns=stamps)
        return {k: v for k, v in arrival.items() if k != "per_wheel"}

    for candidate in candidates:
        cached = make_backend(candidate, drive.config.grid)
        windows: list[MapWindow] = []
        shipped = candidate_previews(drive, samples, candidate, cached, "shipped", ride_settings=ride_settings,
                                     on_map=windows.append)
        out["rows"][candidate.name] = score(shipped)
        out["fused_frames"][candidate.name] = f"{len(shipped)}/{frames}"
        out["map"][candidate.name] = map_accuracy(windows, road_map, truth, odometry=odometry) if windows else None
        per_frame = candidate_previews(drive, samples, candidate, cached, "shipped", ride_settings=ride_settings,
                                       map_on=False)
        out["rows"][f"{candidate.name}{STAGE_SEPARATOR}per_frame"] = score(per_frame)
        for stage in stages_of(candidate, drive.config.grid)[1:] if budgeted(candidate.name, budget) else ():
            previews = candidate_previews(drive, samples, candidate, cached, stage, ride_settings=ride_settings)
            out["rows"][f"{candidate.name}{STAGE_SEPARATOR}{stage}"] = score(previews)
        grid = MetricAccumulator(drive.config.grid)
        for sample in samples:
            grid.add(cached.estimate(sample.frame).elevation, sample.truth.elevation)
        metrics = grid.result().to_dict()
        out["grid"][candidate.name] = {k: metrics[k] for k in ("abs_err_cm", "rmse_cm", "coverage_pct", "cells")}
        pa, fm = out["rows"][candidate.name], out["map"][candidate.name]
        print(f"  {candidate.name:14s} {speed:4.0f} m/s {rate:4.0f} Hz seed {seed}: arrival {pa['abs_err_cm']:.3f} cm "
              f"({pa['coverage_pct']:.1f} %), features {pa['features_abs_err_cm']:.3f}, contact plane "
              f"{pa['contact_plane_abs_err_cm']:.3f}; map {fm['abs_err_cm'] if fm else math.nan:.3f} cm",
              file=sys.stderr, flush=True)
    return out


def _run_job(job: tuple[float, float, int], *, duration: float, candidates: Sequence[Candidate],
             budget: Sequence[str] | None, lead: float, frame_cache: str) -> dict[str, Any]:
    speed, rate, seed = job
    print(f"drive {speed:g} m/s, {rate:g} Hz, seed {seed}, {duration:g} s", file=sys.stderr, flush=True)
    return run_drive(speed, rate, duration, seed, candidates, budget, lead, DriveFrames(frame_cache))


def summarise(results: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (speed, rate, row): the preview at arrival pooled over the seeds (errors weighted by the
    points each drive covered, feature errors by its feature points)."""
    groups: dict[tuple[float, float], list[dict[str, Any]]] = {}
    for r in results:
        groups.setdefault((r["speed_mps"], r["rate_hz"]), []).append(r)
    table = []
    for (speed, rate), items in sorted(groups.items()):
        names = list(dict.fromkeys(n for r in items for n in r["rows"]))
        rows = {}
        for name in names:
            arrivals = [r["rows"][name] for r in items if name in r["rows"]]
            points = np.array([a["points"] for a in arrivals], float)
            covered = np.array([a["covered_points"] for a in arrivals], float)
            feature_covered = np.array([a["features_points"] * (a["features_coverage_pct"] or 0) / 100.0
                                        for a in arrivals], float)

            def weighted(key: str, weights: np.ndarray, arrivals: list[dict[str, Any]] = arrivals) -> float:
                values = np.array([a[key] for a in arrivals], float)
                ok = np.isfinite(values) & (weights > 0)
                return float(np.sum(values[ok] * weights[ok]) / np.sum(weights[ok])) if ok.any() else math.nan

            rows[name] = {"abs_err_cm": weighted("abs_err_cm", covered),
                          "features_abs_err_cm": weighted("features_abs_err_cm", feature_covered),
                          "smooth_abs_err_cm": weighted("smooth_abs_err_cm", covered),
                          "contact_plane_abs_err_cm": weighted("contact_plane_abs_err_cm", covered),
                          "coverage_pct": float(100.0 * covered.sum() / points.sum()) if points.sum() else math.nan}
        table.append({"speed_mps": speed, "rate_hz": rate, "drives": len(items), "rows": rows})
    return table


def plot(table: Sequence[dict[str, Any]], candidates: Sequence[str], path: Path) -> None:
    """Error at arrival, against the true contact plane, and coverage against speed: one colour per
    candidate (fused map solid, per frame dotted), circles 10 Hz / squares 5 Hz."""
    from roadbev_lab.reports.figures import new_figure

    fig, axes = new_figure(1, 3, figsize=(14, 4.2), dpi=100)
    rates = sorted({t["rate_hz"] for t in table})
    for c, name in enumerate(candidates):
        for rate in rates:
            items = sorted((t for t in table if t["rate_hz"] == rate), key=lambda t: t["speed_mps"])
            speeds = [t["speed_mps"] for t in items]
            marker = "o" if rate == rates[-1] else "s"
            for row, style, tag in ((name, "-", "map"), (f"{name}{STAGE_SEPARATOR}per_frame", ":", "per frame")):
                values = [t["rows"].get(row) for t in items]
                if any(v is None for v in values):
                    continue
                label = f"{name} {tag} {rate:g} Hz"
                for ax, key in zip(axes, ("abs_err_cm", "contact_plane_abs_err_cm", "coverage_pct"), strict=True):
                    ax.plot(speeds, [v[key] for v in values], style + marker, color=f"C{c}", label=label)
    for ax, title in zip(axes, ("abs. error at arrival (cm)", "vs the true contact plane (cm)", "coverage (%)"),
                         strict=True):
        ax.set_xlabel("speed (m/s)")
        ax.set_title(title)
        ax.grid(alpha=0.3)
    axes[2].legend(fontsize=6, ncol=2)
    fig.suptitle("previews at the front wheels' arrival, each configuration at its own latency")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--duration", type=float, default=10.0, help="seconds of camera frames per drive")
    parser.add_argument("--seeds", type=int, default=1, help="drives per speed and camera rate")
    parser.add_argument("--speeds", type=float, nargs="+", default=[5.0, 10.0, 20.0, 30.0])
    parser.add_argument("--rates", type=float, nargs="+", default=[5.0, 10.0])
    add_candidate_arguments(parser, CACHE / "arrival_frames", "configurations of the node (node parameters after "
                            "the colon; each needs a row in --node-results)")
    parser.add_argument("--lead-time", type=float, default=0.1, help="lead time of messages without a receipt time")
    add_executor_arguments(parser, "drives run")
    parser.add_argument("--out", default=str(RESULTS / "arrival.json"))
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
    jobs = [(speed, rate, SEED_BASE + i + 100 * s) for i, speed in enumerate(args.speeds) for rate in args.rates
            for s in range(args.seeds)]
    work = partial(_run_job, duration=args.duration, candidates=tuple(candidates), budget=args.budget,
                   lead=args.lead_time, frame_cache=args.frame_cache)
    with executor_from(args, parser) as pool:  # drives are independent and deterministic: the same results anywhere
        results = pool.map(work, jobs)
        info["executor"] = pool.describe()
    table = summarise(results)
    data = {
        "what": "preview at arrival of node configurations (fused map; per_frame: map off; the error budget's "
                "stages), each at its latency measured in the node (docs/interface/evaluation.md: Preview at "
                "arrival); grid = the per-frame elevation metrics of the drive frames; map = the fused map against "
                "the true road under the car, time-averaged",
        "command": "python -m benchmarks.bench_arrival " + " ".join(argv if argv is not None else sys.argv[1:]),
        "duration_s": args.duration,
        "lead_time_s": args.lead_time,
        "candidates": [{"name": c.name, "backend": c.backend, "params": dict(c.params), "latency_s": c.latency_s,
                        "period_s": c.period_s} for c in candidates],
        "node_results": args.node_results,
        "budget": args.budget,
        "machine": info,
        "wall_s": round(time.perf_counter() - start, 1),
        "table": table,
        "results": results,
    }
    out = Path(args.out)
    write_json(out, data)
    plot(table, [c.name for c in candidates], out.with_suffix(".png"))
    print(f"wrote {out} and {out.with_suffix('.png')} in {data['wall_s']} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
