"""``roadbev demo``: the main job, end to end over ROS 2, leaving a report folder.

Writes (or reuses from ``./.cache/roadbev``) a synthetic drive bag with ground truth, runs the
node on it over DDS, records its outputs, scores them, checks them against the offline
evaluation (``roadbev eval``) and writes ``DIR/index.html`` with the figures.
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
from pathlib import Path

from roadbev_cli.cli import CommandError, add_output_flags, shows_progress
from roadbev_core.backends import available
from roadbev_core.config import DEFAULT_BACKEND
from roadbev_core.errors import RoadbevError
from roadbev_lab.demo.drive import DEFAULT_DRIVE_FRAMES, DRIVE_SEED
from roadbev_lab.demo.run import DEFAULT_FRAMES, DEFAULT_OUT, DemoOptions, run_demo, summary_lines

HELP = "the main job: synthetic drive -> node over ROS 2 -> recorded outputs -> report (+ a drive, map on/off)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roadbev demo``."""

    parser.add_argument("--frames", type=int, default=DEFAULT_FRAMES, metavar="N",
                        help=f"frames of the synthetic drive (default {DEFAULT_FRAMES}; ignored with --bag)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, metavar="DIR",
                        help=f"report folder (default ./{DEFAULT_OUT})")
    parser.add_argument("--backend", default=DEFAULT_BACKEND, metavar="B",
                        help=f"elevation backend of the node (default {DEFAULT_BACKEND})")
    parser.add_argument("--bag", type=Path, default=None, metavar="BAG",
                        help="any evaluation bag (rosbag2 directory or .mcap) instead of the synthetic drive")
    parser.add_argument("--seed", type=int, default=0, help="seed of the synthetic drive (default 0)")
    parser.add_argument("--cache", type=Path, default=None, metavar="DIR",
                        help="cache of synthetic bags (default ./.cache/roadbev)")
    parser.add_argument("--no-drive", action="store_true",
                        help="leave out the drive section (the fused map, previews at arrival, hazards, ride)")
    parser.add_argument("--drive-frames", type=int, default=DEFAULT_DRIVE_FRAMES, metavar="N",
                        help=f"camera frames (10 Hz, 10 m/s) of the drive section's synthetic drive "
                        f"(default {DEFAULT_DRIVE_FRAMES}; with --bag the section runs on BAG when it is a drive bag)")
    parser.add_argument("--drive-seed", type=int, default=DRIVE_SEED,
                        help=f"seed of the drive section's synthetic drive (default {DRIVE_SEED})")
    add_output_flags(parser, summary=False)


def run(args: argparse.Namespace) -> int:
    """Run the demo; a failed stage ends with a one-line reason (non-zero exit).

    The run writes into ``DIR.partial`` and replaces ``DIR`` only when it succeeds, so a failed
    run leaves the last good report as it was; what the failed one wrote (the node's log among
    it) is kept in ``DIR.failed`` and the error line names it.
    """

    # DemoError and CommandError are RoadbevErrors: the CLI prints either as one line (it catches
    # the root class, so running as `python -m roadbev_cli.cli`, as `make demo` does, is no different)
    if args.backend not in available():
        raise CommandError(f"unknown backend {args.backend!r}; choose from {', '.join(available())}")
    out = Path(args.out)
    work, failed = out.with_name(out.name + ".partial"), out.with_name(out.name + ".failed")
    shutil.rmtree(work, ignore_errors=True)
    options = DemoOptions(frames=args.frames, out_dir=work, backend=args.backend, bag=args.bag,
                          cache_dir=args.cache, seed=args.seed, progress=shows_progress(args),
                          drive=not args.no_drive, drive_frames=args.drive_frames, drive_seed=args.drive_seed)
    try:
        result = run_demo(options)
    except (RoadbevError, KeyboardInterrupt) as exc:
        if not work.exists() or not any(work.iterdir()):
            shutil.rmtree(work, ignore_errors=True)  # it failed before writing anything
            raise
        shutil.rmtree(failed, ignore_errors=True)
        work.rename(failed)
        kept = ", ".join(sorted(p.name for p in failed.iterdir())) or "nothing"
        where = f"what it wrote is in {failed} ({kept}); {out} is as it was"
        if isinstance(exc, KeyboardInterrupt):
            raise CommandError(f"interrupted; {where}") from None
        raise CommandError(f"{exc}; {where}") from None
    shutil.rmtree(out, ignore_errors=True)
    shutil.rmtree(failed, ignore_errors=True)
    work.rename(out)
    result = dataclasses.replace(result, out_dir=out,
                                 files={name: out / path.relative_to(work) for name, path in result.files.items()})
    for line in summary_lines(result):
        print(line)
    return 0
