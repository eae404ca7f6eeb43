"""GwcNet-lite's ``max_sigma_px`` on the tuning scenes, with the classical matchers beside it.

Each limit's row also holds GwcNet-lite against ``sgbm`` and ``bm`` on the cells both answered
(``vs_sgbm``, ``vs_bm``): its error where the classical matcher has one, whatever else it answers.

The tuning scenes (seeds 200,000+, :data:`benchmarks.tune_bev_sweep.TUNING_SEED_BASE`) are
disjoint from the training seeds and from the Table I frames. Each limit's abs. error and
coverage, and ``sgbm``'s and ``bm``'s, go to ``benchmarks/results/tune_gwcnet.json``; the default
(:data:`roadbev_core.backends.gwcnet.DEFAULT_MAX_SIGMA_PX`) is chosen from it.

Run: ``.venv/bin/python -m benchmarks.tune_gwcnet [--frames 16] [--limits 0 2.5 2 1.7 1.5 1.3]
[--checkpoint PATH]`` (default: the shipped checkpoint).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from benchmarks.common import RESULTS, machine_info, scene_samples, write_json
from benchmarks.tune_bev_sweep import TUNING_SEED_BASE
from roadbev_core.backends import create
from roadbev_core.config import GridSpec
from roadbev_lab.evaluation.frames import common_cell_errors, evaluate


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.tune_gwcnet", description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=16, help="tuning scenes (default 16)")
    parser.add_argument("--limits", type=float, nargs="+", default=[0.0, 2.5, 2.0, 1.7, 1.5, 1.3],
                        help="max_sigma_px values (0: no limit)")
    parser.add_argument("--checkpoint", default=None, metavar="PATH",
                        help="GwcNet-lite checkpoint to tune (default: the shipped one)")
    parser.add_argument("--scene-cache", default=".cache/scenes", metavar="DIR")
    parser.add_argument("--out", default=str(RESULTS / "tune_gwcnet.json"))
    args = parser.parse_args(argv)
    grid = GridSpec()
    samples = scene_samples(range(TUNING_SEED_BASE, TUNING_SEED_BASE + args.frames), grid, args.scene_cache)
    rows: list[dict[str, Any]] = []
    runs: list[tuple[str, dict[str, Any]]] = [("sgbm", {}), ("bm", {})]
    checkpoint = {"checkpoint": args.checkpoint} if args.checkpoint else {}
    runs += [("gwcnet", {"max_sigma_px": limit}) for limit in args.limits]
    truths = [truth for _, truth in samples]
    classical: dict[str, list[Any]] = {}
    for name, options in runs:
        evaluated = evaluate(create(name, grid, **options, **(checkpoint if name == "gwcnet" else {})), samples,
                             keep_estimates=True)
        elevations = [e.elevation for e in evaluated.estimates or []]
        result = evaluated.to_dict()
        row = {"backend": name, **options, "abs_err_cm": result["abs_err_cm"], "coverage_pct": result["coverage_pct"],
               "rmse_cm": result["rmse_cm"]}
        if name == "gwcnet":  # against each classical matcher on the cells that matcher answered too
            for other, theirs in classical.items():
                cells, ours_cm, theirs_cm = common_cell_errors(elevations, theirs, truths)
                row[f"vs_{other}"] = {"cells": cells, "abs_err_cm": ours_cm, f"{other}_abs_err_cm": theirs_cm}
        else:
            classical[name] = elevations
        rows.append(row)
        print(rows[-1], flush=True)
    write_json(Path(args.out), {
        "command": " ".join(["python -m benchmarks.tune_gwcnet", *(argv if argv is not None else sys.argv[1:])]),
        "machine": machine_info(), "frames": args.frames, "checkpoint": args.checkpoint or "shipped",
        "seeds": [TUNING_SEED_BASE, TUNING_SEED_BASE + args.frames - 1], "rows": rows,
    })
    return 0


if __name__ == "__main__":
    sys.exit(main())
