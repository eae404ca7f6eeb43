"""Node throughput and end-to-end latency per backend, over real DDS (replay -> node -> record).

Run (from the repository root)::

    .venv/bin/python -m benchmarks.bench_node                       # bev_sweep, sgbm, bm
    .venv/bin/python -m benchmarks.bench_node --backends bm --frames 10 --scale 0.5
    .venv/bin/python -m benchmarks.bench_node --backends stereo stereo:runtime=openvino --frames 40
    .venv/bin/python -m benchmarks.bench_node --drive --rate 10 --backends bev_sweep --frames 40  # map on

A backend may carry options, ``NAME:OPTION=VALUE[,OPTION=VALUE]`` (node parameters
``NAME.OPTION``), so that one run compares e.g. the torch and ONNX runtimes of a model.

For every backend the node runs as its own process (``roadbev node``) and a synthetic drive
(5 Hz, 960 x 528 stereo at ``--scale 1``, 100 Hz IMU; with ``--drive`` a drive bag where the car
rides on its road at 10 m/s, with ``/odom`` and ``/tf_static``, so the node runs the fused map)
is replayed into it twice:

* ``5hz``: with the bag's timing, as a camera would deliver it (5 Hz; with ``--drive --rate R``
  R Hz); a backend slower than the camera makes the node drop frames (it keeps the newest);
* ``max``: as fast as the node answers (each left image waits for the previous answer), i.e.
  the node's maximum throughput.

Latency is end to end: the left image leaving the replay process to its elevation map arriving
in the recording process (DDS both ways, synchronisation, IMU wait, inference, conversions).
With a node slower than the camera a frame also waits for the node to finish the previous one;
``latency_on_arrival_ms`` leaves that wait out (each frame's latency less the time from its
publication to the previous answer's receipt: what a frame costs when the node takes it at once,
the latency the ride benchmark charges, adding the waits of its own model of the node). The
node's own figures come from its ``/diagnostics``: ``inference_mean_ms`` (the backend) and
``overhead_mean_ms`` (everything else the node does per frame: decoding, calibration, preview,
message building and publishing; waiting for the IMU is reported apart). Writes
``benchmarks/results/node.json``.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.common import RESULTS, available_backends, backend_spec, machine_info, write_json
from roadbev_core.config import DEFAULT_BACKEND, RoadbevConfig, parse_assignments

REPO = Path(__file__).resolve().parents[1]
CACHE = REPO / ".cache"
TARGET_HZ = 5.0
TARGET_P95_MS = 200.0
TARGET_OVERHEAD_MS = 10.0
STEREO_TARGET_P95_MS = 300.0
MAP_TARGET_P95_MS = 250.0


def drive_bag(frames: int, scale: float, seed: int = 7, *, riding: bool = False, rate: float = 5.0,
              speed: float = 10.0) -> Path:
    """A synthetic drive as an evaluation bag (cached by its arguments); ``riding``: a drive bag
    where the car rides on its road, with ``/odom`` and ``/tf_static`` (the node fuses the map)."""
    from roadbev_core.config import StereoCamera
    from roadbev_lab.evaluation.drivebag import write_drive_bag
    from roadbev_lab.evaluation.evalbag import write_eval_bag
    from roadbev_lab.synth import REAL_ROAD_MIDDLE, DriveConfig, RidingConfig, RidingDrive, RoadConfig, SyntheticDrive

    CACHE.mkdir(exist_ok=True)
    kind = f"_drive_{rate:g}hz_{speed:g}mps" if riding else ""
    path = CACHE / f"bench_node_{frames}f_{scale:g}x_s{seed}{kind}.mcap"
    if not path.exists():
        camera = StereoCamera.rsrd_half()
        if scale != 1.0:
            camera = camera.scaled(scale)
        road = REAL_ROAD_MIDDLE.apply(RoadConfig(road_class="C", features=("pothole", "speed_bump")))
        tmp = path.with_suffix(".tmp.mcap")
        tmp.unlink(missing_ok=True)
        if riding:
            config = DriveConfig(frames=frames, camera=camera, seed=seed, road=road, frame_rate_hz=rate,
                                 speed_mps=speed)
            write_drive_bag(tmp, RidingDrive(RidingConfig(drive=config)))
        else:
            write_eval_bag(tmp, SyntheticDrive(DriveConfig(frames=frames, camera=camera, seed=seed, road=road)))
        tmp.replace(path)
    return path


def _float(values: dict[str, str], key: str) -> float:
    try:
        return float(values[key])
    except (KeyError, ValueError):
        return math.nan


def run_one(
    bag: Path, backend: str, mode: str, work: Path, node_params: dict[str, Any] | None = None
) -> dict[str, Any]:
    """One backend (``NAME[:OPTION=VALUE,...]``) in one mode: throughput, latency, node figures, accuracy."""
    from roadbev_lab.evaluation.online import evaluate_online

    rate = 1.0 if mode == "5hz" else None
    name, options = backend_spec(backend)
    folder = work / f"{backend.replace(':', '_').replace('=', '-').replace(',', '_')}_{mode}"
    result = evaluate_online(bag, folder, backend=name, rate=rate, node_params={**(node_params or {}), **options})
    m = result.metrics
    online = m["online"]
    node = online["node"]
    outputs = online["outputs_matched"]
    frames = online["frames_published"]
    wall = online["wall_s"]
    inference = _float(node, "inference_mean_ms")  # the first frame includes the backend's warm-up
    return {
        "backend": backend,
        "mode": mode,
        "frames": frames,
        "outputs": outputs,
        "dropped": frames - outputs,
        "throughput_hz": outputs / wall if wall > 0 else math.nan,
        "latency_ms": online["latency_ms"],
        "latency_after_first_ms": online["latency_after_first_ms"],
        # less each frame's wait for the node (a node slower than the camera): what the ride
        # benchmark's model of the node charges, adding the waits itself (preview_budget)
        "latency_on_arrival_ms": online["latency_on_arrival_ms"],
        "node_latency_p95_ms": _float(node, "latency_p95_ms"),
        "inference_mean_ms": inference,
        "inference_p50_ms": _float(node, "inference_p50_ms"),
        "overhead_mean_ms": _float(node, "overhead_mean_ms"),
        "overhead_p95_ms": _float(node, "overhead_p95_ms"),
        "imu_wait_mean_ms": _float(node, "imu_wait_mean_ms"),
        # frames the pace backend answered (the chosen one slower than the camera: roadbev_core.pacing)
        "paced_frames": int(node.get("paced_frames", "0")),
        "pace": node.get("pace", ""),
        "e2e_minus_inference_p50_ms": online["latency_ms"]["p50"] - _float(node, "inference_p50_ms"),
        "abs_err_cm": m["abs_err_cm"],
        "coverage_pct": m["coverage_pct"],
        # a drive bag with odometry: the node's recorded previews at arrival and its fused map
        **{key: m[key] for key in ("preview_at_arrival", "map") if key in m},
    }


def pipeline_overhead(scale: float, repeats: int = 30) -> dict[str, float]:
    """The node's own per-frame work, single-threaded and without DDS or contention.

    Times :func:`msg_bridge.pipeline_io.camera_input` (image and CameraInfo conversion), the
    Frame, the preview profiles and :func:`msg_bridge.pipeline_io.output_messages` (GridMap and
    RoadPreview messages; the PointCloud2 apart, it is only built for a listening viewer) on
    messages of the benchmark's image size and the default grid.
    """
    import numpy as np

    from msg_bridge import RclpyFactory
    from msg_bridge.camera_info import camera_info_from_stereo
    from msg_bridge.image import array_to_image
    from msg_bridge.pipeline_io import camera_input, output_messages
    from roadbev_core.config import RoadbevConfig, StereoCamera
    from roadbev_core.frame import Estimate, Frame
    from roadbev_core.geometry import Attitude
    from roadbev_core.pipeline import PipelineOutput
    from roadbev_core.preview import wheel_track_profiles

    camera = StereoCamera.rsrd_half()
    if scale != 1.0:
        camera = camera.scaled(scale)
    factory = RclpyFactory()
    rng = np.random.default_rng(0)
    pixels = rng.integers(0, 255, (camera.height, camera.width, 3), np.uint8)
    msgs = (
        array_to_image(pixels, factory, stamp_ns=1, encoding="rgb8"),
        array_to_image(pixels, factory, stamp_ns=1, encoding="rgb8"),
        camera_info_from_stereo(camera, factory, stamp_ns=1),
        camera_info_from_stereo(camera, factory, right=True, stamp_ns=1),
    )
    config = RoadbevConfig()
    p = config.preview
    elevation = rng.normal(0.0, 0.02, config.grid.shape).astype(np.float32)
    estimate = Estimate(elevation, np.full_like(elevation, 0.01))
    times: dict[str, list[float]] = {"inputs_ms": [], "outputs_ms": [], "points_ms": []}
    for _ in range(repeats + 1):
        t0 = time.perf_counter()
        inputs = camera_input(msgs, "raw")
        frame = Frame(inputs.left, inputs.right, inputs.camera, Attitude(), inputs.stamp_ns)
        t1 = time.perf_counter()
        preview = wheel_track_profiles(
            estimate.elevation, estimate.uncertainty, config.grid, track_offsets_m=p.track_offsets_m,
            tyre_width_m=p.tyre_width_m, spacing_m=p.spacing_m, vehicle_speed=5.0,
        )
        output = PipelineOutput(frame, estimate, preview)
        output_messages(output, config, factory, with_points=False)
        t2 = time.perf_counter()
        output_messages(output, config, factory, with_points=True)
        t3 = time.perf_counter()
        times["inputs_ms"].append((t1 - t0) * 1e3)
        times["outputs_ms"].append((t2 - t1) * 1e3)
        times["points_ms"].append((t3 - t2 - (t2 - t1)) * 1e3)
    out = {k: float(np.median(v[1:])) for k, v in times.items()}  # the first is a warm-up
    out["total_ms"] = out["inputs_ms"] + out["outputs_ms"]
    return out


def check_targets(rows: list[dict[str, Any]], overhead: dict[str, float], default: str = DEFAULT_BACKEND,
                  drive_rate_hz: float | None = None) -> dict[str, Any]:
    """The targets on the default backend (and the overhead on every backend); with a drive bag at
    ``drive_rate_hz``, the default's latency with the map on and how many frames it fused."""
    by = {(r["backend"], r["mode"]): r for r in rows}
    out: dict[str, Any] = {}
    five, fast = by.get((default, "5hz")), by.get((default, "max"))
    if five is not None:
        out["default_p95_latency_under_200ms_at_5hz"] = five["latency_ms"]["p95"] < TARGET_P95_MS
        out["default_p95_latency_under_200ms_at_5hz_after_warmup"] = (
            five["latency_after_first_ms"]["p95"] < TARGET_P95_MS
        )
        out["default_no_drops_at_5hz"] = five["dropped"] == 0
    if fast is not None:
        out["default_sustains_5hz"] = fast["throughput_hz"] >= TARGET_HZ
    out["pipeline_overhead_under_10ms"] = overhead["total_ms"] < TARGET_OVERHEAD_MS
    # The learned stereo backend's target (issue 20): every frame of the 5 Hz replay, p95 < 300 ms.
    out["stereo_every_frame_and_p95_under_300ms_at_5hz"] = {
        r["backend"]: r["dropped"] == 0 and r["latency_ms"]["p95"] < STEREO_TARGET_P95_MS
        for r in rows if r["mode"] == "5hz" and r["backend"].split(":")[0] == "stereo"
    }
    out["in_node_overhead_under_10ms"] = {
        f"{r['backend']}/{r['mode']}": r["overhead_mean_ms"] < TARGET_OVERHEAD_MS for r in rows
    }
    if drive_rate_hz is not None and five is not None:
        # the default with the map on, fed a camera's timing: it may drop frames, never queue
        out[f"default_map_on_{drive_rate_hz:g}hz_p95_under_{MAP_TARGET_P95_MS:g}ms"] = (
            five["latency_ms"]["p95"] < MAP_TARGET_P95_MS)
        out["default_map_on_fused_frames"] = f"{five['outputs']}/{five['frames']}"
    return out


