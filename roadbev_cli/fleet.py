"""The options ``roadbev eval`` and ``roadbev label`` share for many bags at once (:mod:`roadbev_lab.fleet`).

A command runs over many bags when it is given more than one BAG, a glob pattern, a folder that
is not itself a bag but holds bags, or ``--workers`` / ``--ray``; one BAG alone (a bag) keeps the
one-bag behaviour and output.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from roadbev_cli.cli import CommandError, progress_bar, shows_progress, version
from roadbev_lab.fleet.executors import Executor, FleetError, make_executor
from roadbev_lab.fleet.runner import FAILED, BagOutcome, find_bags, is_bag, run_bags
from roadbev_lab.fleet.store import ResultStore, config_digest
from roadbev_lab.fleet.tasks import EvalSettings, LabelSettings

__all__ = ["FleetRun", "add_fleet_arguments", "fail_on_failed_bags", "run_fleet", "wants_fleet"]

_GLOB_CHARS = frozenset("*?[")


def add_fleet_arguments(parser: argparse.ArgumentParser, *, store: bool) -> None:
    """``--workers``, ``--ray``, ``--no-resume`` and (``store``) ``--store``."""
    group = parser.add_argument_group("many bags (a list, a folder of bags, a glob pattern)")
    group.add_argument("--workers", type=int, default=None, metavar="N",
                       help="bags run in parallel in N local processes (default: the CPU cores; 1: in this process); "
                            "with --ray local, the local cluster's CPUs")
    group.add_argument("--ray", default=None, metavar="ADDRESS",
                       help="run the bags as tasks on a Ray cluster: its address (HOST:PORT, ray://HOST:PORT), "
                            "'auto' (the cluster of this environment) or 'local' (start one here); needs the fleet "
                            "extra (pip install .[fleet])")
    if store:
        group.add_argument("--store", type=Path, default=Path(".cache") / "roadbev" / "fleet", metavar="DIR",
                           help="keep each bag's result here, keyed by the bag's content and the settings, so that "
                                "a run again skips the bags done (default .cache/roadbev/fleet)")
    group.add_argument("--no-resume", action="store_true",
                       help="run every bag again, even those whose result is in the store")


def wants_fleet(specs: Sequence[str | Path], args: argparse.Namespace) -> bool:
    """Whether the command runs over many bags (see the module docstring)."""
    if len(specs) != 1 or args.workers is not None or args.ray is not None:
        return True
    path = Path(specs[0])
    if not path.exists():
        return bool(_GLOB_CHARS & set(str(specs[0])))
    # a folder that is no bag (no metadata.yaml, no .mcap file of its own) but holds bags below
    return path.is_dir() and not is_bag(path) and not any(path.glob("*.mcap")) and \
        any(is_bag(p) for p in path.rglob("*"))


@dataclass(frozen=True)
class FleetRun:
    """Many bags run through one command: the bags found, their outcomes, what ran them and how long it took."""

    bags: list[Path]
    outcomes: list[BagOutcome]
    executor: dict[str, Any]
    wall_s: float


def run_fleet(command: str, args: argparse.Namespace, specs: Sequence[str | Path],
              settings: EvalSettings | LabelSettings, config: dict[str, Any], store: ResultStore,
              outputs: Callable[[list[Path]], dict[Path, Path]] | None = None) -> FleetRun:
    """Find the bags, open the executor, run every bag not done (:func:`roadbev_lab.fleet.runner.run_bags`).

    Args:
        command: ``eval`` or ``label`` (its name in the configuration's digest).
        config: everything else that changes a bag's result (its digest keys the store).
        outputs: the bags -> the file each one's task writes.

    Raises:
        CommandError: no bags, or an executor that cannot start (no Ray, no cluster).
    """
    try:
        bags = find_bags(specs)
    except FileNotFoundError as exc:
        raise CommandError(str(exc)) from None
    digest = config_digest({"command": command, "version": version(), **config})
    started = time.perf_counter()
    try:
        executor: Executor = make_executor(args.workers, args.ray)
    except FleetError as exc:
        raise CommandError(str(exc)) from None
    with executor, progress_bar(total=len(bags), unit="bag", desc=command, disable=not shows_progress(args),
                                leave=False) as bar:
        outcomes = run_bags(bags, settings, digest, executor, store, resume=not args.no_resume,
                            outputs=None if outputs is None else outputs(bags), progress=lambda _o: bar.update(1))
        described = executor.describe()
    return FleetRun(bags, outcomes, described, time.perf_counter() - started)


def fail_on_failed_bags(run: FleetRun) -> None:
    """Exit non-zero (after the summary is written) when a bag failed, with the first reason.

    Raises:
        CommandError: naming how many bags failed.
    """
    failed = [o for o in run.outcomes if o.status == FAILED]
    if failed:
        raise CommandError(f"{len(failed)} of {len(run.outcomes)} bag(s) failed (first: {failed[0].bag}: "
                           f"{failed[0].error}); the others' results are kept")
