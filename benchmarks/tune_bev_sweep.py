"""The measurement behind ``bev_sweep``'s defaults: accuracy and coverage per configuration.

Runs on tuning frames (seeds 200,000+, disjoint from training 0..9,999 and from the evaluation
set 100,000+), each configuration against the same frames, with ``bm`` and ``sgbm`` for
reference. Error and coverage trade off (stricter confidence tests drop the worst cells), so read
the table as a curve.

Run: ``.venv/bin/python -m benchmarks.tune_bev_sweep [--frames 8]``; writes
``benchmarks/results/bev_sweep_tuning.json``.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

import torch

from benchmarks.common import RESULTS, machine_info, write_json
from roadbev_core.backends import create
from roadbev_lab.evaluation.frames import evaluate

TUNING_SEED_BASE = 200_000

# name, backend, options: one change at a time around the defaults, plus the references.
CONFIGS: list[tuple[str, str, dict[str, Any]]] = [
    ("defaults", "bev_sweep", {}),
    (
        "square windows 15 / 25 / 9, check 9 (before)",
        "bev_sweep",
        {"aggregation_cells": 15, "far_aggregation_cells": 25, "near_aggregation_cells": 9, "check_cells": 9},
    ),
    (
        "square windows 15 / 25 / 9, check 9, min_score 0.86",
        "bev_sweep",
        {"aggregation_cells": 15, "far_aggregation_cells": 25, "near_aggregation_cells": 9, "check_cells": 9,
         "min_score": 0.86},
    ),
    ("one window shape (21, 9)", "bev_sweep", {"far_aggregation_cells": (21, 9), "near_aggregation_cells": (21, 9)}),
    ("wide windows (9, 21) / (15, 35) / (5, 13)", "bev_sweep",
     {"aggregation_cells": (9, 21), "far_aggregation_cells": (15, 35), "near_aggregation_cells": (5, 13)}),
    ("near window (11, 5)", "bev_sweep", {"near_aggregation_cells": (11, 5)}),
    ("far window (41, 15)", "bev_sweep", {"far_aggregation_cells": (41, 15)}),
    ("check window (9, 5)", "bev_sweep", {"check_cells": (9, 5)}),
    ("ZNCC patch (1, 3), min_score 0.83", "bev_sweep", {"patch_cells": (1, 3), "min_score": 0.83}),
    ("no occlusion test", "bev_sweep", {"occlusion_clearance": 0.0}),
    ("no outlier test", "bev_sweep", {"max_deviation": 0.0}),
    ("no window check", "bev_sweep", {"max_disagreement": 0.0}),
    ("no window check, min_score 0.88", "bev_sweep", {"max_disagreement": 0.0, "min_score": 0.88}),
    ("window check 1.5 cm", "bev_sweep", {"max_disagreement": 0.015}),
    ("one window size (5)", "bev_sweep", {f"{zone}aggregation_cells": 5 for zone in ("", "far_", "near_")}),
    ("min_score 0.85", "bev_sweep", {"min_score": 0.85}),
    ("min_score 0.86", "bev_sweep", {"min_score": 0.86}),
    ("min_score 0.88", "bev_sweep", {"min_score": 0.88}),
    ("min_score 0.90", "bev_sweep", {"min_score": 0.90}),
    ("min_score 0.95", "bev_sweep", {"min_score": 0.95}),
    ("shiftable windows", "bev_sweep", {"shiftable_windows": True}),
    ("no blur", "bev_sweep", {"blur_sigma": 0.0}),
    ("no high-pass", "bev_sweep", {"highpass_sigma": 0.0}),
    ("0.5 cm sweep", "bev_sweep", {"z_step": 0.005}),
    ("1 cm sweep", "bev_sweep", {"z_step": 0.01}),
    ("4 cm sweep", "bev_sweep", {"z_step": 0.04}),
    ("1 x 2 samples per cell everywhere", "bev_sweep", {f"{zone}subsamples": (1, 2) for zone in ("", "far_", "near_")}),
    ("2 x 4 samples per cell everywhere", "bev_sweep", {f"{zone}subsamples": (2, 4) for zone in ("", "far_", "near_")}),
    ("bm", "bm", {}),
    ("bm block 9, uniqueness 10", "bm", {"block_size": 9, "uniqueness_ratio": 10}),
    ("bm block 15", "bm", {"block_size": 15}),
    ("sgbm", "sgbm", {}),
    ("sgbm 5-path, block 5, uniqueness 10", "sgbm", {"mode": "sgbm", "block_size": 5, "uniqueness_ratio": 10}),
]


def main(argv: list[str] | None = None) -> int:
    torch.set_flush_denormal(True)  # in inference (cpu-sizing.md); set here, not at import
    parser = argparse.ArgumentParser(prog="python -m benchmarks.tune_bev_sweep", description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=16, help="tuning frames (default 16)")
    args = parser.parse_args(argv)
    from roadbev_lab.synth import make_sample

    samples = [make_sample(TUNING_SEED_BASE + i) for i in range(args.frames)]
    rows = []
    for label, name, options in CONFIGS:
        m = evaluate(create(name, None, **options), samples).metrics
        row = {
            "config": label,
            "backend": name,
            "options": options,
            "abs_err_cm": m["abs_err_cm"],
            "rmse_cm": m["rmse_cm"],
            "gt_0p5cm_pct": m["gt_0p5cm_pct"],
            "coverage_pct": m["coverage_pct"],
            "pipeline_ms": m["pipeline_ms"],
        }
        rows.append(row)
        print(
            f"{label:<24} abs {row['abs_err_cm']:.3f} cm  rmse {row['rmse_cm']:.3f}  "
            f"coverage {row['coverage_pct']:.1f} %  {row['pipeline_ms']:.0f} ms",
            flush=True,
        )
    write_json(
        RESULTS / "bev_sweep_tuning.json",
        {
            "command": " ".join(["python -m benchmarks.tune_bev_sweep", *sys.argv[1:]]),
            "machine": machine_info(),
            "frames": args.frames,
            "seeds": [TUNING_SEED_BASE, TUNING_SEED_BASE + args.frames - 1],
            "results": rows,
        },
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
