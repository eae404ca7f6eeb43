"""``roadbev export``: a deployment checkpoint (weights, model config, grid; no optimizer state)."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "export a checkpoint for deployment"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", type=Path, help="a checkpoint written by `roadbev train`")
    parser.add_argument("out", type=Path, help="where to write the exported checkpoint")
    parser.add_argument("--half", action="store_true", help="store weights as float16 (half the size)")


def run(args: argparse.Namespace) -> int:
    from roadbev_core.checkpoint import load_model, save_checkpoint

    model, payload = load_model(args.checkpoint)
    meta = dict(payload.get("meta", {}))
    train_state = payload.get("train_state") or {}
    if train_state.get("history"):
        meta["final_epoch"] = train_state["history"][-1]
    meta["exported_from"] = args.checkpoint.name
    path = save_checkpoint(args.out, model, meta=meta, half=args.half)
    params = sum(p.numel() for p in model.parameters())
    print(f"exported RoadBEV-{model.config.kind} ({model.config.backbone}, C={model.config.channels}, "
          f"{params / 1e6:.2f} M parameters) for a {model.grid.n_rows}x{model.grid.n_cols} grid to {path} "
          f"({path.stat().st_size / 1e6:.1f} MB)")
    return 0
