"""The far field per band of 1 m: error, coverage and sigma honesty against the physical limit.

On rendered synthetic frames (the evaluation seeds, :data:`benchmarks.common.EVAL_SEED_BASE` up,
appearance ``--appearance``, default ``real-road``; the road's features placed in the far-field
window too: ``make_sample(far_grid=...)``) every backend that estimates the far field runs through
the pipeline with ``far_field.enabled`` (:func:`roadbev_lab.evaluation.frames.evaluate`, the code
of ``roadbev eval``), and per band of 1 m from the grid's near edge to the far field's far edge
this reports

* the mean absolute error (cm), the coverage (labelled cells answered, %), the share of errors
  within 2 sigma and the confidently wrong share (error > 3 sigma and > 1 cm, %), the mean sigma;
* a backend run with options (``bm:plane_parallax_px=16``) beside the same backend without
  (``bm``) is also compared with it on the cells both answered, band by band (``against``);
* the physical limit (:mod:`roadbev_core.far_field`): the mean absolute height error a disparity
  error of :data:`~roadbev_core.far_field.SUBPIXEL_PRECISION_PX` px makes at the band's centre on
  the RSRD rig at its mean pitch (``sqrt(2 / pi) * h * Z * sigma_d / (fx * B)``), and the ratio of
  the error to it; the length of road one image row covers there; the share of frames whose
  pitch keeps the band's centre inside the image.

Run: ``.venv/bin/python -m benchmarks.bench_far_field [--frames 100]
[--backends bm sgbm ensemble ensemble:sgbm.refine_width=21] [--appearance real-road]
[--out benchmarks/results/far_field.json]``; the table is on docs/results/backends.md
(``python -m benchmarks.doc_tables --write``).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from benchmarks.common import EVAL_SEED_BASE, RESULTS, add_appearance_argument, backend_spec, machine_info, write_json
from roadbev_core.config import GridSpec, RoadbevConfig, StereoCamera
from roadbev_core.far_field import SUBPIXEL_PRECISION_PX, far_cell_size, farthest_road_in_view, road_sampling
from roadbev_core.pipeline import Pipeline
from roadbev_lab.evaluation.frames import evaluate
from roadbev_lab.evaluation.metrics import BandAccumulator
from roadbev_lab.synth import RSRD_ATTITUDE, appearance_range, make_sample

BACKENDS = ("bm", "sgbm", "ensemble")
DEFAULT_FRAMES = 100
BAND_M = 1.0
# mean |e| of a zero-mean Gaussian error of 1-sigma s is sqrt(2 / pi) s
_MEAN_ABS = math.sqrt(2.0 / math.pi)


def band_physics(grid: GridSpec, camera: StereoCamera, pitch_rad: float, pitches: list[float], which: str
                 ) -> list[dict[str, Any]]:
    """Per band of :data:`BAND_M` of ``grid``: its range, the rig's ground sampling, disparity and
    limit at the band's centre at ``pitch_rad``, and the share of ``pitches`` (rad, one per frame)
    that keep that centre in view."""
    edges = BandAccumulator(grid, BAND_M).result()
    out = []
    for band in edges:
        lo, hi = float(band["x_from_m"]), float(band["x_to_m"])
        centre = 0.5 * (lo + hi)
        at = road_sampling(camera, pitch_rad, grid.base_height, centre)
        seen = [bool(road_sampling(camera, p, grid.base_height, centre).in_view[0]) for p in pitches]
        limit_cm = 100.0 * float(at.height_sigma_m[0])
        out.append({
            "grid": which, "cell_m": grid.resolution, "x_from_m": lo, "x_to_m": hi,
            "row_length_cm": 100.0 * float(at.row_length_m[0]), "disparity_px": float(at.disparity_px[0]),
            "limit_sigma_cm": limit_cm, "limit_abs_err_cm": _MEAN_ABS * limit_cm,
            "in_view_pct": 100.0 * sum(seen) / max(len(seen), 1),
        })
    return out


class Estimates(NamedTuple):
    """One backend's per-frame estimates: (elevation, sigma) on the grid and on the far-field grid."""

    near: list[tuple[np.ndarray, np.ndarray]]
    far: list[tuple[np.ndarray, np.ndarray]]


def run_backend(spec: str, config: RoadbevConfig, samples: list[Any], physics: list[dict[str, Any]]
                ) -> tuple[dict[str, Any], Estimates]:
    """One backend (``NAME[:OPTION=VALUE,...]``) over the samples: the near and far metrics and the
    bands (aligned with ``physics``), and its estimates."""
    name, options = backend_spec(spec)
    pipeline = Pipeline(config.with_params({"backend": name, **options}), configure_process=False)
    result = evaluate(pipeline, samples, keep_estimates=True)
    outputs = result.outputs or []
    near = BandAccumulator(config.grid, BAND_M)
    estimates = Estimates([], [])
    for output, sample in zip(outputs, samples, strict=True):
        near.add(output.estimate.elevation, output.estimate.uncertainty, sample.truth.elevation)
        estimates.near.append((output.estimate.elevation, output.estimate.uncertainty))
        if output.far is not None:
            estimates.far.append((output.far.elevation, output.far.uncertainty))
    far = result.metrics["far_field"]
    bands = []
    for band, limit in zip(near.result() + far["bands"], physics, strict=True):
        ratio = band["abs_err_cm"] / limit["limit_abs_err_cm"] if band["cells"] else math.nan
        bands.append({**band, "ratio_to_limit": ratio})
    timed = outputs[1:] or outputs
    keys = ("abs_err_cm", "coverage_pct", "within_2sigma_pct", "confident_wrong_pct", "mean_sigma_cm")
    return {
        "near": {k: result.metrics[k] for k in keys},
        "far": {k: far[k] for k in keys},
        "bands": bands,
        "near_ms": float(np.mean([o.timings_ms["estimate"] for o in timed])),
        "far_ms": float(np.mean([o.timings_ms["estimate_far"] for o in timed])),
    }, estimates


