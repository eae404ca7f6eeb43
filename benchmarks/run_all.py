"""Every available backend on the same synthetic evaluation set: the paper's Table I for this data.

Run (from the repository root)::

    .venv/bin/python -m benchmarks.run_all            # default: 24 frames + robustness sweep
    .venv/bin/python -m benchmarks.run_all --quick    # smoke test: 3 frames, one level each
    .venv/bin/python -m benchmarks.run_all --ray auto # the backends as tasks on a Ray cluster (or --jobs N)

Writes ``benchmarks/results/table1.json`` and ``table1.md`` (abs. err., RMSE, >0.5 cm, FPS on
this machine, coverage, per-stage times, the uncertainty keys: error within 1/2/3 sigma,
confidently wrong cells, mean sigma), ``reliability.png`` (observed error quantile against
predicted sigma, per backend), ``band_error.png`` (abs. error per distance band, one
line per backend, like the paper's Fig. 9), and the robustness sweep
(:mod:`benchmarks.robustness`): ``robustness.json`` and ``robustness.png``.

Backends: ``bev_sweep``, ``sgbm``, ``bm`` always; the learned ones (``stereo`` and ``mono``,
RoadBEV in BEV; ``gwcnet`` and ``adabins``, the learned image-view baselines) when their
checkpoints exist (skipped with the reason otherwise). All run in one process on the same frames; the issue's
targets are checked on these numbers and recorded in the JSON.
"""

from __future__ import annotations

import argparse
import sys
import time
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from benchmarks.common import (
    EVAL_SEED_BASE,
    RESULTS,
    add_appearance_argument,
    add_executor_arguments,
    available_backends,
    eval_samples,
    executor_from,
    machine_info,
    scene_samples,
    write_json,
)
from roadbev_core.backends import create
from roadbev_core.config import GridSpec
from roadbev_lab.evaluation.frames import common_cell_errors, evaluate, format_table
from roadbev_lab.evaluation.metrics import N_BANDS, MetricAccumulator
from roadbev_lab.fleet.executors import Executor, SerialPool
from roadbev_lab.reports.figures import FigureError, reliability_figure
from roadbev_lab.synth.appearance import DEFAULT_APPEARANCE

DEFAULT_FRAMES = 24
# Table I's rows: the BEV methods (bev_sweep, RoadBEV-stereo / -mono) and the image-view ones
# (OpenCV's matchers, the learned baselines)
TABLE1_BACKENDS = ("bev_sweep", "sgbm", "bm", "gwcnet", "stereo", "adabins", "mono")
QUICK_FRAMES = 3


