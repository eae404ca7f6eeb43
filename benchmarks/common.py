"""The synthetic evaluation set and helpers shared by the benchmark scripts.

The evaluation set uses seeds from :data:`EVAL_SEED_BASE` upward, disjoint from the training
seeds (0..9,999) and from the bev_sweep tuning seeds (200,000+); every backend sees the same
frames.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from roadbev_core.config import GridSpec, StereoCamera, split_backend_spec
from roadbev_core.frame import Estimate, Frame
from roadbev_lab.evaluation.frames import to_json
from roadbev_lab.fleet.executors import Executor, FleetError, make_executor

__all__ = [
    "CACHE",
    "EVAL_SEED_BASE",
    "RESULTS",
    "add_appearance_argument",
    "add_executor_arguments",
    "available_backends",
    "backend_spec",
    "eval_samples",
    "executor_from",
    "machine_info",
    "scene_samples",
    "write_json",
]

RESULTS = Path(__file__).resolve().parent / "results"
CACHE = Path(__file__).resolve().parents[1] / ".cache"  # rendered scenes and drives, kept between runs
EVAL_SEED_BASE = 100_000

class ReplayBackend:
    """A backend that hands back estimates already made, in order (to score them again with
    :func:`roadbev_lab.evaluation.frames.evaluate`, e.g. pooled or interleaved runs)."""

    def __init__(self, name: str, grid: GridSpec, estimates: Iterable[Estimate], needs_stereo: bool) -> None:
        self.name = name
        self.grid = grid
        self.needs_stereo = needs_stereo
        self._estimates = iter(estimates)

    def estimate(self, frame: Frame) -> Estimate:
        return next(self._estimates)


def add_appearance_argument(parser: argparse.ArgumentParser, frames: str) -> None:
    """``--appearance NAME``: the range of ``roadbev_lab.synth.APPEARANCE_NAMES`` that ``frames``
    (the help's subject) draw their appearance from (``real-road``, the default) or ``clean``
    (the generator's own, scene version 1's default). Every function here that takes an
    appearance reads None as the default."""
    from roadbev_lab.synth.appearance import APPEARANCE_NAMES, DEFAULT_APPEARANCE

    parser.add_argument(
        "--appearance", default=DEFAULT_APPEARANCE, choices=APPEARANCE_NAMES,
        help=f"draw {frames} from this appearance range (default {DEFAULT_APPEARANCE}; clean: the "
             "generator's own before scene version 2)",
    )


def add_executor_arguments(parser: argparse.ArgumentParser, what: str) -> None:
    """``--jobs N`` (``what`` in N local processes) and ``--ray ADDRESS`` (as tasks on a Ray
    cluster: ``auto``, ``local`` or its address; :mod:`roadbev_lab.fleet.executors`). The results
    are the serial run's: every task is independent and deterministic, and comes back in order."""
    parser.add_argument("--jobs", type=int, default=1, help=f"{what} in parallel processes (default 1: in this one)")
    parser.add_argument("--ray", default=None, metavar="ADDRESS",
                        help=f"{what} as tasks on a Ray cluster: its address, 'auto' (this environment's) or "
                             "'local' (start one with --jobs CPUs)")


def executor_from(args: argparse.Namespace, parser: argparse.ArgumentParser) -> Executor:
    """The executor of :func:`add_executor_arguments`' options (refused through ``parser`` when it cannot start)."""
    try:
        return make_executor(args.jobs if args.ray is None or args.jobs > 1 else None, args.ray)
    except FleetError as exc:
        parser.error(str(exc))


def eval_samples(
    n_frames: int,
    *,
    camera: StereoCamera | None = None,
    grid: GridSpec | None = None,
    progress: Callable[[int], Any] | None = None,
    appearance: str | None = None,
) -> list[Any]:
    """``n_frames`` rendered samples (``DriveSample``), seeds ``EVAL_SEED_BASE + i``.

    Each seed draws its own road (``roadbev_lab.synth`` random roads: ISO 8608 class A-E, one to
    three features, asphalt or concrete, read noise 0.5-3 DN, gain mismatch up to 8 %, JPEG on
    about 30 % of frames) and camera attitude from the RSRD distribution, and its pavement and
    camera appearance from ``appearance`` (a name of ``roadbev_lab.synth.APPEARANCE_NAMES``;
    None: the default range).
    """
    from roadbev_lab.synth import appearance_range, make_sample

    drawn = appearance_range(appearance)
    out = []
    for i in range(n_frames):
        out.append(make_sample(EVAL_SEED_BASE + i, camera=camera, grid=grid, appearance=drawn))
        if progress is not None:
            progress(1)
    return out


def scene_samples(
    seeds: Iterable[int], grid: GridSpec, cache: str | Path | None = None, appearance: str | None = None
) -> list[tuple[Any, Any]]:
    """(frame, truth [n_rows, n_cols]) of the synthetic scenes ``seeds`` on the RSRD rig.

    With ``cache`` the scenes are rendered once into that folder
    (:class:`roadbev_lab.training.datasets.SyntheticSet`) and read back afterwards: the same frames,
    without minutes of rendering per benchmark run. ``appearance`` names the range of
    ``roadbev_lab.synth.APPEARANCE_NAMES`` to draw each scene's appearance from (None: the
    default range).
    """
    seeds = list(seeds)
    if cache is None:
        from roadbev_lab.synth import appearance_range, make_sample

        drawn = appearance_range(appearance)
        samples = (make_sample(seed, grid=grid, appearance=drawn) for seed in seeds)
        return [(s.frame, s.truth.elevation) for s in samples]
    from roadbev_lab.training.datasets import SyntheticSet

    scenes = SyntheticSet(cache, seeds, grid=grid, appearance=appearance)
    return [scenes[i] for i in range(len(scenes))]


def backend_spec(spec: str) -> tuple[str, dict[str, Any]]:
    """``NAME[:OPTION=VALUE,...]`` -> the backend name and its options as node parameters."""
    name, options = split_backend_spec(spec, "--backends")
    return name, {f"{name}.{key}": value for key, value in options.items()}


def available_backends(names: Iterable[str] = ("bev_sweep", "sgbm", "bm", "stereo", "mono", "gwcnet", "adabins")
                       ) -> dict[str, str]:
    """Backends that can be created here: name -> '' (ok) or the reason it is skipped."""
    from roadbev_core.backends import BackendError, create

    status: dict[str, str] = {}
    for name in names:
        try:
            create(name, GridSpec())
            status[name] = ""
        except (BackendError, ImportError, OSError, ValueError, RuntimeError) as exc:
            status[name] = f"{type(exc).__name__}: {exc}"
    return status


def machine_info() -> dict[str, Any]:
    """Where the numbers were measured."""
    import torch

    cpu = platform.processor() or platform.machine()
    try:
        with Path("/proc/cpuinfo").open() as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        load = os.getloadavg()
    except OSError:
        load = (math.nan, math.nan, math.nan)
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=False, timeout=5
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit = ""
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "python": sys.version.split()[0],
        "torch": torch.__version__,
        "load_average_at_start": [round(v, 2) for v in load],
        "git_commit": commit,
        "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }


def write_json(path: Path, data: dict[str, Any]) -> None:
    """Write strict JSON (NaN -> null)."""

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(to_json(data))
