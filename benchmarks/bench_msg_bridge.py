"""Cost of the message conversions on the node's hot path, and of reading an evaluation bag.

Run: ``.venv/bin/python -m benchmarks.bench_msg_bridge [--repeats 50]``; writes
``benchmarks/results/msg_bridge.json`` (median milliseconds per call, 960x528 images, the
default 164x64 grid).
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from msg_bridge import RclpyFactory, bag_factory
from msg_bridge.grid_map import elevation_grid_map, grid_map_to_arrays
from msg_bridge.image import array_to_compressed, array_to_image, compressed_to_rgb, image_to_rgb
from msg_bridge.point_cloud import elevation_point_cloud
from msg_bridge.preview import road_preview_message
from roadbev_core.config import GridSpec
from roadbev_core.preview import wheel_track_profiles
from roadbev_lab.evaluation.evalbag import read_eval_bag
from roadbev_lab.evaluation.frames import to_json

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
SAMPLE = ROOT / "bags" / "sample_drive.mcap"


def median_ms(call: Callable[[], Any], repeats: int) -> float:
    call()  # warm-up (imports, caches)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        call()
        times.append(time.perf_counter() - t0)
    return float(np.median(times) * 1e3)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=50)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    grid = GridSpec()
    pixels = rng.integers(0, 256, (528, 960, 3), dtype=np.uint8)
    elevation = rng.normal(0, 0.02, grid.shape).astype(np.float32)
    sigma = np.full(grid.shape, 0.01, np.float32)
    rclpy_f, store_f = RclpyFactory(), bag_factory()
    rclpy_image = array_to_image(pixels, rclpy_f)
    store_image = array_to_image(pixels, store_f)
    bgr_image = array_to_image(pixels, store_f, encoding="bgr8")  # same bytes, read as BGR
    jpeg = array_to_compressed(pixels, store_f, jpeg_quality=90)
    rclpy_map = elevation_grid_map(elevation, sigma, grid, rclpy_f, stamp_ns=0)
    profiles = wheel_track_profiles(elevation, sigma, grid, vehicle_speed=5.0)
    r = args.repeats
    result: dict[str, Any] = {
        "benchmark": "msg_bridge",
        "image_960x528_rgb8_to_array_rclpy_ms": median_ms(lambda: image_to_rgb(rclpy_image), r),
        "image_960x528_rgb8_to_array_rosbags_ms": median_ms(lambda: image_to_rgb(store_image), r),
        "image_960x528_bgr8_to_rgb_ms": median_ms(lambda: image_to_rgb(bgr_image), r),
        "array_to_image_960x528_rclpy_ms": median_ms(lambda: array_to_image(pixels, rclpy_f), r),
        "jpeg_960x528_decode_ms": median_ms(lambda: compressed_to_rgb(jpeg), r),
        "grid_map_164x64_2_layers_build_rclpy_ms": median_ms(
            lambda: elevation_grid_map(elevation, sigma, grid, rclpy_f, stamp_ns=0), r
        ),
        "grid_map_164x64_decode_rclpy_ms": median_ms(lambda: grid_map_to_arrays(rclpy_map), r),
        "wheel_track_profiles_ms": median_ms(lambda: wheel_track_profiles(elevation, sigma, grid), r),
        "road_preview_build_rclpy_ms": median_ms(
            lambda: road_preview_message(profiles, rclpy_f, stamp_ns=0), r
        ),
        "point_cloud_build_rclpy_ms": median_ms(
            lambda: elevation_point_cloud(elevation, sigma, grid, rclpy_f, stamp_ns=0), r
        ),
        "zero_copy_image_read": bool(np.shares_memory(image_to_rgb(store_image), store_image.data)),
    }
    if SAMPLE.is_file():
        t0 = time.perf_counter()
        bag = read_eval_bag(SAMPLE)
        index_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        frames = sum(1 for _ in bag)
        result["sample_bag_index_s"] = index_s
        result["sample_bag_frames_per_s"] = frames / (time.perf_counter() - t0)
    result["machine"] = f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores"
    RESULTS.mkdir(parents=True, exist_ok=True)
    text = to_json(result)
    (RESULTS / "msg_bridge.json").write_text(text)
    print(text, end="")


if __name__ == "__main__":
    main()
