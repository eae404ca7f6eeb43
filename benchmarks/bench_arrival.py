"""Preview at arrival, per frame and from the fused map, on drives where the car rides on its road.

For every speed and camera rate, one :class:`roadbev_core.synth.RidingDrive` (the full
960x528 rig, a random road of the test-scene distribution plus speed bumps and potholes, a
feature every 3 m, the body on its suspension, S-curves) is rendered once; each backend estimates every frame
through the pipeline twice, as ``roadbev eval --no-map`` and ``--map`` do on a drive bag:

* map off: the per-frame wheel-track previews (``roadbev_road``);
* map on: the drive's own (drifting, noisy) odometry and the camera mount of its ``/tf_static``
  feed the fused map; its contact-plane previews (the per-frame one for the first frames, until
  the map holds three tyre contacts).

Both are scored at the front wheels' arrival (:func:`roadbev_core.arrival.preview_at_arrival`,
lead 0.1 s); with the map on, the map itself is scored against the true road
(:func:`roadbev_core.arrival.map_accuracy`). The per-frame grid metrics of the same frames are
kept too: they say whether the shipped checkpoints hold on drive frames (compare
``benchmarks/results/models.json``, the single-frame test scenes).

Run: ``.venv/bin/python -m benchmarks.bench_arrival [--duration 2] [--speeds 5 10 20 30]
[--rates 5 10] [--backends bev_sweep stereo mono]``; writes ``benchmarks/results/arrival.json``
and ``arrival.png``.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from benchmarks.common import RESULTS, machine_info, write_json

SEED_BASE = 310_000  # disjoint from training (< 1e5), test (1e5+), tuning (2e5+) and the map's tuning drive (300001)
FEATURES = ("speed_bump", "pothole")  # added to each drive's random features: the feature points a controller needs


def make_drive(speed: float, rate: float, duration: float, seed: int) -> Any:
    """The benchmark's drive (a :class:`roadbev_core.synth.RidingDrive`, not yet rendered): a
    random road of the test-scene distribution plus FEATURES, a feature every 3 m."""
    from roadbev_core.synth import DriveConfig, RidingConfig, RidingDrive
    from roadbev_core.synth.drive import random_road

    road = random_road(np.random.default_rng(seed))  # class, surface, slopes, noise as the test scenes
    road = replace(road, features=tuple(dict.fromkeys((*FEATURES, *road.features))), feature_spacing_m=3.0)
    frames = max(2, int(round(duration * rate)))
    return RidingDrive(RidingConfig(drive=DriveConfig(frames=frames, speed_mps=speed, frame_rate_hz=rate,
                                                      seed=seed, road=road)))


class DriveTruth(NamedTuple):
    """What scoring a rendered drive needs (the truth the drive bag would carry).

    Attributes:
        trajectory: the true ``base_link`` poses (``/ground_truth/odom``).
        road_map: the true road (``/ground_truth/road_map``).
        settings: the preview-at-arrival settings for the drive's rig and lead time.
        odometry: the drive's own (noisy, drifting) planar odometry (``/odom``).
    """

    trajectory: Any
    road_map: Any
    settings: Any
    odometry: list[Any]


def drive_truth(drive: Any, lead: float) -> DriveTruth:
    """The truth and odometry of a :class:`roadbev_core.synth.RidingDrive`."""
    from roadbev_core.arrival import ArrivalSettings, Trajectory
    from roadbev_core.synth.riding import planar_odometry

    gt = drive.ground_truth_poses()
    grid = drive.config.grid
    settings = ArrivalSettings(lead_time_s=lead, base_height=grid.base_height, camera_in_base=drive.base_to_camera)
    return DriveTruth(Trajectory(gt.stamp_ns, gt.position, gt.orientation_xyzw), drive.road_map(), settings,
                      list(planar_odometry(drive.odometry())))


def evaluate_on_drive(drive: Any, samples: list[Any], backend: str, fused: bool, odometry: list[Any]) -> Any:
    """``backend`` through the pipeline over a drive's rendered samples, map on or off, as
    ``roadbev eval --map`` / ``--no-map`` run it (an :class:`~roadbev_core.evaluation.EvalResult`
    with the outputs kept)."""
    from roadbev_core.config import RoadbevConfig
    from roadbev_core.evaluation import evaluate
    from roadbev_core.pipeline import Pipeline

    grid = drive.config.grid
    config = RoadbevConfig.from_params({**grid.to_dict(), "backend": backend, "map.enabled": fused})
    pipeline = Pipeline(config, configure_process=False)
    pipeline.set_camera_mount(*drive.base_to_camera)
    return evaluate(pipeline, samples, keep_estimates=True, odometry=odometry)


def run_drive(speed: float, rate: float, duration: float, seed: int, backends: list[str], lead: float,
              ) -> dict[str, Any]:
    """Render one drive, run every backend on it, score the previews at arrival."""
    from roadbev_core.arrival import map_accuracy, per_frame_previews, preview_at_arrival

    drive = make_drive(speed, rate, duration, seed)
    road, frames = drive.config.road, drive.config.frames
    start = time.perf_counter()
    samples = list(drive)
    render_s = time.perf_counter() - start
    truth, road_map, settings, odometry = drive_truth(drive, lead)
    out: dict[str, Any] = {"speed_mps": speed, "rate_hz": rate, "frames": frames, "seed": seed,
                           "road": {"class": road.road_class, "features": list(road.features),
                                    "surface": road.surface}, "render_s": round(render_s, 1), "backends": {}}
    for name in backends:
        rows: dict[str, Any] = {}
        for fused in (False, True):
            result = evaluate_on_drive(drive, samples, name, fused, odometry)
            stamps = [int(r["stamp_ns"]) for r in result.per_frame]
            outputs = result.outputs or []
            arrival = preview_at_arrival(per_frame_previews(outputs), truth, road_map, settings,
                                         frame_stamps_ns=stamps)
            metrics = result.to_dict()
            row: dict[str, Any] = {
                "preview_at_arrival": {k: v for k, v in arrival.items() if k != "per_wheel"},
                "grid": {k: metrics[k] for k in ("abs_err_cm", "rmse_cm", "coverage_pct", "cells", "fps")},
            }
            pa = arrival
            line = (f"  {name:9s} {speed:4.0f} m/s {rate:4.0f} Hz map {'on ' if fused else 'off'}: arrival "
                    f"{pa['abs_err_cm']:.3f} cm ({pa['coverage_pct']:.1f} %), features "
                    f"{pa['features_abs_err_cm']:.3f}, smooth {pa['smooth_abs_err_cm']:.3f}, contact plane "
                    f"{pa['contact_plane_abs_err_cm']:.3f}")
            if fused:
                fusions = [o.fusion for o in outputs if o.fusion is not None]
                row["map"] = map_accuracy([o.map for o in outputs if o.map is not None], road_map, truth)
                row["map"]["fusion_ms_p50"] = float(np.median([f.cost_ms for f in fusions]))
                row["map"]["map_stage_ms_p50"] = float(np.median([o.timings_ms["map"] for o in outputs]))
                line += (f"; map {row['map']['abs_err_cm']:.3f} cm ({row['map']['coverage_pct']:.1f} %), "
                         f"confidently wrong {row['map']['confident_wrong_pct']:.2f} %")
            else:
                line += f"; grid {metrics['abs_err_cm']:.3f} cm"
            print(line, file=sys.stderr, flush=True)
            rows["map" if fused else "per_frame"] = row
        out["backends"][name] = {**rows["per_frame"], "map_on": rows["map"]}
    return out


def plot(results: list[dict[str, Any]], path: Any) -> None:
    """Error and coverage against speed, one line per backend and camera rate."""
    from roadbev_core.figures import new_figure

    fig, axes = new_figure(1, 3, figsize=(14, 4), dpi=100)
    backends = sorted({b for r in results for b in r["backends"]})
    rates = sorted({r["rate_hz"] for r in results})
    for name in backends:
        for rate in rates:
            rows = sorted((r for r in results if r["rate_hz"] == rate and name in r["backends"]),
                          key=lambda r: r["speed_mps"])
            speeds = [r["speed_mps"] for r in rows]
            for key, tag, marker in (("per_frame", "per frame", "o"), ("map_on", "map", "^")):
                pa = [(r["backends"][name] if key == "per_frame" else r["backends"][name][key])["preview_at_arrival"]
                      for r in rows]
                style = ("-" if rate == rates[0] else "--") + marker
                label = f"{name} {tag} {rate:g} Hz"
                axes[0].plot(speeds, [p["abs_err_cm"] for p in pa], style, label=label)
                axes[1].plot(speeds, [p["contact_plane_abs_err_cm"] for p in pa], style, label=label)
                axes[2].plot(speeds, [p["coverage_pct"] for p in pa], style, label=label)
    for ax, title in zip(axes, ("abs. error at arrival (cm)", "vs the true contact plane (cm)", "coverage (%)"),
                         strict=True):
        ax.set_xlabel("speed (m/s)")
        ax.set_title(title)
        ax.grid(alpha=0.3)
    axes[2].legend(fontsize=7)
    fig.suptitle("previews at the front wheels' arrival (lead 0.1 s): per frame and from the fused map")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--duration", type=float, default=2.0, help="seconds of camera frames per drive (default 2)")
    parser.add_argument("--speeds", type=float, nargs="+", default=[5.0, 10.0, 20.0, 30.0])
    parser.add_argument("--rates", type=float, nargs="+", default=[5.0, 10.0])
    parser.add_argument("--backends", nargs="+", default=["bev_sweep", "stereo", "mono"])
    parser.add_argument("--lead-time", type=float, default=0.1)
    parser.add_argument("--out", default=str(RESULTS / "arrival.json"))
    args = parser.parse_args(argv)
    info = machine_info()
    start = time.perf_counter()
    results = []
    for i, speed in enumerate(args.speeds):
        for rate in args.rates:
            print(f"drive {speed:g} m/s, {rate:g} Hz, {args.duration:g} s", file=sys.stderr, flush=True)
            results.append(run_drive(speed, rate, args.duration, SEED_BASE + i, args.backends, args.lead_time))
    data = {
        "what": "preview at arrival of the per-frame pipeline and (map_on) of the fused map (contract: Drive "
                "bags and the evaluation of previews); grid = the per-frame elevation metrics of the same drive "
                "frames; map_on.map = the fused map against the true road, time-averaged",
        "command": "python -m benchmarks.bench_arrival " + " ".join(argv if argv is not None else sys.argv[1:]),
        "duration_s": args.duration,
        "lead_time_s": args.lead_time,
        "machine": info,
        "wall_s": round(time.perf_counter() - start, 1),
        "results": results,
    }
    out = Path(args.out)
    write_json(out, data)
    plot(results, out.with_suffix(".png"))
    print(f"wrote {out} and {out.with_suffix('.png')} in {data['wall_s']} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
