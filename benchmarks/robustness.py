"""Robustness sweep: abs. error and coverage of each backend vs one perturbation at a time.

Perturbations, applied to clean rendered frames (seeds ``EVAL_SEED_BASE + 1000 + i``, read noise
0.5 DN, no gain mismatch, lossless):

* ``noise_sigma``: extra Gaussian read noise on both images (8-bit digital numbers);
* ``gain_mismatch``: the right image's gain is (1 + g) times the left's;
* ``row_offset_px``: the right image moved down by this many pixels (bilinear, sub-pixel): a
  rectification residual, which real stereo calibrations leave at a few tenths of a pixel and
  the renderer never does;
* ``jpeg_quality``: both images JPEG-compressed at this quality (0 = lossless);
* ``pitch_bias_deg``: the attitude given to the backend is off in pitch (an IMU bias);
* ``base_height_error_m``: the backend assumes a camera height off by this much.

Run via ``python -m benchmarks.run_all`` (or ``python -m benchmarks.robustness [--quick]``);
writes ``benchmarks/results/robustness.json`` and ``robustness.png``.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch

from benchmarks.common import EVAL_SEED_BASE, RESULTS, add_appearance_argument, machine_info, write_json
from roadbev_core.backends import create
from roadbev_core.config import GridSpec
from roadbev_core.frame import Frame
from roadbev_core.geometry import Attitude
from roadbev_lab.evaluation.frames import evaluate
from roadbev_lab.synth.appearance import DEFAULT_APPEARANCE
from roadbev_lab.synth.render import shift_rows

# perturbation -> levels (the unperturbed level included)
LEVELS: dict[str, list[float]] = {
    "noise_sigma": [0.0, 2.0, 4.0, 8.0],
    "gain_mismatch": [0.0, 0.05, 0.1, 0.2],
    "row_offset_px": [-0.5, -0.25, 0.0, 0.25, 0.5],
    "jpeg_quality": [0.0, 90.0, 70.0, 50.0],
    "pitch_bias_deg": [-0.5, -0.25, 0.0, 0.25, 0.5],
    "base_height_error_m": [-0.03, 0.0, 0.03],
}
UNITS = {
    "noise_sigma": "added noise sigma (DN)",
    "gain_mismatch": "right/left gain - 1",
    "row_offset_px": "right image moved down (px)",
    "jpeg_quality": "JPEG quality (0 = lossless)",
    "pitch_bias_deg": "pitch bias (deg)",
    "base_height_error_m": "base-height error (m)",
}
DEFAULT_FRAMES = 6
QUICK_FRAMES = 2


def _noisy(image: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    noisy = image.astype(np.float32) + rng.normal(0.0, sigma, image.shape).astype(np.float32)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


def _jpeg(image: np.ndarray, quality: int) -> np.ndarray:
    ok, data = cv2.imencode(".jpg", cv2.cvtColor(image, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    decoded = cv2.imdecode(data, cv2.IMREAD_COLOR)
    if decoded is None:
        raise RuntimeError("JPEG decoding failed")
    return cv2.cvtColor(decoded, cv2.COLOR_BGR2RGB)


def perturb(frame: Frame, kind: str, level: float, seed: int) -> Frame:
    """``frame`` with one perturbation applied (image ones only; geometry ones act on the backend)."""
    rng = np.random.default_rng(seed)
    right = frame.right
    if right is None:
        raise ValueError("the robustness sweep needs stereo frames")
    if kind == "noise_sigma" and level > 0:
        return replace(frame, left=_noisy(frame.left, level, rng), right=_noisy(right, level, rng))
    if kind == "gain_mismatch" and level != 0:
        gained = np.clip(right.astype(np.float32) * (1.0 + level), 0, 255).astype(np.uint8)
        return replace(frame, right=gained)
    if kind == "row_offset_px" and level != 0:
        return replace(frame, right=shift_rows(right, level))
    if kind == "jpeg_quality" and level > 0:
        return replace(frame, left=_jpeg(frame.left, int(level)), right=_jpeg(right, int(level)))
    if kind == "pitch_bias_deg" and level != 0:
        roll, pitch = frame.attitude.degrees
        return replace(frame, attitude=Attitude.from_degrees(roll, pitch + level))
    return frame


def clean_samples(
    n_frames: int, progress: Callable[[int], Any] | None = None, appearance: str | None = None
) -> list[tuple[Frame, np.ndarray]]:
    """Rendered frames for the sweep (a mix of roads with features, low noise, no JPEG).

    Their appearance spans the range ``appearance`` names (``roadbev_lab.synth.APPEARANCE_NAMES``;
    None: the default range) from its weak to its strong end, evenly in frame order; ``clean``
    leaves them the generator's own Lambertian pavement and a clean camera.
    """
    from roadbev_lab.synth import RoadConfig, appearance_range, make_sample

    roads = [
        RoadConfig(road_class=c, features=f, noise_sigma=0.5, gain_mismatch=0.0, jpeg_quality=None)
        for c, f in (("C", ("pothole",)), ("B", ("speed_bump",)), ("D", ("crack", "patch")))
    ]
    span = appearance_range(appearance)
    out = []
    for i in range(n_frames):
        road = roads[i % len(roads)]
        if span is not None:
            road = span.at(i / max(n_frames - 1, 1)).apply(road)
        s = make_sample(EVAL_SEED_BASE + 1000 + i, road=road)
        out.append((s.frame, s.truth.elevation))
        if progress is not None:
            progress(1)
    return out


def run_sweep(
    names: list[str], *, quick: bool, out_dir: Path = RESULTS, quiet: bool = False, appearance: str | None = None
) -> dict[str, Any]:
    """Run every backend over every perturbation level; write robustness.{json,png}."""
    from tqdm import tqdm

    frames = QUICK_FRAMES if quick else DEFAULT_FRAMES
    levels = {k: [v[0], v[-1]] if quick else v for k, v in LEVELS.items()}
    with tqdm(total=frames, desc="render robustness set", disable=quiet, file=sys.stderr) as bar:
        samples = clean_samples(frames, bar.update, appearance)
    grid = GridSpec()
    results: dict[str, Any] = {}
    total = sum(len(v) for v in levels.values()) * len(names)
    with tqdm(total=total, desc="robustness", disable=quiet, file=sys.stderr) as bar:
        for kind, values in levels.items():
            entry: dict[str, Any] = {"levels": values, "unit": UNITS[kind]}
            for name in names:
                errs, covs = [], []
                for level in values:
                    backend_grid = grid
                    if kind == "base_height_error_m":
                        backend_grid = grid.with_overrides(base_height=grid.base_height + level)
                    backend = create(name, backend_grid)
                    perturbed = [(perturb(f, kind, level, 7 + i), t) for i, (f, t) in enumerate(samples)]
                    m = evaluate(backend, perturbed).metrics
                    errs.append(m["abs_err_cm"])
                    covs.append(m["coverage_pct"])
                    bar.update(1)
                entry[name] = {"abs_err_cm": errs, "coverage_pct": covs}
            results[kind] = entry
    record = {
        # the module that was run (run_all or this one) with its arguments
        "command": " ".join([f"python -m benchmarks.{Path(sys.argv[0]).stem}", *sys.argv[1:]]),
        "machine": machine_info(),
        "frames": frames,
        "seeds": [EVAL_SEED_BASE + 1000, EVAL_SEED_BASE + 1000 + frames - 1],
        "appearance": appearance or DEFAULT_APPEARANCE,
        "sweep": results,
    }
    write_json(out_dir / "robustness.json", record)
    plot(results, names, out_dir / "robustness.png", frames)
    return record


def plot(results: dict[str, Any], names: list[str], path: Path, frames: int) -> None:
    """Abs. error (top) and coverage (bottom) vs each perturbation, one line per backend."""
    from roadbev_lab.reports.figures import new_figure

    kinds = list(results)
    fig, axes = new_figure(2, len(kinds), figsize=(3.3 * len(kinds), 5.6), dpi=110)
    markers = ["o", "s", "^", "D", "v"]
    for col, kind in enumerate(kinds):
        entry = results[kind]
        x = entry["levels"]
        labels = [("lossless" if v == 0 else f"{v:g}") for v in x] if kind == "jpeg_quality" else None
        xs = list(range(len(x))) if labels else x
        for i, name in enumerate(names):
            err = [math.nan if v is None else v for v in entry[name]["abs_err_cm"]]
            cov = [math.nan if v is None else v for v in entry[name]["coverage_pct"]]
            axes[0, col].plot(xs, err, marker=markers[i % len(markers)], ms=4, label=name)
            axes[1, col].plot(xs, cov, marker=markers[i % len(markers)], ms=4, label=name)
        for row in (0, 1):
            axes[row, col].grid(True, alpha=0.3)
            if labels:
                axes[row, col].set_xticks(xs, labels)
        axes[0, col].set_ylim(bottom=0)
        axes[1, col].set_ylim(0, 102)  # same coverage scale everywhere: no exaggerated dips
        axes[1, col].set_xlabel(entry["unit"], fontsize=9)
    axes[0, 0].set_ylabel("mean abs. error (cm)")
    axes[1, 0].set_ylabel("coverage (%)")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f"Robustness: one perturbation at a time ({frames} synthetic frames)", fontsize=11)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)


def main(argv: list[str] | None = None) -> int:
    torch.set_flush_denormal(True)  # in inference (cpu-sizing.md); set here, not at import
    parser = argparse.ArgumentParser(prog="python -m benchmarks.robustness", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 frames, two levels per perturbation")
    parser.add_argument("--backends", default="bev_sweep,sgbm,bm", help="comma-separated backends")
    parser.add_argument("--out", default=str(RESULTS), help="results folder")
    add_appearance_argument(parser, "the frames (spanning the range, instead of clean ones)")
    args = parser.parse_args(argv)
    run_sweep(args.backends.split(","), quick=args.quick, out_dir=Path(args.out), appearance=args.appearance)
    return 0


if __name__ == "__main__":
    sys.exit(main())
