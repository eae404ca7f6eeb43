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


def coverage_hint(backend: Any, samples: Any, coverage_pct: float | None) -> str | None:
    """The self-check's one-line hint (:func:`roadbev_core.selfcheck.self_check` on the first
    frame) when the evaluation's coverage fell below the threshold; None otherwise."""
    from roadbev_core.selfcheck import MIN_COVERAGE_PCT, self_check

    if coverage_pct is None or coverage_pct >= MIN_COVERAGE_PCT:
        return None
    sample = next(iter(samples), None)
    if sample is None:
        return None
    return self_check(backend.estimate(sample.frame), sample.frame, backend.grid).message


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
    try:
        result = evaluate(backend, _read_failures(bag, path), progress=progress, max_frames=args.frames)
    finally:
        if bar is not None:
            bar.close()
    metrics = result.to_dict()
    print(format_table([metrics]))
    bands = ", ".join("-" if b is None else f"{b:.3f}" for b in metrics["band_abs_err_cm"])
    print(f"abs. error per distance band (cm, near to far): {bands}")
    print(
        "uncertainty: error within 1 / 2 / 3 sigma "
        + " / ".join("-" if metrics.get(k) is None else f"{metrics[k]:.1f}"
                     for k in ("within_1sigma_pct", "within_2sigma_pct", "within_3sigma_pct"))
        + " %, confidently wrong "
        + ("-" if metrics.get("confident_wrong_pct") is None else f"{metrics['confident_wrong_pct']:.2f}")
        + " %, mean sigma "
        + ("-" if metrics.get("mean_sigma_cm") is None else f"{metrics['mean_sigma_cm']:.3f}")
        + " cm"
    )
    hint = coverage_hint(backend, bag, metrics.get("coverage_pct"))
    if hint:
        print(f"self-check: {hint}")
        metrics["self_check"] = hint
    if args.json:
        record = {**metrics, "bag": str(path), "grid": bag.grid.to_dict(), "backend_options": options}
        if args.params:
            record["params_file"] = str(args.params)
        out = Path(args.json)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(record, indent=2) + "\n")
        print(f"metrics written to {out}")
    return 0
