"""``roadbev eval BAG``: run a backend over every frame of a bag (no DDS) and report the metrics.

The bag (a rosbag2 directory with ``metadata.yaml`` or a single ``.mcap`` file) carries the
stereo images, camera infos, the IMU and ``/ground_truth/elevation``; the horizontal grid comes
from the ground truth's GridMap info, ``base_height`` and the vertical range from ``--params``
(a standard ROS 2 params YAML; defaults otherwise). The metrics are those of
:mod:`roadbev_lab.evaluation.frames`, the same code the demo and the benchmarks use; the bag, the pipeline
and the drive keys are :mod:`roadbev_lab.evaluation.offline` (which the demo runs on its drive too).

Backend options may be given in the params file as ``<backend>.<option>`` (for example
``bev_sweep.patch_cells: 5``); the learned backends take ``checkpoint`` (or ``--checkpoint``).

A truncated, unfinished or partly damaged bag is evaluated on every readable frame; the lost
frames and the reasons are printed (and are in the JSON: ``lost_frames``, ``losses``). The exit is
non-zero only when no frame at all could be evaluated. ``--out OUT.mcap`` writes the outputs
(``/roadbev/elevation``, ``/roadbev/elevation_far`` with the far field, ``/roadbev/map`` with the
map, ``/roadbev/preview``, as the node publishes them); on a bag without
ground truth that is the result, and the command says there is nothing to score.

Many bags at once (several BAGs, a folder of bags, a glob pattern, or ``--workers`` / ``--ray``:
:mod:`roadbev_cli.fleet`): one task per bag on a local process pool or a Ray cluster, each bag's
result kept in ``--store`` as it finishes (a run again skips the bags done), and one summary:
every bag's JSON as above and the metrics of all of them pooled (``--json``), and a report
(printed; ``--report``). A bag that fails is listed with its reason; the exit is then non-zero,
after everything else is written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from msg_bridge.outputs import OutputBag
from roadbev_cli.cli import CommandError, add_output_flags, progress_bar, seconds, shows_progress, warn
from roadbev_cli.fleet import add_fleet_arguments, fail_on_failed_bags, run_fleet, wants_fleet
from roadbev_core.backends import takes_checkpoint
from roadbev_core.config import DEFAULT_BACKEND, RoadbevConfig, load_params_file
from roadbev_core.pipeline import check_config
from roadbev_lab.evaluation.evalbag import grid_fields
from roadbev_lab.evaluation.frames import format_table, to_json
from roadbev_lab.evaluation.offline import OfflineEvalError, eval_record, prepare_bag, run_prepared
from roadbev_lab.fleet.store import ResultStore, content_digest
from roadbev_lab.fleet.summary import eval_report, eval_summary
from roadbev_lab.fleet.tasks import EvalSettings

HELP = "run a backend over every frame of a bag (no DDS) and report the metrics"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roadbev eval``."""
    parser.add_argument("bag", metavar="BAG", nargs="+",
                        help="rosbag2 directory (with metadata.yaml) or .mcap file; several, a folder of bags or a "
                             "glob pattern (quoted: 'archive/day*') evaluate many bags")
    parser.add_argument(
        "--backend", default=None, help=f"elevation backend (default: the params' 'backend', else {DEFAULT_BACKEND})"
    )
    parser.add_argument("--params", default=None, metavar="P", help="ROS 2 params YAML (grid, base_height, backend)")
    parser.add_argument("--json", default=None, metavar="OUT",
                        help="write the metrics as JSON here (its folder is created)")
    parser.add_argument("--frames", type=int, default=None, metavar="N", help="evaluate only the first N frames")
    parser.add_argument("--checkpoint", default=None,
                        help="checkpoint for the learned backends (stereo, mono, gwcnet, adabins)")
    add_output_flags(parser, summary=False)
    parser.add_argument("--out", default=None, metavar="OUT.mcap",
                        help="also write every output message (/roadbev/elevation, /roadbev/elevation_far with the far "
                             "field, /roadbev/map with the map, /roadbev/preview) to this bag (its folder is created)")
    parser.add_argument("--lead-time", type=seconds, default=0.1, metavar="S",
                        help="drive bags: preview at arrival counts messages stamped this long before (default 0.1 s)")
    fused = parser.add_mutually_exclusive_group()
    fused.add_argument("--map", dest="map", action="store_true", default=None,
                       help="run the fused road map (needs odometry in the bag; default: on when the bag has it)")
    fused.add_argument("--no-map", dest="map", action="store_false", help="the per-frame pipeline only")
    add_fleet_arguments(parser, store=True)
    parser.add_argument("--report", default=None, metavar="OUT.md",
                        help="many bags: also write the printed report (Markdown) here (its folder is created)")


