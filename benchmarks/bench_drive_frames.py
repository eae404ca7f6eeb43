"""Learned checkpoints on held-out drive frames and on the Table I frames, side by side.

Run (from the repository root)::

    .venv/bin/python -m benchmarks.bench_drive_frames --checkpoints OLD.pt checkpoints/roadbev_stereo_lite.pt

The held-out drives are :mod:`benchmarks.training_drives` at seeds
:data:`~benchmarks.training_drives.VALIDATION_SEED_BASE` + i (10 drives: 5, 10, 15, 20 and 25 m/s
twice; 12 frames each; rendered once into ``--drives`` and read back), never trained on and never
used by another benchmark. Every frame goes through :func:`roadbev_lab.evaluation.frames.evaluate` (the
registry's backend with its calibrated sigma, the attitude from the bag's IMU as the node reads it),
so each figure is the Table I metric: per drive, and over all drive frames (cell-weighted), next to
the 24 Table I frames (seeds 100000-100023). Writes ``benchmarks/results/drive_frames.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from benchmarks.common import RESULTS, ReplayBackend, eval_samples, machine_info, write_json
from benchmarks.training_drives import SPEEDS, VALIDATION_SEED_BASE, write_drive

DRIVES = 10
FRAMES = 12
SPACING_M = 2.0


def _scores(result: Any) -> dict[str, float]:
    m = result.metrics
    return {key: m[key] for key in ("abs_err_cm", "rmse_cm", "coverage_pct", "confident_wrong_pct", "cells")
            if key in m}


def run(checkpoints: list[Path], kind: str, drives: Path) -> dict[str, Any]:
    from roadbev_core.backends import create
    from roadbev_core.config import GridSpec
    from roadbev_lab.evaluation.evalbag import bag_frames
    from roadbev_lab.evaluation.frames import evaluate
    from roadbev_lab.training.datasets import LabelledFrames

    drives.mkdir(parents=True, exist_ok=True)
    bags = [write_drive(drives, i, FRAMES, SPACING_M, VALIDATION_SEED_BASE) for i in range(DRIVES)]
    grid = GridSpec()
    sets = []
    for i, bag in enumerate(bags):
        bag_grid, labelled = bag_frames(bag)
        sets.append((VALIDATION_SEED_BASE + i, SPEEDS[i % len(SPEEDS)], LabelledFrames(bag_grid, labelled, str(bag))))
    table1 = eval_samples(24, grid=grid)
    rows: list[dict[str, Any]] = []
    for path in checkpoints:
        backend = create(kind, grid, checkpoint=str(path))
        start = time.perf_counter()
        per_drive: list[dict[str, Any]] = []
        everything: list[tuple[Any, Any]] = []
        estimates: list[Any] = []
        for seed, speed, frames in sets:
            result = evaluate(backend, frames.samples, keep_estimates=True)
            per_drive.append({"seed": seed, "speed_mps": speed, **_scores(result)})
            everything.extend(frames.samples)
            estimates.extend(result.estimates or [])
        # all drive frames pooled: the estimates above scored once more, not the network run again
        pooled = _scores(evaluate(ReplayBackend(kind, grid, estimates, backend.needs_stereo), everything))
        row: dict[str, Any] = {"checkpoint": str(path), "drives": per_drive, "all_drive_frames": pooled,
               "table1": _scores(evaluate(backend, table1)), "seconds": round(time.perf_counter() - start, 1)}
        rows.append(row)
        print(f"{path}: drive frames {pooled['abs_err_cm']:.3f} cm, Table I {row['table1']['abs_err_cm']:.4f} cm; "
              + " ".join(f"{d['abs_err_cm']:.3f}" for d in per_drive), file=sys.stderr)
    return {"what": f"{kind} checkpoints on held-out drive frames and the Table I frames",
            "drives": {"seeds": [VALIDATION_SEED_BASE, VALIDATION_SEED_BASE + DRIVES - 1], "frames_each": FRAMES,
                       "speeds_mps": [SPEEDS[i % len(SPEEDS)] for i in range(DRIVES)]},
            "machine": machine_info(), "rows": rows}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoints", nargs="+", type=Path, required=True)
    parser.add_argument("--kind", choices=("stereo", "mono"), default="stereo")
    parser.add_argument("--drives", type=Path, default=Path(".cache/val_drives"), help="held-out drive bags (cache)")
    parser.add_argument("--out", type=Path, default=RESULTS / "drive_frames.json")
    args = parser.parse_args(argv)
    record = run(args.checkpoints, args.kind, args.drives)
    given = argv if argv is not None else sys.argv[1:]
    record["command"] = " ".join(["python -m benchmarks.bench_drive_frames", *given])
    write_json(args.out, record)
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
