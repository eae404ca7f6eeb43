"""``roadbev export``: a checkpoint for deployment, as a ``.pt`` (weights, model config, grid; no
optimizer state) or as an ONNX graph (``--format onnx``, :mod:`roadbev_core.deploy`), fp32 or with
int8 convolutions (``--int8``, post-training quantisation calibrated on training scenes). The
image-view baselines' checkpoints (``gwcnet``, ``adabins``) export the same way, fp32."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from roadbev_cli.cli import CommandError, add_output_flags, output_path, progress_bar, shows_progress
from roadbev_core.checkpoint import (
    baseline_kind,
    load_baseline,
    load_model,
    save_baseline,
    save_checkpoint,
    training_envelope,
)
from roadbev_core.deploy import (
    BASELINE_IO,
    OPSET,
    DeployError,
    export_baseline_onnx,
    export_onnx,
    frame_feeds,
    input_names,
    quantize_int8,
    trtexec_shapes,
    write_graph,
)
from roadbev_lab.synth import make_sample

HELP = "export a checkpoint for deployment (.pt or ONNX)"
# Calibration frames of --int8: training seeds (disjoint from every test and tuning seed), as many
# as the Table I test set has frames.
CALIBRATION_SCENES = 24


def add_arguments(parser: argparse.ArgumentParser) -> None:

    parser.add_argument("checkpoint", type=Path, help="a checkpoint written by `roadbev train`")
    parser.add_argument("out", type=output_path, help="where to write the export")
    parser.add_argument("--format", choices=("pt", "onnx"), default="pt",
                        help="pt: a deployment checkpoint (default); onnx: the network as an ONNX graph whose "
                             "geometry (voxel sampling coordinates) are inputs, for ONNX Runtime, OpenVINO, TensorRT")
    parser.add_argument("--half", action="store_true", help="pt: store weights as float16 (half the size)")
    parser.add_argument("--opset", type=int, default=OPSET, help=f"onnx: the ONNX opset (default {OPSET}; >= 16)")
    parser.add_argument("--gather", action="store_true",
                        help="onnx: voxel features by Gather nodes instead of GridSample (same numbers), for "
                             "engines without GridSample")
    parser.add_argument("--int8", action="store_true",
                        help="onnx: int8 convolutions (QDQ), ranges calibrated on synthetic training scenes")
    parser.add_argument("--calibration-scenes", type=int, default=CALIBRATION_SCENES, metavar="N",
                        help=f"--int8: training scenes (seeds 0..N-1) to calibrate on (default {CALIBRATION_SCENES})")
    add_output_flags(parser, summary=False)


def run(args: argparse.Namespace) -> int:

    kind = baseline_kind(args.checkpoint)
    if kind is not None:
        return _export_baseline(args, kind)
    model, payload = load_model(args.checkpoint)
    meta = dict(payload.get("meta", {}))
    train_state = payload.get("train_state") or {}
    if train_state.get("history"):
        meta["final_epoch"] = train_state["history"][-1]
    meta["exported_from"] = args.checkpoint.name
    if args.format == "onnx":
        if args.half:
            raise CommandError("--half is for --format pt (the ONNX graph is fp32; engines choose their precision)")

        data = export_onnx(model, None if args.int8 else args.out, meta=meta, opset=args.opset, gather=args.gather)
        path = args.out
        what = f"ONNX opset {args.opset}, inputs {', '.join(input_names(model.config))}"
        if args.int8:
            _write_int8(data, model, args)
            what += f", int8 convolutions calibrated on {args.calibration_scenes} training scenes"
    else:
        if args.int8:
            raise CommandError("--int8 is for --format onnx")
        path = save_checkpoint(args.out, model, meta=meta, half=args.half)
        what = "checkpoint"
    params = sum(p.numel() for p in model.parameters())
    if args.format == "onnx":

        print("TensorRT (docs/tutorials/deploy.md), batch 1 of 960x528 frames (grey's H x W follow the frames): "
              f"trtexec --onnx={path} --shapes={trtexec_shapes(model.config, model.grid, 960, 528)}")
    print(f"exported RoadBEV-{model.config.kind} ({model.config.backbone}, C={model.config.channels}, "
          f"{params / 1e6:.2f} M parameters) for a {model.grid.n_rows}x{model.grid.n_cols} grid to {path} "
          f"({what}; {path.stat().st_size / 1e6:.1f} MB)")
    return 0


def _export_baseline(args: argparse.Namespace, kind: str) -> int:
    """An image-view baseline's checkpoint as ONNX (``--format onnx``) or again as a checkpoint."""
    if args.int8 or args.half or args.gather:
        raise CommandError(f"--int8, --half and --gather are for RoadBEV checkpoints, not {kind}")
    model, payload = load_baseline(args.checkpoint, kind)
    meta = {**dict(payload.get("meta", {})), "exported_from": args.checkpoint.name}
    if args.format == "onnx":
        export_baseline_onnx(model, kind, args.out, meta=meta, opset=args.opset)
        what = f"ONNX opset {args.opset}, inputs {', '.join(BASELINE_IO[kind][0])}"
    else:
        save_baseline(args.out, kind, model, training_envelope(payload), meta=meta)
        what = "checkpoint"
    params = sum(p.numel() for p in model.parameters())
    print(f"exported {kind} ({params / 1e6:.2f} M parameters) to {args.out} ({what}; "
          f"{Path(args.out).stat().st_size / 1e6:.1f} MB)")
    return 0


def _write_int8(data: bytes, model: Any, args: argparse.Namespace) -> None:
    """Quantise the exported graph on training scenes and write it to ``args.out`` (atomically)."""
    if args.calibration_scenes < 1:
        raise CommandError(f"--calibration-scenes must be >= 1, got {args.calibration_scenes}")
    feeds = []
    with progress_bar(total=args.calibration_scenes, unit="scene", desc="int8 calibration scenes",
                      disable=not shows_progress(args)) as bar:
        for seed in range(args.calibration_scenes):
            frame = make_sample(seed, grid=model.grid).frame
            feeds.append(frame_feeds(model.config, model.grid, frame))
            bar.update(1)
    try:
        quantized = quantize_int8(data, feeds)
    except DeployError as exc:
        raise CommandError(str(exc)) from exc
    write_graph(quantized, args.out)