def check_bag_path(path: Path) -> None:
    """A bag is a directory with metadata.yaml or an .mcap file (docs/interface/command-line.md)."""
    if not path.exists():
        raise CommandError(f"bag not found: {path}")
    if path.is_dir():
        if not (path / "metadata.yaml").is_file() and not any(path.glob("*.mcap")):
            raise CommandError(f"{path} is a directory without metadata.yaml or .mcap files: not a rosbag2 bag")
    elif path.suffix != ".mcap":
        raise CommandError(f"{path} is neither a rosbag2 directory nor an .mcap file")


def _settings(args: argparse.Namespace) -> tuple[RoadbevConfig, dict[str, float], set[str]]:
    """The settings the user gave (params file, --backend, --checkpoint) as the one config, checked
    by name, type and range, the grid fields among them (they win over the bag's own) and the
    names of the parameters given."""
    explicit: dict[str, Any] = {}
    if args.params is not None:
        loaded = load_params_file(args.params)
        note = loaded.note()
        if note:
            warn("eval", note)
        explicit.update(loaded.values)
    if args.backend:
        explicit["backend"] = args.backend
    name = explicit.get("backend", DEFAULT_BACKEND)
    if args.checkpoint:
        if not takes_checkpoint(str(name)):
            raise CommandError(f"--checkpoint applies to the learned backends (stereo, mono), not {name!r}")
        explicit["checkpoint"] = args.checkpoint
    config = check_config(RoadbevConfig.from_params(explicit))  # unknown names, wrong types, ranges, the whole
    return config, grid_fields(explicit), set(explicit)


def _print_drive_keys(metrics: dict[str, Any]) -> None:
    """One line for the previews at arrival (per frame or from the map) and one for the map."""
    out = metrics.get("preview_at_arrival")
    if out is None:
        return
    kind = "fused map" if "map" in metrics else "per frame"
    print(f"preview at arrival, {kind} (lead {out['lead_time_s']:g} s, {out['points']} points): abs. error "
          f"{_cm(out['abs_err_cm'])} cm, coverage {_cm(out['coverage_pct'], 1)} %, features "
          f"{_cm(out['features_abs_err_cm'])} cm, smooth {_cm(out['smooth_abs_err_cm'])} cm, vs the contact plane "
          f"{_cm(out['contact_plane_abs_err_cm'])} cm; within 1 / 2 sigma {_cm(out['within_1sigma_pct'], 1)} / "
          f"{_cm(out['within_2sigma_pct'], 1)} %, confidently wrong {_cm(out['confident_wrong_pct'], 2)} %, mean sigma "
          f"{_cm(out['mean_sigma_cm'])} cm")
    fused = metrics.get("map")
    if fused is not None:
        print(f"fused map vs /ground_truth/road_map ({fused['windows']} windows): abs. error "
              f"{_cm(fused['abs_err_cm'])} cm, coverage {_cm(fused['coverage_pct'], 1)} %, confidently wrong "
              f"{_cm(fused['confident_wrong_pct'], 2)} %")


def _print_far_field(metrics: dict[str, Any]) -> None:
    """The far field (a bag with its truth): the whole far grid, then error, coverage and the
    confidently-wrong share per band of 1 m; or why it was not estimated."""
    far = metrics.get("far_field")
    if far is None:
        return
    grid = far["grid"]
    where = f"far field {grid['x_min']:g}-{grid['x_max']:g} m ({100 * grid['resolution']:g} cm cells)"
    if not far["estimated"]:
        print(f"{where}: not estimated: {far['reason']}")
        return
    print(f"{where}: abs. error {_cm(far['abs_err_cm'])} cm, coverage {_cm(far['coverage_pct'], 1)} %, within 2 "
          f"sigma {_cm(far['within_2sigma_pct'], 1)} %, confidently wrong {_cm(far['confident_wrong_pct'], 2)} %")
    for band in far["bands"]:
        print(f"  {band['x_from_m']:g}-{band['x_to_m']:g} m: abs. error {_cm(band['abs_err_cm'])} cm, coverage "
              f"{_cm(band['coverage_pct'], 1)} %, confidently wrong {_cm(band['confident_wrong_pct'], 2)} %")


def _cm(value: Any, digits: int = 3) -> str:
    return "nan" if value is None else f"{float(value):.{digits}f}"


