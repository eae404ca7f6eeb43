"""How the shipped image-view baselines were trained: their phases, budget and loss curves.

Reads the training record each shipped baseline checkpoint carries (``meta``: every phase's
command, frames, epochs, learning rate, batch, seconds and per-epoch history; written by
``roadbev train --kind gwcnet|adabins``) and writes ``benchmarks/results/baseline_training.json``
and ``baseline_training.png`` (training loss and abs. error per epoch, per baseline).

With ``--held-out N`` (default 16) each network's own output is also scored against its labels
(disparity or depth; :func:`network_errors`) on N of its training scenes and on the N tuning
scenes (seeds 200,000+, never trained on): how far its training error carries to new scenes.

Run: ``.venv/bin/python -m benchmarks.baseline_training [--checkpoints checkpoints/gwcnet_lite.pt
checkpoints/adabins_lite.pt] [--held-out 16]``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from benchmarks.common import RESULTS, machine_info, scene_samples, write_json
from benchmarks.tune_bev_sweep import TUNING_SEED_BASE
from roadbev_core.backends.gwcnet import gwcnet_inputs, search_window
from roadbev_core.checkpoint import baseline_kind, load_baseline
from roadbev_core.config import GridSpec
from roadbev_lab.training.train_image_view import adabins_sample, gwcnet_sample, training_phases

DEFAULT_CHECKPOINTS = ("checkpoints/gwcnet_lite.pt", "checkpoints/adabins_lite.pt")
# what each baseline's training abs. error measures
ERROR_UNIT = {"gwcnet": "px of disparity", "adabins": "m of depth"}


def summary(path: Path) -> dict[str, Any]:
    """One checkpoint's training record: its phases and their totals."""
    kind = baseline_kind(path)
    if kind is None:
        raise ValueError(f"{path} is not an image-view baseline's checkpoint")
    model, payload = load_baseline(path, kind)
    phases = [{**p, "seconds": p.get("seconds") or sum(float(h.get("seconds", 0.0)) for h in p.get("history") or [])}
              for p in training_phases(payload.get("meta", {}))]  # a phase without its total: its epochs'
    steps = sum(int(p.get("steps", 0)) for p in phases)
    passes = sum(int(p.get("steps", 0)) * int(p.get("batch_size", 0)) for p in phases)
    return {
        "kind": kind, "checkpoint": str(path), "parameters": sum(p.numel() for p in model.parameters()),
        "model_config": model.config.to_dict(), "error_unit": ERROR_UNIT[kind],
        "phases": [{k: p.get(k) for k in ("command", "frames", "epochs", "lr", "batch_size", "crop", "steps",
                                          "seconds", "history")} for p in phases],
        "steps": steps, "sample_passes": passes,
        "minutes": sum(float(p.get("seconds", 0.0)) for p in phases) / 60.0,
    }


@torch.inference_mode()
def network_errors(kind: str, model: nn.Module, samples: Sequence[tuple[Any, np.ndarray]], grid: GridSpec
                   ) -> dict[str, float]:
    """A baseline network's own output against its training labels on ``samples`` ((frame, truth
    [n_rows, n_cols]) pairs): the mean abs. error in its unit (px of disparity, m of depth) and the
    mean relative error (of the disparity or the depth), over every labelled pixel."""
    errors, relative = [], []
    for frame, truth in samples:
        if kind == "gwcnet":
            sample = gwcnet_sample(frame, truth, grid, model.config)  # type: ignore[arg-type]
            window = search_window(grid, frame.camera, frame.attitude)
            left, right = gwcnet_inputs(frame, window)  # [H, W, 3], padded to the network's stride
            out, _ = model(torch.from_numpy(left).permute(2, 0, 1)[None],
                           torch.from_numpy(right).permute(2, 0, 1)[None])
            h, w = sample.target.shape
            estimate, target, offset = out[0, :h, :w].numpy(), sample.target, float(window.min_disparity)
        else:
            depth_sample = adabins_sample(frame, truth, grid, model.config)  # type: ignore[arg-type]
            out, _, _ = model(torch.from_numpy(depth_sample.image)[None])
            estimate, target, offset = out[0].numpy(), depth_sample.target, 0.0
        labelled = np.isfinite(target)
        diff = np.abs(estimate[labelled] - target[labelled])
        errors.append(diff)
        relative.append(diff / (target[labelled] + offset))
    every, every_relative = np.concatenate(errors), np.concatenate(relative)
    return {"abs_err": float(every.mean()), "relative_err": float(every_relative.mean()), "pixels": int(every.size)}


