"""Real-frame benchmark: every backend on bags made from the three KITTI frames.

The frames (at ``KITTI``, beside the repository; :func:`roadbev_lab.data.kitti.load_frames`) are
a *test set*: nothing is tuned on them. For each frame this script does what a user with a LiDAR would do:

1. fit the camera's roll, pitch and height over the road robustly on the ground-truth points
   under the window (``roadbev_lab.data.kitti.fit_road_pose``): ``base_height`` and the attitude the
   IMU message of the bag carries (these frames come without an IMU; the fitted road plane is the
   reference, so the road is level by construction);
2. write a recording (stereo pair, CameraInfos, IMU, the ground-truth points as a PointCloud2 —
   the Velodyne scan with its ``/tf_static``, or the disparity map's points in the left optical
   frame) and run ``roadbev label`` on it (``roadbev_lab.data.labelbag.label_bag``, the same road-surface
   test and per-cell mean as for any drive);
3. run every backend through ``roadbev_lab.evaluation.frames.evaluate`` on the labelled bag, and score
   the flat prior (elevation 0 everywhere: the fitted plane) on the same cells.

Window: x 6.5-18.5 m, y -2..2 m, 0.1 m cells (KITTI cameras look horizontally from ~1.65 m, so the
nearest road in the images is ~5.9 m away). The GT's own noise is about 1 cm per distance band (a
9x9 ZNCC of the right image against the left around each GT road point): differences below ~1 cm are
within it; coverage, bias, gross failures and whether sigma is honest are what these frames measure.

Run: ``python -m benchmarks.bench_kitti`` -> ``benchmarks/results/kitti.json`` (+ a Markdown
table on stdout).
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from benchmarks.common import RESULTS, machine_info, write_json
from roadbev_core.config import GridSpec
from roadbev_lab.data.kitti import KittiFrame, RoadPose, fit_road_pose, load_frames

KITTI = Path(__file__).resolve().parents[1].parent / "shared" / "realdata" / "kitti"
WINDOW = GridSpec(x_min=6.5, x_max=18.5, y_min=-2.0, y_max=2.0, resolution=0.1, base_height=1.65)
BACKENDS = ("bev_sweep", "bm", "sgbm", "stereo", "mono")
STAMP_NS = 1_317_000_000_000_000_000
GT_NOISE_CAVEAT = (
    "The ground truth's own elevation error is about 1 cm per distance band on these frames "
    "(a 9x9 ZNCC of the right image against the left around each ground-truth road point); "
    "differences below ~1 cm are within it. "
    "Coverage, bias, gross failures and the honesty of sigma are what these frames measure."
)


def frame_grid(frame: KittiFrame) -> tuple[GridSpec, RoadPose]:
    """The window with ``base_height`` fitted on the frame's GT points (mm rounding)."""
    cam = frame.points @ frame.rotation.T + frame.translation
    pose = fit_road_pose(cam, WINDOW)
    return WINDOW.with_overrides(base_height=round(pose.base_height, 3)), pose


def labelled_bag(frame: KittiFrame, workdir: Path) -> tuple[Path, GridSpec, RoadPose, dict[str, Any]]:
    """Recording of one frame -> ``label_bag`` -> the evaluation bag, its grid and the fit."""
    from msg_bridge.tf import StaticTransform
    from roadbev_core.attitude import quaternion_from_rotation
    from roadbev_core.geometry import rotation_from_rpy
    from roadbev_lab.data.labelbag import RecordedFrame, label_bag, write_recording
    from roadbev_lab.data.lidar_labels import LabelConfig

    grid, pose = frame_grid(frame)
    q = quaternion_from_rotation(rotation_from_rpy(pose.attitude.roll, pose.attitude.pitch, 0.0))
    src = workdir / f"{frame.name}_recording.mcap"
    dst = workdir / f"{frame.name}.mcap"
    transforms = []
    if frame.points_frame != "stereo_left_optical_frame":
        transforms.append(
            StaticTransform("stereo_left_optical_frame", frame.points_frame, frame.rotation, frame.translation)
        )
    write_recording(
        src,
        frame.camera,
        [RecordedFrame(STAMP_NS, frame.left, frame.right)],
        imu=[(STAMP_NS, q)],
        scans=[(STAMP_NS, frame.points_frame, frame.points)],
        static_transforms=transforms,
    )
    report = label_bag(src, dst, grid=grid, config=LabelConfig())
    info = {
        "labelled_cells_pct": report.mean_labelled_pct,
        "rejected_points": report.rejected_points,
        "plane_offset_cm": report.plane_offset_cm,
    }
    return dst, grid, pose, info


