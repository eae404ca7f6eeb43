"""The learned models on a GPU machine: torch CUDA against ONNX Runtime's CUDA and TensorRT providers.

For when a GPU machine is lent; CI never runs it. On that machine (CUDA torch, and
``onnxruntime-gpu`` in place of ``onnxruntime``: the two packages share one module name)::

    python -m pip install onnx onnxruntime-gpu          # + the project's requirements, torch with CUDA
    python -m benchmarks.bench_device                   # lite + paper, stereo + mono, < 5 min
    python -m benchmarks.bench_device --presets lite --runtimes torch-cuda ort-cuda

And here, on the CPU, as a smoke test of the script itself (tiny preset, CPU providers)::

    .venv/bin/python -m benchmarks.bench_device --smoke

For every preset and kind the network (the shipped checkpoint for ``lite``; random weights, BN
folded, for ``paper`` and ``tiny``: their speed does not depend on the weights) runs on one 960 x
528 synthetic frame (RSRD half rig, the default grid): ``--warmup`` runs, then ``--frames`` timed
runs, each with the device synchronised. The geometry step (``voxel_geometry``: where each voxel
is read, on the CPU) is timed apart: it is the same for every runtime. Every runtime's elevation
is compared with torch's on the CPU (mean |diff|, cm). TensorRT builds its engine on the first
run (minutes for ``paper``); the build time is reported, and cached in ``--cache``. Writes
``benchmarks/results/device.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.common import RESULTS, machine_info, write_json

RUNTIMES = ("torch-cpu", "torch-cuda", "torch-cuda-fp16", "ort-cpu", "ort-cuda", "ort-tensorrt", "ort-tensorrt-fp16")
DEFAULT_RUNTIMES = ("torch-cuda", "torch-cuda-fp16", "ort-cuda", "ort-tensorrt", "ort-tensorrt-fp16")


def _model(preset: str, kind: str) -> Any:
    """The network of a preset: the shipped checkpoint for lite, random weights otherwise."""
    import torch

    from roadbev_core.backends.learned import default_checkpoint
    from roadbev_core.checkpoint import load_model
    from roadbev_core.config import GridSpec
    from roadbev_core.models.efficientnet import fold_batchnorm
    from roadbev_core.models.presets import model_config
    from roadbev_core.models.roadbev import RoadBEV

    path = default_checkpoint(kind)
    if preset == "lite" and path.is_file():
        model, _ = load_model(path)
    else:
        torch.manual_seed(0)
        model = RoadBEV(model_config(preset, kind), GridSpec())
    return fold_batchnorm(model.eval())


def _latency(run: Any, warmup: int, frames: int) -> dict[str, float]:
    for _ in range(warmup):
        run()
    times = []
    for _ in range(frames):
        t = time.perf_counter()
        run()
        times.append(1e3 * (time.perf_counter() - t))
    return {"p50_ms": float(np.median(times)), "p95_ms": float(np.percentile(times, 95)),
            "mean_ms": float(np.mean(times)), "fps": 1e3 / float(np.mean(times))}


def bench_one(
    preset: str, kind: str, runtimes: list[str], warmup: int, frames: int, cache: Path
) -> list[dict[str, Any]]:
    """Every runtime on one (preset, kind); rows with latency, FPS and the difference to torch-cpu."""
    import torch

    from roadbev_core.config import StereoCamera
    from roadbev_core.deploy import export_onnx, geometry_feeds, image_feeds, input_names
    from roadbev_core.geometry import Attitude
    from roadbev_core.models.loss import soft_argmin
    from roadbev_core.models.roadbev import VoxelGeometry, voxel_geometry
    from roadbev_core.models.voxel_query import VoxelLookup

    model = _model(preset, kind)
    cfg, grid = model.config, model.grid
    camera = StereoCamera.rsrd_half()
    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, (camera.height, camera.width, 3), dtype=np.uint8)
    right = np.roll(left, -8, axis=1)
    attitude = Attitude.from_degrees(0.3, 18.4)
    feeds = {**image_feeds(cfg, left, right), **geometry_feeds(cfg, grid, [camera], [attitude])}
    geometry_ms = _latency(lambda: voxel_geometry(cfg, grid, [camera], [Attitude.from_degrees(0.3, 18.4)]), 1, 5)
    names = input_names(cfg)

    def torch_runner(device: str, half: bool) -> Any:
        net = model.to(device)
        tensors = {k: torch.from_numpy(v).to(device) for k, v in feeds.items()}

        def look(prefix: str, eye: str) -> VoxelLookup | None:
            if f"{prefix}coords_{eye}" not in tensors:
                return None
            return VoxelLookup(tensors[f"{prefix}coords_{eye}"], tensors[f"{prefix}mask_{eye}"] > 0.5)

        left_look = look("", "left")
        assert left_look is not None
        geometry = VoxelGeometry(left_look, look("", "right"), look("fine_", "left"), look("fine_", "right"))

        def run() -> np.ndarray:
            with torch.inference_mode(), torch.autocast(device_type=device.split(":")[0], dtype=torch.float16,
                                                        enabled=half):
                logits, _ = net.logits(tensors["left"], tensors.get("right"), tensors.get("grey"), geometry)
                elevation, _ = soft_argmin(logits.float(), net.centres)
            if device.startswith("cuda"):
                torch.cuda.synchronize()
            return elevation.float().cpu().numpy()

        return run

    def ort_runner(provider: str, fp16: bool) -> tuple[Any, float]:
        import onnxruntime as ort

        data = export_onnx(model.to("cpu"))
        options = ort.SessionOptions()
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        chain: list[Any] = []
        if provider == "tensorrt":
            cache.mkdir(parents=True, exist_ok=True)
            chain.append(("TensorrtExecutionProvider", {
                "trt_fp16_enable": fp16, "trt_engine_cache_enable": True, "trt_engine_cache_path": str(cache),
                "trt_timing_cache_enable": True, "trt_max_workspace_size": 4 << 30,
            }))
        if provider in ("tensorrt", "cuda"):
            chain.append("CUDAExecutionProvider")
        chain.append("CPUExecutionProvider")
        t = time.perf_counter()
        session = ort.InferenceSession(data, sess_options=options, providers=chain)
        session.run(["elevation"], {k: feeds[k] for k in names})  # the engine is built here
        build_s = time.perf_counter() - t
        active = session.get_providers()
        wanted = {"tensorrt": "TensorrtExecutionProvider", "cuda": "CUDAExecutionProvider",
                  "cpu": "CPUExecutionProvider"}[provider]
        if wanted not in active:
            raise RuntimeError(f"{wanted} is not active (have {active})")
        return (lambda: session.run(["elevation"], {k: feeds[k] for k in names})[0]), build_s

    reference = torch_runner("cpu", False)()
    rows: list[dict[str, Any]] = []
    for runtime in runtimes:
        row: dict[str, Any] = {"preset": preset, "kind": kind, "runtime": runtime,
                               "geometry_cpu_ms": geometry_ms["p50_ms"]}
        try:
            build_s = 0.0
            if runtime.startswith("torch"):
                device = "cpu" if runtime == "torch-cpu" else "cuda"
                if device == "cuda" and not torch.cuda.is_available():
                    raise RuntimeError("torch has no CUDA device here")
                run = torch_runner(device, runtime.endswith("fp16"))
            else:
                provider = runtime.split("-")[1]
                run, build_s = ort_runner(provider, runtime.endswith("fp16"))
            row.update(_latency(run, warmup, frames))
            elevation = np.asarray(run())
            row["build_s"] = build_s
            row["mean_abs_diff_vs_torch_cpu_cm"] = float(np.abs(elevation - reference).mean() * 100.0)
        except Exception as exc:  # a missing provider or device is a row with its reason, not the end of the run
            row["error"] = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        model.to("cpu")
        rows.append(row)
        shown = {k: (round(v, 3) if isinstance(v, float) else v) for k, v in row.items()}
        print(shown, file=sys.stderr)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_device", description=__doc__.splitlines()[0])
    parser.add_argument("--presets", nargs="+", choices=("tiny", "lite", "paper"), default=["lite", "paper"])
    parser.add_argument("--kinds", nargs="+", choices=("stereo", "mono"), default=["stereo", "mono"])
    parser.add_argument("--runtimes", nargs="+", choices=RUNTIMES, default=list(DEFAULT_RUNTIMES))
    parser.add_argument("--frames", type=int, default=20, help="timed runs per runtime")
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--cache", type=Path, default=Path(".cache/roadbev/tensorrt"), help="TensorRT engine cache")
    parser.add_argument("--smoke", action="store_true", help="CPU only: tiny preset, torch-cpu and ort-cpu, 2 runs")
    parser.add_argument("--out", type=Path, default=RESULTS / "device.json")
    args = parser.parse_args(argv)
    if args.smoke:
        args.presets, args.runtimes, args.frames, args.warmup = ["tiny"], ["torch-cpu", "ort-cpu"], 2, 1
        if args.out == RESULTS / "device.json":
            args.out = RESULTS / "device_smoke.json"
    import torch

    torch.set_flush_denormal(True)
    started = time.monotonic()
    rows = []
    for preset in args.presets:
        for kind in args.kinds:
            rows += bench_one(preset, kind, args.runtimes, args.warmup, args.frames, args.cache)
    gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
    record = {
        "what": "learned models per GPU runtime (one 960x528 frame, default grid; latency of the network "
                "after the CPU geometry step)",
        "command": " ".join(["python -m benchmarks.bench_device", *(argv if argv is not None else sys.argv[1:])]),
        "machine": {**machine_info(), "gpu": gpu},
        "wall_s": time.monotonic() - started,
        "rows": rows,
    }
    write_json(args.out, record)
    print(f"wrote {args.out} in {record['wall_s']:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