def common_cell_bands(config: RoadbevConfig, samples: list[Any], estimates: Estimates, reference: Estimates
                      ) -> list[dict[str, Any]]:
    """Per band (the grid's, then the far field's) on the labelled cells both ``estimates`` and
    ``reference`` answered: their count and each one's mean absolute error (cm)."""
    far_grid = config.far_grid
    assert far_grid is not None
    out = []
    for grid, mine, theirs, truths in ((config.grid, estimates.near, reference.near, [s.truth for s in samples]),
                                       (far_grid, estimates.far, reference.far, [s.far_truth for s in samples])):
        own, other = BandAccumulator(grid, BAND_M), BandAccumulator(grid, BAND_M)
        for (e, es), (r, rs), truth in zip(mine, theirs, truths, strict=True):
            both = np.isfinite(e) & np.isfinite(r)
            own.add(np.where(both, e, np.nan), es, truth.elevation)
            other.add(np.where(both, r, np.nan), rs, truth.elevation)
        for a, b in zip(own.result(), other.result(), strict=True):
            out.append({"x_from_m": a["x_from_m"], "x_to_m": a["x_to_m"], "cells": a["cells"],
                        "abs_err_cm": a["abs_err_cm"], "against_abs_err_cm": b["abs_err_cm"]})
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_far_field", description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=DEFAULT_FRAMES, help=f"frames (default {DEFAULT_FRAMES})")
    parser.add_argument("--backends", nargs="+", default=list(BACKENDS),
                        help=f"backends that estimate the far field, NAME[:OPTION=VALUE,...] (default "
                             f"{' '.join(BACKENDS)})")
    add_appearance_argument(parser, "the frames")
    parser.add_argument("--out", type=Path, default=RESULTS / "far_field.json", help="result JSON")
    args = parser.parse_args(argv)
    if args.frames < 1:
        parser.error("--frames must be >= 1")
    start = time.perf_counter()
    machine = machine_info()
    config = RoadbevConfig.from_params({"far_field.enabled": True})
    far_grid = config.far_grid
    assert far_grid is not None  # enabled above
    camera = StereoCamera.rsrd_half()
    drawn = appearance_range(args.appearance)
    seeds = range(EVAL_SEED_BASE, EVAL_SEED_BASE + args.frames)
    samples = [make_sample(seed, camera=camera, appearance=drawn, far_grid=far_grid) for seed in seeds]
    rendered = time.perf_counter() - start
    pitch = math.radians(RSRD_ATTITUDE["pitch_mean"])
    pitches = [s.frame.attitude.pitch for s in samples]
    physics = (band_physics(config.grid, camera, pitch, pitches, "near")
               + band_physics(far_grid, camera, pitch, pitches, "far"))
    backends: dict[str, Any] = {}
    estimates: dict[str, Estimates] = {}
    for name in args.backends:
        backends[name], estimates[name] = run_backend(name, config, samples, physics)
        plain = name.partition(":")[0]
        if plain != name and plain in estimates:  # the same backend without the options ran before
            backends[name]["against"] = {"backend": plain, "bands": common_cell_bands(config, samples, estimates[name],
                                                                                     estimates[plain])}
        far = backends[name]["far"]
        print(f"{name:<9} far field: abs. error {far['abs_err_cm']:.3f} cm, coverage {far['coverage_pct']:.1f} %, "
              f"confidently wrong {far['confident_wrong_pct']:.2f} %", flush=True)
    record = {
        "benchmark": "far_field",
        "command": " ".join(["python -m benchmarks.bench_far_field", *(argv if argv is not None else sys.argv[1:])]),
        "frames": args.frames,
        "seeds": [seeds[0], seeds[-1]],
        "appearance": args.appearance,
        "grid": config.grid.to_dict(),
        "far_grid": far_grid.to_dict(),
        "rig": {
            "fx_px": camera.fx, "baseline_m": camera.baseline, "image": f"{camera.width}x{camera.height}",
            "base_height_m": config.grid.base_height, "pitch_deg": RSRD_ATTITUDE["pitch_mean"],
            "subpixel_precision_px": SUBPIXEL_PRECISION_PX,
            "farthest_in_view_m": farthest_road_in_view(camera, pitch, config.grid.base_height),
            "far_cell_m": far_cell_size(camera, pitch, config.grid.base_height, far_grid.x_min, far_grid.x_max,
                                        far_grid.y_max - far_grid.y_min),
        },
        "bands": physics,
        "backends": backends,
        "render_s": rendered,
        "seconds": time.perf_counter() - start,
        "machine": machine,
    }
    write_json(args.out, record)
    print(f"written {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