def _scores(estimate: np.ndarray, sigma: np.ndarray, truth: np.ndarray) -> dict[str, Any]:
    """Bias, flat prior on the covered cells and confident_wrong_pct of one frame."""
    labelled = np.isfinite(truth)
    both = labelled & np.isfinite(estimate)
    err = estimate[both] - truth[both]
    out: dict[str, Any] = {
        "bias_cm": 100.0 * float(err.mean()) if err.size else math.nan,
        "flat_prior_on_covered_cells_cm": 100.0 * float(np.abs(truth[both]).mean()) if both.any() else math.nan,
    }
    with_sigma = both & np.isfinite(sigma)
    if with_sigma.any():
        e = np.abs(estimate[with_sigma] - truth[with_sigma])
        s = sigma[with_sigma]
        out["within_3sigma_pct"] = 100.0 * float((e <= 3 * s).mean())
        out["confident_wrong_pct"] = 100.0 * float(((e > 3 * s) & (e > 0.01)).mean())
        out["mean_sigma_cm"] = 100.0 * float(s.mean())
    else:
        out["within_3sigma_pct"] = out["confident_wrong_pct"] = out["mean_sigma_cm"] = math.nan
    return out


def run_backend(name: str, bag_path: Path, row_offset_px: float = 0.0) -> dict[str, Any]:
    """One backend on one labelled bag: the eval metrics plus bias, prior and confident-wrong.

    Args:
        row_offset_px: the right image moved down by this many pixels first (a rectification
            residual, :func:`roadbev_lab.synth.render.shift_rows`; 0 = the frame as recorded).
    """
    from roadbev_core.backends import BackendError, create
    from roadbev_lab.evaluation.evalbag import read_eval_bag
    from roadbev_lab.evaluation.frames import evaluate
    from roadbev_lab.synth.render import shift_rows

    bag = read_eval_bag(bag_path)
    try:
        backend = create(name, bag.grid)
        samples = [s._replace(inputs=replace(s.inputs, right=shift_rows(s.inputs.right, row_offset_px)))
                   if row_offset_px and s.inputs.right is not None else s for s in bag]
        result = evaluate(backend, samples, imu=bag.imu, keep_estimates=True)
    except (BackendError, ValueError, RuntimeError) as exc:
        return {"backend": name, "refused": f"{type(exc).__name__}: {exc}"}
    (estimate,) = result.estimates or []
    truth = samples[0].truth
    assert truth is not None  # the bag was just labelled
    m = result.metrics
    keep = (
        "abs_err_cm",
        "rmse_cm",
        "coverage_pct",
        "median_abs_err_cm",
        "p95_abs_err_cm",
        "within_1sigma_pct",
        "within_2sigma_pct",
        "band_abs_err_cm",
        "pipeline_ms",
    )
    return {"backend": name, **{k: m.get(k) for k in keep}, **_scores(estimate.elevation, estimate.uncertainty, truth)}


