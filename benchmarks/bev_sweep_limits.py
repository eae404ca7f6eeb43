"""What limits ``bev_sweep``'s accuracy: window smoothing and relief, against ``bm``.

Two measurements on the same frames:

* the smoothing floor: the ground truth itself averaged over ``bev_sweep``'s aggregation windows
  (per zone: far / middle / near rows), scored against the ground truth on the cells
  ``bev_sweep`` answers. No matcher that averages over those windows can do better on a surface
  that is not flat within them.
* error by local relief (max - min of the ground truth within 5 x 5 cells): where the road is
  smooth and where bumps, kerbs and potholes are, for ``bev_sweep`` and ``bm``.
* the error's tail, per backend: median, 95th percentile, the share of the summed error carried
  by the worst 5 % of cells, where the cells off by more than 1.5 cm lie (farthest third of the
  rows; patches of at least 20 connected cells), and the error of every frame.

Run (from the repository root)::

    .venv/bin/python -m benchmarks.bev_sweep_limits            # the Table I frames (24)
    .venv/bin/python -m benchmarks.bev_sweep_limits --tuning   # the tuning frames (16)

Writes ``benchmarks/results/bev_sweep_limits[_tuning].json``.
"""

from __future__ import annotations

import argparse
import itertools
import sys
from typing import Any, cast

import cv2
import numpy as np
import torch

from benchmarks.common import EVAL_SEED_BASE, RESULTS, machine_info, write_json
from benchmarks.tune_bev_sweep import TUNING_SEED_BASE
from roadbev_core.backends import RefinedBackend, create
from roadbev_core.backends.bev_sweep import BevSweep
from roadbev_core.box_filter import WindowSize, box_mean
from roadbev_core.config import GridSpec
from roadbev_lab.evaluation.frames import evaluate

RELIEF_BINS_CM = (0.0, 1.0, 2.0, 4.0, 8.0, float("inf"))
TAIL_CM = 1.5  # a "tail" cell: off by more than this
PATCH_CELLS = 20  # tail cells in a connected patch at least this large are a failed region, not noise
RELIEF_CELLS = 5


def zone_smoothed(truth: np.ndarray, sweep: BevSweep) -> np.ndarray:
    """[R, C] ground truth box-averaged over the sweep's aggregation window of each row's zone
    (labelled cells only; windows shrink at the grid's border, as in the sweep)."""
    p = sweep.params
    labelled = np.isfinite(truth)
    # [2, R, C]: the labelled heights (0 elsewhere) and the labelled mask; the ratio of their
    # window means is the mean over the labelled cells (the sweep's own box filter).
    planes = torch.from_numpy(np.stack([np.where(labelled, truth, 0.0), labelled]).astype(np.float32))

    def box(size: WindowSize) -> np.ndarray:
        values, weight = box_mean(planes, size).numpy()
        return cast("np.ndarray", values / np.maximum(weight, 1e-6))

    mid_start, near_start = sweep._zone_rows()
    out = box(p.aggregation_cells)
    out[:mid_start] = box(p.far_aggregation_cells)[:mid_start]
    out[near_start:] = box(p.near_aggregation_cells)[near_start:]
    return out


def local_relief_cm(truth: np.ndarray) -> np.ndarray:
    """[R, C] max - min (cm) of the labelled ground truth within RELIEF_CELLS x RELIEF_CELLS cells."""
    kernel = np.ones((RELIEF_CELLS, RELIEF_CELLS), np.uint8)
    high = cv2.dilate(np.where(np.isfinite(truth), truth, -np.inf).astype(np.float32), kernel)
    low = cv2.erode(np.where(np.isfinite(truth), truth, np.inf).astype(np.float32), kernel)
    return (high - low) * 100.0


def tail_stats(estimates: list[np.ndarray], truths: list[np.ndarray]) -> dict[str, Any]:
    """How much of one backend's error sits in few cells, and where those cells are."""
    errors = [np.abs(e - t) * 100.0 for e, t in zip(estimates, truths, strict=True)]  # [R, C] cm, NaN = none
    every = np.sort(np.concatenate([err[np.isfinite(err)] for err in errors]))
    worst = every[int(0.95 * every.size):]
    tail = [np.nan_to_num(err, nan=0.0) > TAIL_CM for err in errors]
    n_tail = sum(int(t.sum()) for t in tail)
    far_rows = tail[0].shape[0] // 3
    in_patches = 0
    for t in tail:
        _, _, stats, _ = cv2.connectedComponentsWithStats(t.astype(np.uint8), connectivity=8)
        areas = stats[1:, cv2.CC_STAT_AREA]
        in_patches += int(areas[areas >= PATCH_CELLS].sum())
    return {
        "median_cm": float(np.median(every)),
        "p95_cm": float(np.quantile(every, 0.95)),
        "worst_5pct_share_of_error_pct": float(100.0 * worst.sum() / every.sum()),
        "tail_cm": TAIL_CM,
        "tail_cells_pct": float(100.0 * n_tail / every.size),
        "tail_in_far_third_pct": float(100.0 * sum(int(t[:far_rows].sum()) for t in tail) / max(n_tail, 1)),
        "tail_in_patches_pct": float(100.0 * in_patches / max(n_tail, 1)),
        "per_frame_abs_err_cm": [float(np.nanmean(err)) for err in errors],
    }


