"""``roadbev train``: train RoadBEV-mono / RoadBEV-stereo on synthetic scenes, bags or RSRD, or the
learned image-view baselines of Table I, GwcNet-lite (``--kind gwcnet``, stereo) and AdaBins-lite
(``--kind adabins``, mono), on the same data.

Single process by default; for several GPUs or nodes launch it through ``torchrun``, e.g.
``torchrun --nproc_per_node 4 -m roadbev_cli.cli train ...`` (``--batch-size`` is the global
batch, split over the processes). Checkpoints load with ``torch.load(weights_only=True)``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from roadbev_cli.cli import CommandError, add_output_flags, shows_progress
from roadbev_core.checkpoint import BASELINES
from roadbev_core.config import GridSpec, parse_assignments
from roadbev_core.models.presets import model_config
from roadbev_lab.data.rsrd import RsrdSet
from roadbev_lab.evaluation.evalbag import bag_frames
from roadbev_lab.training.datasets import TEST_SEED_START, ConcatSource, FrameSource, LabelledFrames, SyntheticSet
from roadbev_lab.training.train import TrainConfig, train
from roadbev_lab.training.train_image_view import train_image_view

HELP = "train RoadBEV-mono / RoadBEV-stereo (or the image-view baselines GwcNet-lite, AdaBins-lite)"
DEFAULT_CACHE = Path(".cache") / "roadbev"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    model = parser.add_argument_group("model")
    model.add_argument("--kind", choices=("stereo", "mono", *BASELINES), required=True,
                       help="which network (gwcnet, adabins: the learned image-view stereo and mono baselines, "
                            "trained on the disparities / depths of the labelled road; --preset, --resume and "
                            "--model-option do not apply to them)")
    model.add_argument("--preset", choices=("paper", "lite", "tiny"), default="lite",
                       help="model size (default lite; paper needs a GPU)")
    model.add_argument("--out", type=Path, required=True, help="checkpoint to write (.pt)")
    model.add_argument("--pretrained", type=Path, help="ImageNet EfficientNet weights (torchvision/lukemelas)")
    model.add_argument("--resume", type=Path, help="continue from this checkpoint")
    model.add_argument("--init", type=Path, help="start from this checkpoint's weights with a fresh schedule")
    model.add_argument("--augment", action="store_true",
                       help="--kind adabins: AdaBins' own augmentation (mirror, gamma, brightness, colour)")
    model.add_argument("--model-option", action="append", default=[], metavar="FIELD=VALUE",
                       help="change a ModelConfig field of the preset or of the --init checkpoint's model, "
                            "e.g. zncc_subsamples=2 (repeatable; values are JSON: true, 3, 0.5, or text)")
    data = parser.add_argument_group("data (any combination)")
    data.add_argument("--synth", type=int, default=0, metavar="N", help="N synthetic training scenes")
    data.add_argument("--synth-seed", type=int, default=0, help="first synthetic scene seed (default 0)")
    data.add_argument("--synth-appearance", default=None, metavar="NAME",
                      help="draw the synthetic scenes' pavement and camera appearance from this range "
                           "(roadbev_lab.synth.APPEARANCE_NAMES: real-road, the default, or clean, "
                           "the generator's own before scene version 2)")
    data.add_argument("--cache", type=Path, default=DEFAULT_CACHE, help=f"scene cache (default {DEFAULT_CACHE})")
    data.add_argument("--bag", type=Path, action="append", default=[], help="an evaluation bag with ground truth")
    data.add_argument("--rsrd", type=Path, help="RSRD root (<split>/<sequence>/...)")
    data.add_argument("--rsrd-split", default="train", help="split of the RSRD dataset to train on (default train)")
    data.add_argument("--rsrd-info", type=Path, nargs="+", default=[],
                      help="sample-info pickles to read (trusted files only: pickle runs code)")
    data.add_argument("--rsrd-calib", type=Path, nargs="+", default=[],
                      help="calib_<YYYYMMDD>_half.pkl files to read (trusted files only)")
    opt = parser.add_argument_group("optimisation")
    opt.add_argument("--epochs", type=int, default=10, help="passes over the training data (default 10)")
    opt.add_argument("--batch-size", type=int, default=2, help="global batch size")
    opt.add_argument("--lr", type=float, help="peak learning rate (default 8e-4 mono, 5e-4 stereo)")
    opt.add_argument("--weight-decay", type=float, default=1e-4, help="AdamW weight decay (default 1e-4)")
    opt.add_argument("--pct-start", type=float, default=0.1, help="one-cycle warm-up share")
    opt.add_argument("--seed", type=int, default=0, help="seed of the weights' initialisation and the data order")
    opt.add_argument("--max-minutes", type=float, help="wall-clock cap; saves and stops when crossed")
    opt.add_argument("--threads", type=int, help="torch threads")
    parser.add_argument("--log", type=Path, help="also append the epoch summaries to this file")
    add_output_flags(parser, summary=False)


def run(args: argparse.Namespace) -> int:

    overrides = parse_assignments(args.model_option, "--model-option")  # before any data is read
    if args.augment and args.kind != "adabins":
        raise CommandError("--augment is AdaBins' augmentation (--kind adabins)")
    sources: list[FrameSource] = []
    if args.synth:
        last = args.synth_seed + args.synth
        if args.synth_seed < 0 or last > TEST_SEED_START:
            raise CommandError(f"training seeds must lie in [0, {TEST_SEED_START}) (test scenes use the rest)")
        sources.append(SyntheticSet(args.cache, range(args.synth_seed, last), progress=shows_progress(args),
                                    appearance=args.synth_appearance))
    sources.extend(LabelledFrames(*bag_frames(bag), what=str(bag)) for bag in args.bag)
    if args.rsrd:

        if not args.rsrd_info or not args.rsrd_calib:
            raise CommandError("--rsrd needs --rsrd-info and --rsrd-calib files")
        sources.append(RsrdSet(args.rsrd, args.rsrd_split, args.rsrd_info, args.rsrd_calib))
    if not sources:
        raise CommandError("no training data: give --synth N, --bag BAG or --rsrd ROOT")
    data = ConcatSource(sources)
    grid = data.grid if args.bag else GridSpec()
    config = TrainConfig(
        epochs=args.epochs, batch_size=args.batch_size, lr=args.lr, weight_decay=args.weight_decay,
        pct_start=args.pct_start, seed=args.seed, max_minutes=args.max_minutes, threads=args.threads,
    )

    def log(line: str) -> None:
        print(line, file=sys.stderr, flush=True)
        if args.log:
            with args.log.open("a") as handle:
                handle.write(line + "\n")

    if args.kind in BASELINES:
        if args.resume or args.model_option:
            raise CommandError(f"--kind {args.kind} takes --init to continue, not --resume or --model-option")
        done = train_image_view(args.kind, data, config, args.out, init=args.init, pretrained=args.pretrained,
                                augment=args.augment, log=log, meta={"command": args.command_line})
        print(f"wrote {done['checkpoint']}: {done['steps']} steps, {done['epochs_done']} epochs"
              + (" (stopped at the time cap)" if done["stopped_early"] else ""))
        return 0
    result = train(model_config(args.preset, args.kind), grid, data, config, args.out, resume=args.resume,
                   init=args.init, model_overrides=overrides, pretrained=args.pretrained,
                   progress=shows_progress(args), log=log)
    if result.checkpoint is not None:
        last = result.history[-1] if result.history else {}
        loss, err = last.get("loss", float("nan")), last.get("abs_err_cm", float("nan"))
        print(f"wrote {result.checkpoint}: {result.steps} steps, {result.epochs_done:.2f} epochs, "
              f"last-epoch train loss {loss:.4f}, abs. err. {err:.3f} cm"
              + (" (stopped at the time cap)" if result.stopped_early else ""))
    return 0