def row_offset_sensitivity(names: list[str], bag_path: Path, offsets: list[float]) -> dict[str, list[dict[str, Any]]]:
    """Backend -> [{row_offset_px, coverage_pct, abs_err_cm, confident_wrong_pct}] over ``offsets``
    (0 included), each a run on the bag's frame with the right image moved down by that much."""
    rows: dict[str, list[dict[str, Any]]] = {}
    for name in names:
        rows[name] = []
        for offset in sorted({0.0, *offsets}):
            r = run_backend(name, bag_path, offset)
            rows[name].append({"row_offset_px": offset, **{k: r.get(k) for k in
                                                          ("coverage_pct", "abs_err_cm", "confident_wrong_pct")}})
            print(f"  {name} row offset {offset:+g} px: coverage {r.get('coverage_pct')}", file=sys.stderr)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backends", nargs="*", default=list(BACKENDS))
    parser.add_argument("--out", type=Path, default=RESULTS / "kitti.json")
    parser.add_argument("--row-offsets", type=float, nargs="*", default=[], metavar="PX",
                        help="also run the backends that answer with the right image moved down by each of these "
                             "pixels (a rectification residual): coverage and error per offset")
    args = parser.parse_args(argv)
    if not KITTI.is_dir():
        print(f"KITTI frames not found at {KITTI}", file=sys.stderr)
        return 2
    torch.set_flush_denormal(True)
    frames_out = []
    with tempfile.TemporaryDirectory() as tmp:
        for frame in load_frames(KITTI):
            t0 = time.perf_counter()
            bag, grid, pose, info = labelled_bag(frame, Path(tmp))
            from roadbev_lab.evaluation.evalbag import read_eval_bag

            truth = next(iter(read_eval_bag(bag))).truth
            assert truth is not None  # the bag was just labelled
            labelled = np.isfinite(truth)
            record: dict[str, Any] = {
                "frame": frame.name,
                "gt_source": "Velodyne scan (one, not accumulated)"
                if frame.points_frame == "velodyne"
                else "KITTI disparity map (accumulated Velodyne)",
                "image_size": list(frame.camera.size),
                "fx": frame.camera.fx,
                "baseline_m": frame.camera.baseline,
                "fitted_base_height_m": grid.base_height,
                "fitted_roll_deg": math.degrees(pose.attitude.roll),
                "fitted_pitch_deg": math.degrees(pose.attitude.pitch),
                "plane_fit_sigma_cm": 100.0 * pose.sigma_m,
                "labelled_cells": int(labelled.sum()),
                "flat_prior_abs_err_cm": 100.0 * float(np.abs(truth[labelled]).mean()),
                "label": info,
                "backends": [],
            }
            for name in args.backends:
                t1 = time.perf_counter()
                result = run_backend(name, bag)
                result["wall_s"] = time.perf_counter() - t1
                record["backends"].append(result)
                print(f"{frame.name} {name}: {result.get('abs_err_cm', result.get('refused'))}", file=sys.stderr)
            if args.row_offsets:
                record["row_offset_sensitivity"] = row_offset_sensitivity(
                    [b["backend"] for b in record["backends"] if "refused" not in b], bag, args.row_offsets)
            record["wall_s"] = time.perf_counter() - t0
            frames_out.append(record)
    data = {
        "benchmark": "real KITTI frames (test set, nothing tuned on them)",
        "command": "python -m benchmarks.bench_kitti " + " ".join(argv if argv is not None else sys.argv[1:]),
        "window": WINDOW.to_dict(),
        "caveat": GT_NOISE_CAVEAT,
        "machine": machine_info(),
        "frames": frames_out,
    }
    write_json(args.out, data)
    print(markdown_table(data))
    return 0


def _fmt(value: Any, digits: int = 2) -> str:
    return "–" if value is None or (isinstance(value, float) and not math.isfinite(value)) else f"{value:.{digits}f}"


def markdown_table(data: dict[str, Any]) -> str:
    """One row per backend: abs. error / coverage / bias / confident-wrong on each frame."""
    frames = data["frames"]
    head = "| backend | " + " | ".join(f["frame"] for f in frames) + " |"
    lines = [head, "|---|" + "---|" * len(frames)]
    prior = " | ".join(f"{_fmt(f['flat_prior_abs_err_cm'])} cm (100 %)" for f in frames)
    lines.append(f"| flat prior | {prior} |")
    names = [b["backend"] for b in frames[0]["backends"]]
    for name in names:
        cells = []
        for f in frames:
            b = next(x for x in f["backends"] if x["backend"] == name)
            if "refused" in b:
                cells.append("refused")
                continue
            cells.append(
                f"{_fmt(b['abs_err_cm'])} cm ({_fmt(b['coverage_pct'], 0)} %), bias {_fmt(b['bias_cm'])}, "
                f"prior {_fmt(b['flat_prior_on_covered_cells_cm'])}, c.w. {_fmt(b['confident_wrong_pct'], 0)} %"
            )
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