def held_out(path: Path, frames: int, training_cache: str, tuning_cache: str) -> dict[str, Any]:
    """:func:`network_errors` of one checkpoint on its first ``frames`` training scenes (seeds 0+)
    and on as many tuning scenes."""
    kind = baseline_kind(path)
    assert kind is not None
    model, _ = load_baseline(path, kind)
    grid = GridSpec()
    training = scene_samples(range(frames), grid, training_cache)
    tuning = scene_samples(range(TUNING_SEED_BASE, TUNING_SEED_BASE + frames), grid, tuning_cache)
    return {"frames": frames, "training": network_errors(kind, model, training, grid),
            "tuning": network_errors(kind, model, tuning, grid)}


def plot(records: Sequence[dict[str, Any]], path: Path) -> None:
    """Training loss and abs. error per epoch, one column per baseline (phases one after another)."""
    from roadbev_lab.reports.figures import new_figure

    fig, axes = new_figure(2, len(records), figsize=(5.5 * len(records), 6.0), dpi=100, squeeze=False)
    for col, record in enumerate(records):
        epoch = 0
        for number, phase in enumerate(record["phases"], start=1):
            history = phase["history"] or []
            x = [epoch + int(h["epoch"]) for h in history]
            axes[0][col].plot(x, [h["loss"] for h in history], marker="o", ms=3, label=f"phase {number}")
            error = [h.get("abs_err", h.get("abs_err_px")) for h in history]
            axes[1][col].plot(x, error, marker="o", ms=3, label=f"phase {number}")
            epoch = x[-1] if x else epoch
        axes[0][col].set_title(f"{record['kind']} ({record['parameters'] / 1e6:.2f} M parameters)", fontsize=10)
        axes[0][col].set_ylabel("training loss")
        axes[1][col].set_ylabel(f"training abs. error ({record['error_unit']})")
        axes[1][col].set_xlabel("epoch")
        for ax in (axes[0][col], axes[1][col]):
            ax.set_yscale("log")
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.baseline_training", description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoints", nargs="+", default=list(DEFAULT_CHECKPOINTS), metavar="PT")
    parser.add_argument("--held-out", type=int, default=16, metavar="N",
                        help="score each network on N training and N tuning scenes (default 16; 0: not)")
    parser.add_argument("--training-cache", default=".cache/roadbev", metavar="DIR",
                        help="the training scenes' cache (default .cache/roadbev)")
    parser.add_argument("--scene-cache", default=".cache/scenes", metavar="DIR",
                        help="the tuning scenes' cache (default .cache/scenes)")
    parser.add_argument("--out", default=str(RESULTS), help="results folder")
    args = parser.parse_args(argv)
    records = [summary(Path(p)) for p in args.checkpoints]
    if args.held_out > 0:
        for record in records:
            record["held_out"] = held_out(Path(record["checkpoint"]), args.held_out, args.training_cache,
                                          args.scene_cache)
    out = Path(args.out)
    write_json(out / "baseline_training.json", {
        "command": " ".join(["python -m benchmarks.baseline_training", *(argv if argv is not None else sys.argv[1:])]),
        "machine": machine_info(), "baselines": records,
    })
    plot(records, out / "baseline_training.png")
    for r in records:
        print(f"{r['kind']}: {len(r['phases'])} phase(s), {r['steps']} steps, {r['minutes']:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