def measure(samples: list[Any], grid: GridSpec) -> dict[str, Any]:
    """The smoothing floor and the relief table for bev_sweep and bm on ``samples``."""
    sweep = create("bev_sweep", grid)  # through the visibility and sigma step, as every benchmark scores it
    params = sweep.inner if isinstance(sweep, RefinedBackend) else sweep
    assert isinstance(params, BevSweep)
    truths = [s.truth.elevation for s in samples]
    estimates = {
        name: [e.elevation for e in evaluate(backend, samples, keep_estimates=True).estimates or []]
        for name, backend in (("bev_sweep", sweep), ("bm", create("bm", grid)))
    }
    floor, actual = [], []
    for truth, estimate in zip(truths, estimates["bev_sweep"], strict=True):
        answered = np.isfinite(truth) & np.isfinite(estimate)
        floor.append(np.abs(zone_smoothed(truth, params) - truth)[answered])
        actual.append(np.abs(estimate - truth)[answered])
    record: dict[str, Any] = {
        "smoothing_floor_cm": float(np.concatenate(floor).mean() * 100.0),
        "bev_sweep_abs_err_cm": float(np.concatenate(actual).mean() * 100.0),
        "relief_cells": RELIEF_CELLS,
        "relief": [],
        "tail": {name: tail_stats(est, truths) for name, est in estimates.items()},
    }
    reliefs = [local_relief_cm(t) for t in truths]
    totals = {
        name: sum(float(np.nansum(np.abs(e - t))) for e, t in zip(est, truths, strict=True))
        for name, est in estimates.items()
    }
    for lo, hi in itertools.pairwise(RELIEF_BINS_CM):
        row: dict[str, Any] = {"relief_cm": [lo, hi]}
        for name, est in estimates.items():
            labelled = answered = 0
            error = 0.0
            for e, t, r in zip(est, truths, reliefs, strict=True):
                in_bin = np.isfinite(t) & (r >= lo) & (r < hi)
                hit = in_bin & np.isfinite(e)
                labelled += int(in_bin.sum())
                answered += int(hit.sum())
                error += float(np.abs(e[hit] - t[hit]).sum())
            row[name] = {
                "coverage_pct": 100.0 * answered / labelled if labelled else None,
                "abs_err_cm": 100.0 * error / answered if answered else None,
                "share_of_error_pct": 100.0 * error / totals[name] if totals[name] else None,
            }
        record["relief"].append(row)
    return record


def main(argv: list[str] | None = None) -> int:
    torch.set_flush_denormal(True)  # in inference (cpu-sizing.md); set here, not at import
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bev_sweep_limits", description=__doc__.splitlines()[0])
    parser.add_argument("--tuning", action="store_true", help="the 16 tuning frames instead of the 24 Table I frames")
    parser.add_argument("--frames", type=int, default=None)
    args = parser.parse_args(argv)
    from roadbev_lab.synth import make_sample

    base = TUNING_SEED_BASE if args.tuning else EVAL_SEED_BASE
    frames = args.frames or (16 if args.tuning else 24)
    grid = GridSpec()
    samples = [make_sample(base + i, grid=grid) for i in range(frames)]
    record = {
        "command": " ".join(["python -m benchmarks.bev_sweep_limits", *sys.argv[1:]]),
        "machine": machine_info(),
        "seeds": [base, base + frames - 1],
        **measure(samples, grid),
    }
    print(
        f"smoothing floor {record['smoothing_floor_cm']:.3f} cm on the cells bev_sweep answers "
        f"(its error there {record['bev_sweep_abs_err_cm']:.3f} cm)"
    )
    for row in record["relief"]:
        lo, hi = row["relief_cm"]
        cells = "  ".join(
            f"{name} cov {row[name]['coverage_pct'] or 0:5.1f} % err {row[name]['abs_err_cm'] or 0:.3f} cm "
            f"({row[name]['share_of_error_pct'] or 0:4.1f} % of its error)"
            for name in ("bev_sweep", "bm")
        )
        print(f"relief {lo:g}-{hi:g} cm: {cells}")
    for name, tail in record["tail"].items():
        print(
            f"{name}: median {tail['median_cm']:.3f} cm, p95 {tail['p95_cm']:.2f} cm; the worst 5 % of cells carry "
            f"{tail['worst_5pct_share_of_error_pct']:.0f} % of the error; {tail['tail_cells_pct']:.1f} % of cells "
            f"off by > {TAIL_CM:g} cm, {tail['tail_in_far_third_pct']:.0f} % of them in the farthest third of rows, "
            f"{tail['tail_in_patches_pct']:.0f} % in patches of >= {PATCH_CELLS} cells"
        )
    sweep_frames = record["tail"]["bev_sweep"]["per_frame_abs_err_cm"]
    bm_frames = record["tail"]["bm"]["per_frame_abs_err_cm"]
    worse = [i for i, (a, b) in enumerate(zip(sweep_frames, bm_frames, strict=True)) if a > b]
    print(f"bev_sweep is worse than bm on {len(worse)} of {len(sweep_frames)} frames: "
          + ", ".join(f"seed {base + i} ({sweep_frames[i]:.2f} vs {bm_frames[i]:.2f} cm)" for i in worse))
    write_json(RESULTS / f"bev_sweep_limits{'_tuning' if args.tuning else ''}.json", record)
    return 0


if __name__ == "__main__":
    sys.exit(main())
