"""Synthetic data speed: stereo rendering per frame (issue 2 budget: <= 1 s at 960x528 here).

Run: ``.venv/bin/python -m benchmarks.bench_synth [--frames 6] [--samples 3]``; writes
``benchmarks/results/synth.json``. Reports wall time and process CPU time (all threads) per
stereo frame of a drive on the real RSRD half-resolution rig, the scene set-up of the drive, and
whole independent samples (``make_sample``: scene + render + labels). On a shared machine the
wall time grows with the load average, which is recorded with the numbers.
"""

from __future__ import annotations

import argparse
import functools
import os
import statistics
import time
from collections.abc import Callable
from typing import Any

from benchmarks.common import RESULTS, machine_info, write_json


def _timed(fn: Callable[[], Any]) -> tuple[Any, float, float]:
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


def _stats(values: list[float]) -> dict[str, float]:
    return {
        "median": round(statistics.median(values), 4),
        "min": round(min(values), 4),
        "max": round(max(values), 4),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=6, help="drive frames to time (after one warm-up)")
    parser.add_argument("--samples", type=int, default=3, help="independent samples to time")
    args = parser.parse_args()

    from roadbev_core.config import StereoCamera
    from roadbev_lab.synth import REAL_ROAD_MIDDLE, DriveConfig, RoadConfig, SyntheticDrive, make_sample
    from roadbev_lab.synth.render import render_stereo

    info = machine_info()
    camera = StereoCamera.rsrd_half()
    features = ("pothole", "speed_bump", "crack", "patch", "rut")
    road = REAL_ROAD_MIDDLE.apply(RoadConfig(road_class="C", features=features))
    drive, setup_wall, setup_cpu = _timed(
        lambda: SyntheticDrive(DriveConfig(frames=args.frames + 1, seed=1, camera=camera, road=road))
    )
    drive[0]  # warm-up: texture tiles are made once per process
    render_wall, render_cpu, frame_wall, frame_cpu = [], [], [], []
    for i in range(1, args.frames + 1):
        pose, _ = drive.pose(i)
        _, w, c = _timed(functools.partial(render_stereo, drive.scene, camera, pose))
        render_wall.append(w)
        render_cpu.append(c)
        _, w, c = _timed(functools.partial(drive.__getitem__, i))
        frame_wall.append(w)
        frame_cpu.append(c)
    # One thread: its CPU time is what the wall time is on an idle core (load-independent).
    import cv2

    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    single_cpu = [_timed(functools.partial(drive.__getitem__, i))[2] for i in range(1, args.frames + 1)]
    cv2.setNumThreads(threads)
    sample_wall, sample_cpu = [], []
    for seed in range(args.samples):
        _, w, c = _timed(functools.partial(make_sample, 1000 + seed, camera=camera))
        sample_wall.append(w)
        sample_cpu.append(c)
    try:
        load_end = [round(v, 2) for v in os.getloadavg()]
    except OSError:
        load_end = []
    result = {
        "benchmark": "synth",
        "image": f"{camera.width}x{camera.height}",
        "budget_s_per_stereo_frame": 1.0,
        "stereo_render_wall_s": _stats(render_wall),
        "stereo_render_cpu_s": _stats(render_cpu),
        "drive_frame_wall_s": _stats(frame_wall),
        "drive_frame_cpu_s": _stats(frame_cpu),
        "drive_frame_cpu_1thread_s": _stats(single_cpu),
        "drive_frame_note": "drive[i]: stereo render + sensor model + LiDAR-like points + labels; "
        "the 1-thread CPU time is the wall time on an idle core",
        "drive_setup_wall_s": round(setup_wall, 3),
        "drive_setup_cpu_s": round(setup_cpu, 3),
        "drive_frames": args.frames + 1,
        "make_sample_wall_s": _stats(sample_wall),
        "make_sample_cpu_s": _stats(sample_cpu),
        "load_average_at_end": load_end,
        "machine": info,
    }
    write_json(RESULTS / "synth.json", result)
    print(
        f"stereo frame {camera.width}x{camera.height}: render {result['stereo_render_wall_s']['median']:.3f} s wall "
        f"({result['stereo_render_cpu_s']['median']:.3f} s CPU), whole frame "
        f"{result['drive_frame_wall_s']['median']:.3f} s wall ({result['drive_frame_cpu_s']['median']:.3f} s CPU, "
        f"{result['drive_frame_cpu_1thread_s']['median']:.3f} s CPU on one thread); "
        f"make_sample {result['make_sample_wall_s']['median']:.3f} s wall; load {info['load_average_at_start']}"
    )


if __name__ == "__main__":
    main()