def markdown_table(rows: list[dict[str, Any]]) -> str:
    """The Table I rows as markdown."""

    def f(value: Any, digits: int) -> str:
        return "–" if value is None else f"{value:.{digits}f}"

    lines = [
        "| backend | abs. err. (cm) | RMSE (cm) | >0.5 cm (%) | coverage (%) | FPS | decode | projection | cost/network"
        " | post (ms) | error within 1σ / 2σ / 3σ (%) | confidently wrong (%) | mean σ (cm) | mean σ / RMSE"
        " | median / p95 abs. err. (cm) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for m in rows:
        s = m["stage_ms"]
        lines.append(
            f"| {m['backend']} | {f(m['abs_err_cm'], 3)} | {f(m['rmse_cm'], 3)} | {f(m['gt_0p5cm_pct'], 1)} "
            f"| {f(m['coverage_pct'], 1)} | {f(m['fps'], 1)} | {f(s['decode'], 1)} | {f(s['projection'], 1)} "
            f"| {f(s['cost_network'], 1)} | {f(s['post'], 1)} "
            f"| {f(m.get('within_1sigma_pct'), 1)} / {f(m.get('within_2sigma_pct'), 1)} "
            f"/ {f(m.get('within_3sigma_pct'), 1)} | {f(m.get('confident_wrong_pct'), 2)} "
            f"| {f(m.get('mean_sigma_cm'), 3)} | {f(_sharpness(m), 2)} "
            f"| {f(m.get('median_abs_err_cm'), 3)} / {f(m.get('p95_abs_err_cm'), 2)} |"
        )
    return "\n".join(lines)


# bev_sweep on Table I before the visibility step and the calibrated sigma (issue 17's baseline).
BEV_SWEEP_BEFORE = {"abs_err_cm": 0.407, "coverage_pct": 81.4}


def _sharpness(m: dict[str, Any]) -> float | None:
    """mean sigma / RMSE (None when either is missing)."""
    sigma, rmse = m.get("mean_sigma_cm"), m.get("rmse_cm")
    return sigma / rmse if sigma is not None and rmse else None


def uncertainty_targets(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Issue 17's targets per backend: confidently wrong <= 0.5 %, 90 <= within 2 sigma <= 98 %,
    mean sigma <= 1.5 x RMSE; bev_sweep's coverage and abs. error against its numbers before."""
    out: dict[str, Any] = {}
    for m in rows:
        cw, w2, sharp = m.get("confident_wrong_pct"), m.get("within_2sigma_pct"), _sharpness(m)
        out[m["backend"]] = {
            "confident_wrong_le_0p5": cw is not None and cw <= 0.5,
            "within_2sigma_90_98": w2 is not None and 90.0 <= w2 <= 98.0,
            "mean_sigma_le_1p5_rmse": sharp is not None and sharp <= 1.5,
        }
    sweep = next((m for m in rows if m["backend"] == "bev_sweep"), None)
    if sweep is not None:
        drop = BEV_SWEEP_BEFORE["coverage_pct"] - sweep["coverage_pct"]
        growth = sweep["abs_err_cm"] - BEV_SWEEP_BEFORE["abs_err_cm"]
        out["bev_sweep"].update({
            "before": BEV_SWEEP_BEFORE, "coverage_drop_points": drop, "coverage_drop_le_2": drop <= 2.0,
            "abs_err_growth_cm": growth, "abs_err_growth_le_0p02": growth <= 0.02,
        })
    return out


def check_targets(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The issue's targets on the measured rows: bev_sweep vs the better of sgbm and bm."""
    by_name = {m["backend"]: m for m in rows}
    if not {"bev_sweep", "sgbm", "bm"} <= set(by_name):
        return {"checked": False, "reason": "bev_sweep, sgbm and bm must all have run"}
    sweep = by_name["bev_sweep"]
    best = min((by_name["sgbm"], by_name["bm"]), key=lambda m: m["abs_err_cm"])
    gain = 1.0 - sweep["abs_err_cm"] / best["abs_err_cm"]
    return {
        "checked": True,
        "best_image_view": best["backend"],
        "abs_err_reduction_pct": 100.0 * gain,
        "abs_err_reduction_ok": gain >= 0.30,
        "coverage_ok": sweep["coverage_pct"] >= best["coverage_pct"],
        "faster_than_sgbm": sweep["fps"] > by_name["sgbm"]["fps"],
        "bev_sweep_fps_ge_10": sweep["fps"] >= 10.0,
    }


# (method, against) pairs compared on the cells both estimated: the training-free sweep against
# the classical matchers, each learned RoadBEV network against the learned image-view network of
# its kind (the paper's Table I question), and the learned image-view matcher against the classical
# ones (on the cells they answer: whether it is a real learned baseline).
COMMON_CELL_PAIRS: tuple[tuple[str, str], ...] = (
    ("bev_sweep", "sgbm"), ("bev_sweep", "bm"), ("stereo", "gwcnet"), ("mono", "adabins"),
    ("gwcnet", "sgbm"), ("gwcnet", "bm"),
)


def common_cell_comparison(elevations: dict[str, list[Any]], truths: list[Any]) -> dict[str, Any]:
    """Each pair of :data:`COMMON_CELL_PAIRS` that ran, on the cells both estimated
    (coverage-neutral), keyed ``"<method> vs <against>"``."""
    out: dict[str, Any] = {}
    for method, against in COMMON_CELL_PAIRS:
        if method not in elevations or against not in elevations:
            continue
        cells, method_cm, against_cm = common_cell_errors(elevations[method], elevations[against], truths)
        out[f"{method} vs {against}"] = {
            "method": method, "against": against, "cells": cells,
            "method_abs_err_cm": method_cm, "against_abs_err_cm": against_cm,
            "abs_err_reduction_pct": 100.0 * (1.0 - method_cm / against_cm) if cells else None,
        }
    return out


def common_cell_markdown(comparison: dict[str, Any]) -> str:
    """The common-cell comparison as a markdown table (empty when there is none)."""
    if not comparison:
        return ""
    lines = [
        "| method vs against | common cells | method's abs. err. (cm) | against's abs. err. (cm) | reduction (%) |",
        "|---|---|---|---|---|",
    ]
    for name, c in comparison.items():
        if not c["cells"]:
            continue
        lines.append(f"| {name} | {c['cells']} | {c['method_abs_err_cm']:.3f} | {c['against_abs_err_cm']:.3f} "
                     f"| {c['abs_err_reduction_pct']:.1f} |")
    return "\n".join(lines)


def flat_reference(truths: list[Any], grid: GridSpec) -> dict[str, float]:
    """The error of assuming a flat road (the reference plane, elevation 0, on every labelled cell):
    what a method adds over inverse perspective mapping's flat ground (the same metrics as the rows)."""
    metrics = MetricAccumulator(grid)
    for truth in truths:
        metrics.add(np.zeros(np.shape(truth), np.float32), truth)
    result = metrics.result()
    return {"abs_err_cm": result.abs_err_cm, "rmse_cm": result.rmse_cm, "gt_0p5cm_pct": result.gt_0p5cm_pct}


def flat_reference_line(reference: dict[str, float] | None) -> str:
    """The flat-road reference as a sentence for the table's text ("" without one)."""
    if not reference:
        return ""
    return (f"Assuming a flat road (elevation 0 on every labelled cell): {reference['abs_err_cm']:.3f} cm abs. err., "
            f"{reference['rmse_cm']:.3f} cm RMSE.")


def plot_bands(rows: list[dict[str, Any]], grid_x: tuple[float, float], path: Path, title: str) -> None:
    """Abs. error per distance band, one line per backend (the paper's Fig. 9)."""
    from roadbev_lab.reports.figures import new_figure

    x_min, x_max = grid_x
    width = (x_max - x_min) / N_BANDS
    centres = [x_min + (i + 0.5) * width for i in range(N_BANDS)]
    fig, ax = new_figure(figsize=(7.5, 4.2), dpi=120)
    markers = ["o", "s", "^", "D", "v", "P", "X", "*"]
    for i, m in enumerate(rows):
        values = [float("nan") if v is None else v for v in m["band_abs_err_cm"]]
        label = f"{m['backend']} (mean {m['abs_err_cm']:.3f} cm, {m['coverage_pct']:.0f} % cov.)"
        ax.plot(centres, values, marker=markers[i % len(markers)], ms=4, lw=1.6, label=label)
    ax.set_xlabel("distance ahead of the camera (m), band centre")
    ax.set_ylabel("mean abs. elevation error (cm)")
    ax.set_title(title, fontsize=10)
    ax.set_xlim(x_min, x_max)
    ax.set_ylim(bottom=0)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)


def _backend_row(name: str, *, samples: list[Any], grid: GridSpec, quiet: bool) -> tuple[dict[str, Any], list[Any]]:
    """One backend on the evaluation set: its metrics (with its parameters) and its elevations."""
    backend = create(name, grid)
    with tqdm(total=len(samples), desc=name, unit="frame", disable=quiet, file=sys.stderr) as bar:
        result = evaluate(backend, samples, progress=bar.update, keep_estimates=True)
    metrics = result.to_dict()
    if hasattr(backend, "describe"):
        metrics["parameters"] = backend.describe()
    return metrics, [e.elevation for e in result.estimates or []]


def run_table(
    frames: int, names: list[str], *, out_dir: Path, quiet: bool = False, scene_cache: str | None = None,
    appearance: str | None = None, executor: Executor | None = None,
) -> dict[str, Any]:
    """Render the evaluation set, run every backend on it (one task per backend on ``executor``,
    this process by default), write table1.{json,md}, band_error.png and reliability.png."""
    grid = GridSpec()  # the interface's default grid and the RSRD half-resolution rig
    t0 = time.perf_counter()
    if scene_cache:
        samples = scene_samples(range(EVAL_SEED_BASE, EVAL_SEED_BASE + frames), grid, scene_cache, appearance)
    else:
        with tqdm(total=frames, desc="render eval set", unit="frame", disable=quiet, file=sys.stderr) as bar:
            samples = eval_samples(frames, grid=grid, progress=bar.update, appearance=appearance)
    render_s = time.perf_counter() - t0
    pool = executor or SerialPool()
    # each backend's accuracy is the serial run's wherever it runs; its timing is that of the
    # machine it ran on, alongside whatever ran there too (executor in the record)
    done = pool.map(partial(_backend_row, samples=samples, grid=grid, quiet=quiet or pool.workers > 1), names)
    rows = [metrics for metrics, _ in done]
    elevations = {name: elevation for name, (_, elevation) in zip(names, done, strict=True)}
    table = format_table(rows)
    targets = check_targets(rows)
    truths = [s[1] if isinstance(s, tuple) else s.truth.elevation for s in samples]
    targets["uncertainty"] = uncertainty_targets(rows)
    targets["common_cells"] = common_cell_comparison(elevations, truths)
    targets["flat_reference"] = flat_reference(truths, grid)
    record = {
        "command": " ".join(["python -m benchmarks.run_all", *sys.argv[1:]]),
        "machine": machine_info(),
        "frames": frames,
        "seeds": [EVAL_SEED_BASE, EVAL_SEED_BASE + frames - 1],
        "appearance": appearance or DEFAULT_APPEARANCE,
        "render_s": render_s,
        "executor": pool.describe(),
        "results": rows,
        "targets": targets,
    }
    write_json(out_dir / "table1.json", record)
    common = common_cell_markdown(targets["common_cells"])
    flat = flat_reference_line(targets["flat_reference"])
    (out_dir / "table1.md").write_text(markdown_table(rows) + "\n" + (f"\n{common}\n" if common else "")
                                       + f"\n{flat}\n")
    title = f"Abs. error vs distance, {frames} synthetic frames"
    plot_bands(rows, (grid.x_min, grid.x_max), out_dir / "band_error.png", title)
    try:
        reliability_figure([(m["backend"], m.get("reliability") or []) for m in rows], out_dir / "reliability.png",
                           f"Reliability of sigma, {frames} synthetic frames")
    except FigureError as exc:  # no backend reported a sigma on enough cells
        print(f"reliability.png not drawn: {exc}")
    print(table)
    print("targets:", targets)
    return record


def main(argv: list[str] | None = None) -> int:
    torch.set_flush_denormal(True)  # in inference (cpu-sizing.md); set here, not at import
    parser = argparse.ArgumentParser(prog="python -m benchmarks.run_all", description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=None, help=f"evaluation frames (default {DEFAULT_FRAMES})")
    parser.add_argument("--quick", action="store_true", help=f"smoke test: {QUICK_FRAMES} frames, short sweep")
    parser.add_argument("--backends", default=None, help="comma-separated subset (default: all available)")
    parser.add_argument("--no-robustness", action="store_true", help="skip the robustness sweep")
    parser.add_argument("--out", default=str(RESULTS), help="results folder")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.add_argument("--scene-cache", default=None, metavar="DIR",
                        help="keep the rendered frames here for later runs (a SyntheticSet cache)")
    parser.add_argument(
        "--torch-threads", type=int, default=None, help="torch intra-op threads (default: torch's, = cores)"
    )
    add_appearance_argument(parser, "the frames' pavement and camera appearance")
    add_executor_arguments(parser, "backends run")
    args = parser.parse_args(argv)
    if args.torch_threads is not None:
        if args.torch_threads < 1:
            parser.error("--torch-threads must be >= 1")
        torch.set_num_threads(args.torch_threads)
    frames = args.frames or (QUICK_FRAMES if args.quick else DEFAULT_FRAMES)
    if frames < 2:
        parser.error("--frames must be >= 2 (the first frame is the timing warm-up)")
    wanted = args.backends.split(",") if args.backends else list(TABLE1_BACKENDS)
    status = available_backends(wanted)
    names = [n for n in wanted if not status[n]]
    for n in wanted:
        if status[n]:
            print(f"skipping {n}: {status[n]}", file=sys.stderr)
    if not names:
        print("no backend available", file=sys.stderr)
        return 2
    out_dir = Path(args.out)
    with executor_from(args, parser) as executor:
        record = run_table(frames, names, out_dir=out_dir, quiet=args.quiet, scene_cache=args.scene_cache,
                           appearance=args.appearance, executor=executor)
    record["skipped"] = {n: status[n] for n in wanted if status[n]}
    write_json(out_dir / "table1.json", record)
    if not args.no_robustness:
        from benchmarks.robustness import run_sweep

        run_sweep(names, quick=args.quick, out_dir=out_dir, quiet=args.quiet, appearance=args.appearance)
    return 0


if __name__ == "__main__":
    sys.exit(main())