def recorded_node_params(given: dict[str, Any]) -> dict[str, Any]:
    """The node parameters a result records for every row: those ``given`` (``--node-param``) and
    ``far_field.enabled`` even where the default chose it, since what a frame costs depends on it
    and a default may change under a committed result (``preview_budget`` matches rows by it)."""
    return {"far_field.enabled": RoadbevConfig().far_field.enabled, **given}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backends", nargs="+", default=["bev_sweep", "sgbm", "bm"])
    parser.add_argument("--modes", nargs="+", choices=("5hz", "max"), default=["5hz", "max"])
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--scale", type=float, default=1.0, help="image scale of the 960x528 rig")
    parser.add_argument("--out", type=Path, default=RESULTS / "node.json")
    parser.add_argument("--drive", action="store_true",
                        help="a drive where the car rides on its road, with /odom and /tf_static: the map is on")
    parser.add_argument("--rate", type=float, default=5.0, help="camera rate of the --drive bag (default 5 Hz)")
    parser.add_argument("--node-param", action="append", default=[], metavar="NAME=VALUE",
                        help="a node parameter for every run, e.g. inference_threads=2 (repeatable)")
    args = parser.parse_args(argv)
    try:
        node_params = parse_assignments(args.node_param, "--node-param")
    except ValueError as exc:
        parser.error(str(exc))
    node_params = recorded_node_params(node_params)

    import torch

    torch.set_flush_denormal(True)
    t0 = time.monotonic()
    bag = drive_bag(args.frames, args.scale, riding=args.drive, rate=args.rate)
    print(f"bag {bag.name} ready in {time.monotonic() - t0:.1f} s", file=sys.stderr)
    try:
        specs = {spec: backend_spec(spec) for spec in args.backends}
    except ValueError as exc:
        parser.error(str(exc))
    status = {spec: available_backends([name])[name] for spec, (name, _) in specs.items()}
    rows: list[dict[str, Any]] = []
    skipped = {name: reason for name, reason in status.items() if reason}
    with tempfile.TemporaryDirectory(prefix="bench_node_") as tmp:
        for backend in args.backends:
            if backend in skipped:
                print(f"skip {backend}: {skipped[backend]}", file=sys.stderr)
                continue
            for mode in args.modes:
                row = run_one(bag, backend, mode, Path(tmp), node_params)
                rows.append(row)
                lat = row["latency_ms"]
                steady = row["latency_after_first_ms"]
                print(
                    f"{backend:9s} {mode:3s}: {row['throughput_hz']:6.2f} Hz, {row['outputs']}/{row['frames']} "
                    f"frames, latency p50 {lat['p50']:7.1f} / p95 {lat['p95']:7.1f} ms (p95 after the first "
                    f"{steady['p95']:7.1f}; on arrival p50 {row['latency_on_arrival_ms']['p50']:7.1f}), inference p50 "
                    f"{row['inference_p50_ms']:7.1f} ms, node overhead {row['overhead_mean_ms']:5.2f} ms "
                    f"(p95 {row['overhead_p95_ms']:5.2f}), IMU wait {row['imu_wait_mean_ms']:5.2f} ms, "
                    f"paced {row['paced_frames']} frames",
                    file=sys.stderr,
                )
    overhead = pipeline_overhead(args.scale)
    print(f"node pipeline overhead (single thread, no DDS): {overhead}", file=sys.stderr)
    record = {
        "what": "node throughput and end-to-end latency over DDS (replay -> node process -> record)",
        "bag": {"frames": args.frames, "scale": args.scale, "frame_rate_hz": args.rate if args.drive else 5.0,
                "drive_with_odometry": args.drive},
        "node_params": node_params,
        "machine": machine_info(),
        "rows": rows,
        "pipeline_overhead_ms": overhead,
        "skipped": skipped,
        "targets": check_targets(rows, overhead, drive_rate_hz=args.rate if args.drive else None),
    }
    write_json(args.out, record)
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
