"""``roadbev eval BAG``: run a backend over every frame of a bag (no DDS) and report the metrics.

The bag (a rosbag2 directory with ``metadata.yaml`` or a single ``.mcap`` file) carries the
stereo images, camera infos, the IMU and ``/ground_truth/elevation``; the horizontal grid comes
from the ground truth's GridMap info, ``base_height`` and the vertical range from ``--params``
(a standard ROS 2 params YAML; defaults otherwise). The metrics are those of
:mod:`roadbev_core.evaluation`, the same code the demo and the benchmarks use.

Backend options may be given in the params file as ``<backend>.<option>`` (for example
``bev_sweep.patch_cells: 5``); the learned backends take ``checkpoint`` (or ``--checkpoint``).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from roadbev_ros.cli import CommandError

HELP = "run a backend over every frame of a bag (no DDS) and report the metrics"
DEFAULT_BACKEND = "bev_sweep"
LEARNED = ("stereo", "mono")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roadbev eval``."""
    parser.add_argument("bag", metavar="BAG", help="rosbag2 directory (with metadata.yaml) or .mcap file")
    parser.add_argument(
        "--backend", default=None, help=f"elevation backend (default: the params' 'backend', else {DEFAULT_BACKEND})"
    )
    parser.add_argument("--params", default=None, metavar="P", help="ROS 2 params YAML (grid, base_height, backend)")
    parser.add_argument("--json", default=None, metavar="OUT", help="write the metrics as JSON here")
    parser.add_argument("--frames", type=int, default=None, metavar="N", help="evaluate only the first N frames")
    parser.add_argument("--checkpoint", default=None, help="checkpoint for the learned backends (stereo, mono)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--lead-time", type=float, default=0.1, metavar="S",
                        help="drive bags: preview at arrival counts messages stamped this long before (default 0.1 s)")


def _check_bag_path(path: Path) -> None:
    """A bag is a directory with metadata.yaml or an .mcap file (contract, "Command line")."""
    if not path.exists():
        raise CommandError(f"bag not found: {path}")
    if path.is_dir():
        if not (path / "metadata.yaml").is_file() and not any(path.glob("*.mcap")):
            raise CommandError(f"{path} is a directory without metadata.yaml or .mcap files: not a rosbag2 bag")
    elif path.suffix != ".mcap":
        raise CommandError(f"{path} is neither a rosbag2 directory nor an .mcap file")


def _load_params(path: str | None) -> dict[str, Any]:
    if path is None:
        return {}
    from roadbev_ros.params import load_params_file

    try:
        return load_params_file(path)
    except ValueError as exc:  # YAML errors span lines: the CLI gives one
        raise CommandError(" ".join(line.strip() for line in str(exc).splitlines() if line.strip())) from exc


def _backend_options(name: str, params: dict[str, Any], checkpoint: str | None) -> dict[str, Any]:
    """Options for backend ``name``: params named ``<name>.<option>``, plus the checkpoint."""
    prefix = f"{name}."
    options = {key[len(prefix) :]: value for key, value in params.items() if key.startswith(prefix)}
    if name in LEARNED:
        chosen = checkpoint or params.get("checkpoint") or None
        if chosen:
            options["checkpoint"] = chosen
    elif checkpoint:
        raise CommandError(f"--checkpoint applies to the learned backends ({', '.join(LEARNED)}), not {name!r}")
    return options


def _read_failures(samples: Any, path: Path) -> Iterator[Any]:
    """Re-raise bag read/decode failures during iteration as a one-line CommandError."""
    iterator = iter(samples)
    while True:
        try:
            sample = next(iterator)
        except StopIteration:
            return
        except Exception as exc:  # rosbags/mcap raise many types for a damaged bag
            raise CommandError(f"cannot read bag {path}: {type(exc).__name__}: {exc}") from exc
        yield sample


