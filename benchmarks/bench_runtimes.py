"""The learned backends in every inference runtime on the Table I frames, interleaved frame by frame.

Run (from the repository root)::

    .venv/bin/python -m benchmarks.bench_runtimes                      # 24 frames, stereo + mono
    .venv/bin/python -m benchmarks.bench_runtimes --frames 6 --kinds stereo --threads 1
    .venv/bin/python -m benchmarks.bench_runtimes --threads 1 --int8 stereo=/tmp/stereo_int8.onnx

Every (model, runtime) pair is created once (``stereo`` / ``mono`` with ``runtime`` = ``torch``,
``onnxruntime``, ``openvino``; with ``--int8 KIND=PATH`` also the int8 graph of ``roadbev export
--int8`` in each ONNX engine, rows ``<engine> int8``) and all of them run on frame i before any runs on frame i + 1, in
an order that rotates from frame to frame, so that a load change on a shared machine hits every
runtime alike. Accuracy is scored by :func:`roadbev_lab.evaluation.frames.evaluate` (the Table I
metrics of ``benchmarks.run_all``) on the estimates each runtime produced; FPS is the mean of
``estimate()`` over the frames after the first (the warm-up, as in ``evaluate``). The JSON also
gives each runtime's mean / max |elevation - torch's| and the issue's targets. Writes
``benchmarks/results/runtimes.json`` and ``runtimes.md``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import EVAL_SEED_BASE, RESULTS, ReplayBackend, eval_samples, machine_info, write_json
from roadbev_core.backends import Backend, BackendError, create
from roadbev_core.config import GridSpec
from roadbev_core.deploy import RUNTIMES
from roadbev_core.frame import Estimate
from roadbev_lab.evaluation.frames import evaluate

TARGET_SPEEDUP = 1.5  # the best CPU runtime against torch, stereo
TARGET_ACCURACY_CM = 0.01  # |abs. err. - torch's abs. err.| on the Table I frames


def run(frames: int, kinds: list[str], runtimes: list[str], threads: int | None,
        int8: dict[str, Path] | None = None) -> dict[str, Any]:
    """Render the frames, run every (kind, runtime) on them interleaved, score and time them;
    ``int8`` maps a kind to its int8 graph, run in every ONNX engine of ``runtimes`` too."""
    import torch

    torch.set_flush_denormal(True)
    if threads:
        torch.set_num_threads(threads)
    grid = GridSpec()
    t0 = time.perf_counter()
    samples = eval_samples(frames, grid=grid)
    render_s = time.perf_counter() - t0
    backends: dict[tuple[str, str], Backend] = {}
    skipped: dict[str, str] = {}
    pairs: list[tuple[str, str, str, dict[str, Any]]] = [(kind, runtime, runtime, {}) for kind in kinds
                                                         for runtime in runtimes]
    pairs += [(kind, f"{runtime} int8", runtime, {"checkpoint": str(path)})
              for kind, path in (int8 or {}).items() for runtime in runtimes if runtime != "torch"]
    for kind, label, runtime, options in pairs:
        try:
            t = time.perf_counter()
            backends[kind, label] = create(kind, grid, runtime=runtime, threads=threads, **options)
            print(f"{kind}/{label}: ready in {time.perf_counter() - t:.1f} s", file=sys.stderr)
        except BackendError as exc:
            skipped[f"{kind}/{label}"] = str(exc)
            print(f"skip {kind}/{label}: {exc}", file=sys.stderr)
    keys = list(backends)
    estimates: dict[tuple[str, str], list[Estimate]] = {key: [] for key in keys}
    seconds: dict[tuple[str, str], list[float]] = {key: [] for key in keys}
    load: list[float] = []
    for i, sample in enumerate(samples):
        order = keys[i % len(keys):] + keys[: i % len(keys)]  # rotate who goes first
        for key in order:
            start = time.perf_counter()
            estimate = backends[key].estimate(sample.frame)
            seconds[key].append(time.perf_counter() - start)
            estimates[key].append(estimate)
        load.append(os.getloadavg()[0])
        print(f"frame {i + 1}/{frames}: " + ", ".join(f"{k[0]}/{k[1]} {1e3 * seconds[k][-1]:.0f} ms" for k in keys)
              + f" (load {load[-1]:.1f})", file=sys.stderr)
    rows = []
    for key in keys:
        kind, runtime = key
        metrics = evaluate(ReplayBackend(kind, grid, estimates[key], kind == "stereo"), samples).metrics
        timed = seconds[key][1:] if len(seconds[key]) > 1 else seconds[key]
        stages: dict[str, float] = {}
        for estimate in estimates[key][1:] or estimates[key]:
            for stage, ms in estimate.timings_ms.items():
                stages[stage] = stages.get(stage, 0.0) + ms / max(len(timed), 1)
        reference = estimates.get((kind, "torch"))
        diff: dict[str, float | None] = {"mean_abs_diff_vs_torch_cm": None, "max_abs_diff_vs_torch_cm": None,
                                         "mean_sigma_diff_vs_torch_cm": None, "cells_estimated_by_one_only": None}
        if reference is not None:
            # over the cells both estimated; a cell one runtime answers and the other leaves NaN
            # (the visibility step can tip either way on a tiny difference) is counted apart
            both = [np.isfinite(a.elevation) & np.isfinite(b.elevation) for a, b in zip(estimates[key], reference,
                                                                                       strict=True)]
            d = [np.abs(a.elevation - b.elevation)[m] for a, b, m in zip(estimates[key], reference, both, strict=True)]
            s = [np.abs(a.uncertainty - b.uncertainty)[m] for a, b, m in zip(estimates[key], reference, both,
                                                                              strict=True)]
            one_only = sum(int((np.isfinite(a.elevation) != np.isfinite(b.elevation)).sum())
                           for a, b in zip(estimates[key], reference, strict=True))
            diff = {"mean_abs_diff_vs_torch_cm": float(np.concatenate(d).mean() * 100.0),
                    "max_abs_diff_vs_torch_cm": float(np.concatenate(d).max() * 100.0),
                    "mean_sigma_diff_vs_torch_cm": float(np.concatenate(s).mean() * 100.0),
                    "cells_estimated_by_one_only": one_only}
        rows.append({
            "backend": kind,
            "runtime": runtime,
            "abs_err_cm": metrics["abs_err_cm"],
            "rmse_cm": metrics["rmse_cm"],
            "gt_0p5cm_pct": metrics["gt_0p5cm_pct"],
            "coverage_pct": metrics["coverage_pct"],
            "within_1sigma_pct": metrics.get("within_1sigma_pct"),
            "within_2sigma_pct": metrics.get("within_2sigma_pct"),
            "estimate_ms_mean": 1e3 * float(np.mean(timed)),
            "estimate_ms_median": 1e3 * float(np.median(timed)),
            "fps": 1.0 / float(np.mean(timed)),
            "stage_ms": stages,
            **diff,
        })
    targets: dict[str, Any] = {}
    by = {(r["backend"], r["runtime"]): r for r in rows}
    for kind in kinds:
        base = by.get((kind, "torch"))
        others = [r for r in rows if r["backend"] == kind and r["runtime"] != "torch"]
        if base is None or not others:
            continue
        best = max(others, key=lambda r: r["fps"])
        targets[kind] = {
            "best_cpu_runtime": best["runtime"],
            "speedup_vs_torch": best["fps"] / base["fps"],
            "speedup_ok": best["fps"] / base["fps"] >= TARGET_SPEEDUP,
            "abs_err_change_cm": best["abs_err_cm"] - base["abs_err_cm"],
            "accuracy_ok": abs(best["abs_err_cm"] - base["abs_err_cm"]) < TARGET_ACCURACY_CM,
        }
    return {
        "what": "learned backends per inference runtime on the Table I frames, interleaved frame by frame",
        "command": " ".join(["python -m benchmarks.bench_runtimes", *sys.argv[1:]]),
        "machine": machine_info(),
        "load_average_per_frame": load,
        "frames": frames,
        "seeds": [EVAL_SEED_BASE, EVAL_SEED_BASE + frames - 1],
        "threads": threads,
        "render_s": render_s,
        "results": rows,
        "skipped": skipped,
        "targets": targets,
    }


def markdown(record: dict[str, Any]) -> str:
    """The rows as a markdown table (the one the docs quote, :mod:`benchmarks.doc_tables`)."""
    lines = [
        "| model | runtime | abs. err. (cm) | RMSE (cm) | >0.5 cm (%) | FPS | estimate mean / median (ms) "
        "| mean / max abs. diff. to torch (cm) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in record["results"]:
        diff = ("–" if r["mean_abs_diff_vs_torch_cm"] is None or r["runtime"] == "torch"
                else f"{r['mean_abs_diff_vs_torch_cm']:.5f} / {r['max_abs_diff_vs_torch_cm']:.4f}")
        lines.append(
            f"| {r['backend']} | {r['runtime']} | {r['abs_err_cm']:.3f} | {r['rmse_cm']:.3f} | {r['gt_0p5cm_pct']:.1f} "
            f"| {r['fps']:.2f} | {r['estimate_ms_mean']:.0f} / {r['estimate_ms_median']:.0f} | {diff} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_runtimes", description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=24, help="Table I frames (seeds 100000 upward; default 24)")
    parser.add_argument("--kinds", nargs="+", choices=("stereo", "mono"), default=["stereo", "mono"])
    parser.add_argument("--runtimes", nargs="+", choices=RUNTIMES, default=list(RUNTIMES))
    parser.add_argument("--threads", type=int, default=None, help="intra-op threads of every runtime (default torch's)")
    parser.add_argument("--int8", nargs="+", default=[], metavar="KIND=PATH",
                        help="int8 graphs of `roadbev export --int8` to run too, e.g. stereo=stereo_int8.onnx")
    parser.add_argument("--out", type=Path, default=RESULTS / "runtimes.json")
    args = parser.parse_args(argv)
    if args.frames < 2:
        parser.error("--frames must be >= 2 (the first frame is the warm-up)")
    if args.threads is not None and args.threads < 1:
        parser.error("--threads must be >= 1")
    int8: dict[str, Path] = {}
    for item in args.int8:
        kind, _, path = item.partition("=")
        if kind not in ("stereo", "mono") or not path:
            parser.error(f"--int8 takes KIND=PATH with KIND stereo or mono, got {item!r}")
        int8[kind] = Path(path)
    record = run(args.frames, args.kinds, args.runtimes, args.threads, int8)
    write_json(args.out, record)
    table = markdown(record)
    args.out.with_suffix(".md").write_text(table + "\n")
    print(table)
    print("targets:", record["targets"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