def _write_output(path: str, text: str, what: str) -> None:
    """Write ``text`` to ``path`` (its folder created, as ``--json``'s help says) and say so."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    print(f"{what} written to {out}")


def run(args: argparse.Namespace) -> int:
    """Evaluate, print the table, write the JSON; non-zero exit (via CommandError) on bad input."""
    if wants_fleet(args.bag, args):
        return _run_many(args)
    if args.report:
        raise CommandError("--report is for many bags; one bag's report is what is printed")
    path = Path(args.bag[0])
    check_bag_path(path)
    if args.frames is not None and args.frames < 1:
        raise CommandError(f"--frames must be >= 1, got {args.frames}")
    settings, grid_overrides, _given = _settings(args)
    try:
        prepared = prepare_bag(path, settings, grid_overrides=grid_overrides, map_enabled=args.map)
    except OfflineEvalError as exc:
        raise CommandError(str(exc)) from exc
    bag, config = prepared.bag, prepared.config
    outputs = None
    if args.out:
        outputs = OutputBag(args.out, config, camera_frame=bag.camera_frame)

    total = len(bag) if args.frames is None else min(len(bag), args.frames)
    bar = progress_bar(total=total, unit="frame", desc=f"eval {config.backend.name}", disable=not shows_progress(args),
                       leave=False)
    try:
        evaluation = run_prepared(prepared, lead_time_s=args.lead_time, max_frames=args.frames, progress=bar.update,
                                  on_output=None if outputs is None else outputs.write)
    except OfflineEvalError as exc:
        if outputs is not None:
            outputs.abort()
        raise CommandError(str(exc)) from exc
    except BaseException:
        if outputs is not None:
            outputs.abort()
        raise
    finally:
        bar.close()
    if outputs is not None:
        outputs.close()
    record = eval_record(evaluation, path, args.params)
    metrics, result = evaluation.metrics, evaluation.result
    for line in metrics["losses"]:
        print(f"lost: {line}", file=sys.stderr)
    print(format_table([metrics]))
    for reason, count in sorted(result.refused.items()):
        print(f"{count} frame(s) refused: {reason}", file=sys.stderr)
    if metrics.get("frames_with_truth", 0) == 0:
        print(f"nothing to score: {path} has no ground truth ({bag.topics.ground_truth}); "
              f"{metrics['frames']} frame(s) ran" + (f", outputs in {args.out}" if args.out else
                                                      "; --out OUT.mcap saves the outputs"))
    else:
        _print_drive_keys(metrics)  # docs/interface/evaluation.md: the previews at the wheels' arrival (and the map)
        _print_far_field(metrics)
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
        if record.get("self_check"):
            print(f"self-check: {record['self_check']}")
    if outputs is not None:
        counts = ", ".join(f"{t}: {n}" for t, n in sorted(outputs.counts.items()))
        print(f"outputs written to {args.out} ({counts})")
    if args.json:
        _write_output(args.json, to_json(record), "metrics")
    if metrics["frames"] == 0 and result.refused:
        reasons = "; ".join(f"{n} x {reason}" for reason, n in sorted(result.refused.items()))
        raise CommandError(f"every frame was refused: {reasons}")
    if metrics.get("frames_with_truth", 0) > 0 and metrics.get("coverage_pct") == 0:
        raise CommandError("every frame came out empty (coverage 0 %)"
                           + (f": {record['self_check']}" if record.get("self_check") else ""))
    return 0


def _checkpoint_digest(config: RoadbevConfig) -> str | None:
    """The content digest of the checkpoint file the settings name (None: the shipped one)."""
    checkpoint = config.backend.options_of().get("checkpoint")
    if not checkpoint or not Path(str(checkpoint)).is_file():
        return None
    return content_digest(Path(str(checkpoint)))


def _run_many(args: argparse.Namespace) -> int:
    """Many bags (:mod:`roadbev_cli.fleet`): run them, write the summary and the report."""
    if args.out:
        raise CommandError("--out writes one bag's outputs: evaluate that bag alone to keep them")
    if args.frames is not None and args.frames < 1:
        raise CommandError(f"--frames must be >= 1, got {args.frames}")
    config, grid_overrides, given = _settings(args)
    if "inference_threads" not in given:  # the pool parallelises over bags: one thread per task
        config = config.with_params({"inference_threads": 1})
    settings = EvalSettings(config, grid_overrides, args.map, args.lead_time, args.frames,
                            str(args.params) if args.params else None)
    params = config.to_params()
    params["checkpoint"] = _checkpoint_digest(config)  # the checkpoint's content, not its path, makes the result
    store = ResultStore(args.store)
    fleet = run_fleet("eval", args, args.bag, settings,
                      {"params": params, "grid_overrides": grid_overrides, "map": args.map,
                       "lead_time_s": args.lead_time, "frames": args.frames}, store)
    run_record = {"command": "roadbev eval", "backend": config.backend.name,
                  "backend_options": config.backend.options_of(), "params_file": settings.params_file,
                  "lead_time_s": args.lead_time, "frames": args.frames, "map": args.map, "store": str(args.store),
                  "executor": fleet.executor, "wall_s": fleet.wall_s}
    summary = eval_summary(fleet.outcomes, store, run_record)
    report = eval_report(summary)
    print(report, end="")
    if args.report:
        _write_output(args.report, report, "report")
    if args.json:
        _write_output(args.json, to_json(summary), "summary")
    fail_on_failed_bags(fleet)
    return 0
