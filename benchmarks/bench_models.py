"""Accuracy and speed of the learned backends (shipped checkpoints) on the fixed synthetic test set.

The test set is the scenes of seeds 100000 .. 100000 + N - 1 (disjoint from the training seeds,
which stay below 100000), rendered once and cached under ``--cache``. Each backend runs through
:func:`roadbev_core.evaluation.evaluate`, as ``roadbev eval`` does.

Run: ``.venv/bin/python -m benchmarks.bench_models [--frames 20] [--backends stereo mono]``;
writes ``benchmarks/results/models.json``.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import torch

from roadbev_core.backends import create
from roadbev_core.datasets import TEST_SEED_START, SyntheticSet, as_samples
from roadbev_core.evaluation import evaluate, json_safe

RESULTS = Path(__file__).resolve().parent / "results"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--backends", nargs="+", default=["stereo", "mono"])
    parser.add_argument("--checkpoint-dir", type=Path, help="use <dir>/roadbev_<kind>_lite.pt instead of the shipped")
    parser.add_argument("--cache", type=Path, default=Path(".cache") / "roadbev")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, default=RESULTS / "models.json")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    torch.set_flush_denormal(True)
    data = SyntheticSet(args.cache, range(TEST_SEED_START, TEST_SEED_START + args.frames), progress=True)
    results = []
    for name in args.backends:
        options = {}
        if args.checkpoint_dir:
            options["checkpoint"] = str(args.checkpoint_dir / f"roadbev_{name}_lite.pt")
        backend = create(name, data.grid, **options)
        t0 = time.perf_counter()
        result = evaluate(backend, as_samples(data))
        metrics = dict(result.metrics)
        metrics["wall_s"] = time.perf_counter() - t0
        metrics["checkpoint"] = str(backend.checkpoint)
        results.append(metrics)
        print(f"{name}: abs. err. {metrics['abs_err_cm']:.3f} cm, RMSE {metrics['rmse_cm']:.3f} cm, "
              f">0.5 cm {metrics['gt_0p5cm_pct']:.1f} %, {metrics['fps']:.2f} FPS", flush=True)
    payload = {
        "test_set": {"seeds": [TEST_SEED_START, TEST_SEED_START + args.frames - 1], "frames": args.frames},
        "machine": {"processor": platform.processor() or platform.machine(), "threads": args.threads},
        "results": results,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(json_safe(payload), indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