def _preview_at_arrival(path: Path, grid: Any, result: Any, params: dict[str, Any], lead: float) -> dict[str, Any]:
    """Score the per-frame pipeline's previews at arrival, print one line, return the JSON keys."""
    from msg_bridge.drivebag import evaluate_drive_previews
    from roadbev_core.arrival import ArrivalError, per_frame_previews
    from roadbev_core.evaluation import json_safe

    stamps = [int(r["stamp_ns"]) for r in result.per_frame]
    try:
        previews = per_frame_previews(result.estimates, stamps, grid,
                                      track_offsets_m=params.get("preview.track_offsets_m", (0.8, -0.8)),
                                      tyre_width_m=float(params.get("preview.tyre_width_m", 0.2)),
                                      spacing_m=float(params.get("preview.spacing_m", 0.03)))
        out = evaluate_drive_previews(path, previews, stamps, params, base_height=grid.base_height, lead_time_s=lead)
    except (ArrivalError, ValueError) as exc:
        raise CommandError(f"preview at arrival on {path}: {exc}") from exc
    print(f"preview at arrival (lead {lead:g} s, {out['points']} points): abs. error {out['abs_err_cm']:.3f} cm, "
          f"coverage {out['coverage_pct']:.1f} %, features {out['features_abs_err_cm']:.3f} cm, smooth "
          f"{out['smooth_abs_err_cm']:.3f} cm, vs the contact plane {out['contact_plane_abs_err_cm']:.3f} cm")
    return json_safe(out)


def run(args: argparse.Namespace) -> int:
    """Evaluate, print the table, write the JSON; non-zero exit (via CommandError) on bad input."""
    from roadbev_core.backends import available, create

    path = Path(args.bag)
    _check_bag_path(path)
    if args.frames is not None and args.frames < 1:
        raise CommandError(f"--frames must be >= 1, got {args.frames}")
    params = _load_params(args.params)
    name = args.backend or params.get("backend") or DEFAULT_BACKEND
    if name not in available():
        raise CommandError(f"unknown backend {name!r}; choose from {', '.join(available())}")
    options = _backend_options(name, params, args.checkpoint)
    try:
        from msg_bridge.evalbag import read_eval_bag
    except ModuleNotFoundError as exc:
        raise CommandError(f"reading evaluation bags needs msg_bridge.evalbag ({exc})") from None
    try:
        bag = read_eval_bag(path, params or None)
    except (ValueError, OSError, CommandError):
        raise
    except Exception as exc:  # a damaged bag: one line, no traceback
        raise CommandError(f"cannot read bag {path}: {type(exc).__name__}: {exc}") from exc
    backend = create(name, bag.grid, **options)

    from roadbev_core.evaluation import evaluate, format_table

    total = len(bag) if args.frames is None else min(len(bag), args.frames)
    if total == 0:
        raise CommandError(f"bag {path} has no complete frames to evaluate")
    progress = None
    bar = None
    if not args.no_progress:
        from tqdm import tqdm

        bar = tqdm(total=total, unit="frame", desc=f"eval {name}", file=sys.stderr, leave=False)
        progress = bar.update
    from msg_bridge.drivebag import is_drive_bag

    drive = is_drive_bag(path, params)
    try:
        result = evaluate(backend, _read_failures(bag, path), progress=progress, max_frames=args.frames,
                          keep_estimates=drive)
    finally:
        if bar is not None:
            bar.close()
    metrics = result.to_dict()
    print(format_table([metrics]))
    if drive:  # contract, "Drive bags": the per-frame previews at the wheels' arrival
        metrics["preview_at_arrival"] = _preview_at_arrival(path, bag.grid, result, params, args.lead_time)
    bands = ", ".join("-" if b is None else f"{b:.3f}" for b in metrics["band_abs_err_cm"])
    print(f"abs. error per distance band (cm, near to far): {bands}")
    if args.json:
        record = {**metrics, "bag": str(path), "grid": bag.grid.to_dict(), "backend_options": options}
        if args.params:
            record["params_file"] = str(args.params)
        out = Path(args.json)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(record, indent=2) + "\n")
        print(f"metrics written to {out}")
    return 0
