"""Accuracy and speed of the learned backends (shipped checkpoints) on the fixed synthetic test set.

The test set is the scenes of seeds 100000 .. 100000 + N - 1 (disjoint from the training seeds,
which stay below 100000), rendered once and cached under ``--cache``. Each backend runs through
:func:`roadbev_lab.evaluation.frames.evaluate`, as ``roadbev eval`` does.

Besides the paper's metrics it reports the abs. error left after removing, per frame, the
median of the error (an elevation offset) or its least-squares plane (offset, grade and cross
slope): what part of a model's error is the road plane's position relative to the camera, which
one camera can only infer from perspective, rather than the relief on it.

Run: ``.venv/bin/python -m benchmarks.bench_models [--frames 20] [--backends stereo mono]``;
writes ``benchmarks/results/models.json``.
"""

from __future__ import annotations

import argparse
import platform
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch

from benchmarks.common import add_appearance_argument
from roadbev_core.backends import create
from roadbev_core.backends.learned import LearnedBackend
from roadbev_core.config import GridSpec
from roadbev_core.frame import Frame
from roadbev_lab.evaluation.frames import evaluate, to_json
from roadbev_lab.training.datasets import TEST_SEED_START, SyntheticSet, as_samples

RESULTS = Path(__file__).resolve().parent / "results"


def kept_truths(
    samples: Iterable[tuple[Frame, np.ndarray]], truths: list[np.ndarray]
) -> Iterator[tuple[Frame, np.ndarray]]:
    """Pass ``samples`` through, appending each truth to ``truths`` (scenes are read once)."""
    for frame, truth in samples:
        truths.append(truth)
        yield frame, truth


def plane_removed_errors(estimates: list[np.ndarray], truths: list[np.ndarray], grid: GridSpec) -> dict[str, float]:
    """Mean abs. error (cm) after removing each frame's error offset (median) or error plane (least squares)."""
    x = grid.x_max - (np.arange(grid.n_rows) + 0.5) * grid.resolution
    y = grid.y_max - (np.arange(grid.n_cols) + 0.5) * grid.resolution
    xx, yy = np.meshgrid(x, y, indexing="ij")  # [R, C] cell centres
    offset, plane = [], []
    for estimate, truth in zip(estimates, truths, strict=True):
        error = (estimate - truth).astype(np.float64)
        seen = np.isfinite(error)
        if seen.sum() < 3:
            continue
        e = error[seen]
        offset.append(np.abs(e - np.median(e)))
        design = np.stack([np.ones_like(e), xx[seen], yy[seen]], axis=1)  # [N, 3]
        coeffs, *_ = np.linalg.lstsq(design, e, rcond=None)
        plane.append(np.abs(e - design @ coeffs))
    return {
        "offset_removed_abs_err_cm": float(np.concatenate(offset).mean() * 100.0) if offset else float("nan"),
        "plane_removed_abs_err_cm": float(np.concatenate(plane).mean() * 100.0) if plane else float("nan"),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--backends", nargs="+", default=["stereo", "mono"])
    parser.add_argument("--checkpoint-dir", type=Path, help="use <dir>/roadbev_<kind>_lite.pt instead of the shipped")
    parser.add_argument("--cache", type=Path, default=Path(".cache") / "roadbev")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, default=RESULTS / "models.json")
    add_appearance_argument(parser, "the test scenes' pavement and camera appearance")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    torch.set_flush_denormal(True)
    data = SyntheticSet(args.cache, range(TEST_SEED_START, TEST_SEED_START + args.frames), progress=True,
                        appearance=args.appearance)
    results = []
    for name in args.backends:
        options: dict[str, Any] = {}
        if args.checkpoint_dir:
            options["checkpoint"] = str(args.checkpoint_dir / f"roadbev_{name}_lite.pt")
        backend = create(name, data.grid, **options)
        t0 = time.perf_counter()
        truths: list[np.ndarray] = []
        result = evaluate(backend, kept_truths(as_samples(data), truths), keep_estimates=True)
        metrics = dict(result.metrics)
        metrics["wall_s"] = time.perf_counter() - t0
        metrics.update(plane_removed_errors([e.elevation for e in result.estimates or []], truths, data.grid))
        metrics["checkpoint"] = str(backend.checkpoint if isinstance(backend, LearnedBackend) else None)
        results.append(metrics)
        print(f"{name}: abs. err. {metrics['abs_err_cm']:.3f} cm, RMSE {metrics['rmse_cm']:.3f} cm, "
              f">0.5 cm {metrics['gt_0p5cm_pct']:.1f} %, {metrics['fps']:.2f} FPS; without each frame's error "
              f"offset {metrics['offset_removed_abs_err_cm']:.3f} cm, "
              f"plane {metrics['plane_removed_abs_err_cm']:.3f} cm",
              flush=True)
    payload = {
        "test_set": {"seeds": [TEST_SEED_START, TEST_SEED_START + args.frames - 1], "frames": args.frames,
                     "appearance": args.appearance},
        "machine": {"processor": platform.processor() or platform.machine(), "threads": args.threads},
        "results": results,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(to_json(payload))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
