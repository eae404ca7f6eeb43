"""Fit each backend's map-datum uncertainty on tuning drives (``roadbev_core/data/datum_calibration.json``).

``odom`` z is observed by nothing: the fused map's datum is where the alignments of its frames
put it, and it drifts with the distance driven (see :mod:`roadbev_core.fusion`). For every
tuning drive (the benchmark's drive construction, :func:`benchmarks.bench_arrival.make_drive`,
on seeds of their own: 300001 + i, disjoint from the benchmark drives 310000 + i) and backend,
the pipeline runs with the map on and the datum term off; after each frame the datum's error
is ``base_z`` (``base_link``'s z in ``odom`` as the map has it) minus the true z of
``base_link`` at the stamp, and ``s`` the distance driven since the datum was fixed. The fit is
the maximum likelihood of ``D ~ N(0, (datum_sigma_m + datum_drift * s)^2)`` over all frames of
all drives (a grid search; ``datum_sigma_m`` at least 1 mm), and ``datum_drift`` at least half
the steepest drift any one drive showed (``max (|D| - datum_sigma_m) / s`` over its frames 10 m
and more into it):
the datum of one road can drift several times faster than that of another (a kerb, a cross
slope), and a cell is confidently wrong beyond 3 sigma, so the worst tuning drive stays within
2 sigma of its datum.

Run: ``.venv/bin/python -m benchmarks.calibrate_datum [--drives SPEED:RATE:SEED ...] [--duration 3]
[--backends bev_sweep stereo mono]`` (default: 10 drives at 10 and 20 m/s, 5 and 10 Hz).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.bench_arrival import make_drive
from benchmarks.common import RESULTS, machine_info, write_json


def datum_errors(drive: Any, samples: list[Any], backend: str) -> tuple[np.ndarray, np.ndarray]:
    """[K] datum errors (m) and [K] distances driven (m) of one backend on one rendered drive."""
    from roadbev_core.config import RoadbevConfig
    from roadbev_core.pipeline import Pipeline, check_config
    from roadbev_lab.evaluation.arrival import Trajectory
    from roadbev_lab.evaluation.frames import evaluate
    from roadbev_lab.synth.riding import planar_odometry

    gt = drive.ground_truth_poses()
    truth = Trajectory(gt.stamp_ns, gt.position, gt.orientation_xyzw)
    config = check_config(RoadbevConfig.from_params({**drive.config.grid.to_dict(), "backend": backend,
                                                     "map.enabled": True, "map.datum_sigma_m": 0.0,
                                                     "map.datum_drift": 0.0}))
    pipeline = Pipeline(config, configure_process=False)
    pipeline.set_camera_mount(*drive.base_to_camera)
    result = evaluate(pipeline, samples, keep_estimates=True, odometry=planar_odometry(drive.odometry()))
    errors, driven = [], []
    for out in result.outputs or []:
        if out.fusion is None:
            continue
        position, _ = truth.interpolate(np.array([out.stamp_ns]))
        errors.append(out.fusion.base_z_m - float(position[0][2]))
        driven.append(out.fusion.driven_m)
    return np.asarray(errors), np.asarray(driven)


def fit(errors: np.ndarray, driven: np.ndarray) -> tuple[float, float]:
    """Maximum-likelihood ``(datum_sigma_m, datum_drift)`` of ``errors ~ N(0, (a + b s)^2)`` [K]."""
    best = (math.inf, 0.001, 0.0)
    for a in np.geomspace(0.001, 0.2, 60):
        for b in np.concatenate([[0.0], np.geomspace(1e-5, 0.05, 80)]):
            sigma = a + b * driven
            nll = float(np.sum(np.log(sigma) + 0.5 * (errors / sigma) ** 2))
            if nll < best[0]:
                best = (nll, float(a), float(b))
    return best[1], best[2]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--drives", nargs="+", help="SPEED:RATE:SEED of each tuning drive",
                        default=["10:10:300001", "20:10:300002", "10:10:300003", "20:10:300004", "10:5:300005",
                                 "20:5:300006", "10:5:300007", "20:5:300008", "20:10:300009", "20:5:300010"])
    parser.add_argument("--duration", type=float, default=3.0)
    parser.add_argument("--backends", nargs="+", default=["bev_sweep", "stereo", "mono"])
    parser.add_argument("--out", default=str(Path(__file__).resolve().parent.parent / "roadbev_core" / "data"
                                             / "datum_calibration.json"))
    args = parser.parse_args(argv)
    start = time.perf_counter()
    collected: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {b: [] for b in args.backends}
    drives = []
    for item in args.drives:
        speed_text, rate_text, seed_text = item.split(":")
        drive = make_drive(float(speed_text), float(rate_text), args.duration, int(seed_text))
        samples = list(drive)
        drives.append({"speed_mps": float(speed_text), "rate_hz": float(rate_text), "seed": int(seed_text)})
        for name in args.backends:
            errors, driven = datum_errors(drive, samples, name)
            collected[name].append((errors, driven))
            print(f"  {name:9s} {item}: datum error at the end {100 * errors[-1]:+.2f} cm after {driven[-1]:.1f} m, "
                  f"largest {100 * np.abs(errors).max():.2f} cm", file=sys.stderr, flush=True)
    table: dict[str, Any] = {}
    for name, runs in collected.items():
        errors = np.concatenate([e for e, _ in runs])
        driven = np.concatenate([s for _, s in runs])
        sigma, drift = fit(errors, driven)
        steepest = max(float(np.max(np.maximum(np.abs(e[s >= 10.0]) - sigma, 0.0) / s[s >= 10.0]))
                       for e, s in runs if np.any(s >= 10.0))
        drift = max(drift, 0.5 * steepest)
        covered = np.abs(errors) <= 3.0 * (sigma + drift * driven)
        table[name] = {"datum_sigma_m": round(sigma, 5), "datum_drift": round(drift, 6), "frames": int(errors.size),
                       "rms_error_cm": round(100 * float(np.sqrt(np.mean(errors ** 2))), 3),
                       "within_3sigma_pct": round(100 * float(covered.mean()), 1),
                       "steepest_drift": round(steepest, 6),
                       "end_errors_cm": [round(100 * float(e[-1]), 2) for e, _ in runs],
                       "errors_cm": [[round(100 * float(v), 3) for v in e] for e, _ in runs],
                       "driven_m": [[round(float(v), 2) for v in s] for _, s in runs]}
        print(f"{name}: datum_sigma_m {sigma:.4f}, datum_drift {drift:.6f} m/m "
              f"({100 * covered.mean():.0f} % within 3 sigma)", file=sys.stderr)
    record = {"what": "map datum 1-sigma per backend: datum_sigma_m + datum_drift * metres driven",
              "command": "python -m benchmarks.calibrate_datum " + " ".join(argv if argv is not None else sys.argv[1:]),
              "drives": drives, "duration_s": args.duration, "backends": table,
              "wall_s": round(time.perf_counter() - start, 1), "machine": machine_info()}
    write_json(Path(args.out), record)
    write_json(RESULTS / "datum_calibration.json", record)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
