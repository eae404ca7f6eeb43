"""A fleet's evaluation: many bags on a local two-worker Ray cluster against the serial loop.

``--bags`` synthetic evaluation bags (``roadbev synth``, ``--frames`` each, seeds 0, 1, ...;
kept under ``.cache/fleet_bags/`` for the next run) are evaluated twice in one run, through the
same code as ``roadbev eval BAG...`` (:func:`roadbev_lab.fleet.runner.run_bags`, each time into a
fresh result store so that nothing is skipped):

* the serial loop: every bag in this process, one after another (:class:`~roadbev_lab.fleet.executors.SerialPool`);
* Ray: one task per bag on a local cluster of ``--workers`` CPUs
  (:class:`~roadbev_lab.fleet.executors.RayPool`), started and its workers warmed up (each has
  imported the evaluation) before the clock starts, as on a cluster that serves many runs; the
  start and the warm-up are recorded beside.

Both evaluate with one thread per task (``inference_threads: 1``, as ``roadbev eval`` over many
bags does). The JSON records both wall times, the speed-up, whether every bag's metrics and the
pooled metrics are identical (timing keys aside: :data:`roadbev_lab.evaluation.frames.TIMING_KEYS`),
the pooled metrics, and the serial loop's cost per frame (core-seconds: one core ran it).

Run: ``.venv/bin/python -m benchmarks.bench_fleet [--bags 20] [--frames 10] [--workers 2]
[--backend bm] [--image-scale 1]``; writes ``benchmarks/results/fleet.json``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

from benchmarks.common import CACHE, RESULTS, machine_info, write_json
from roadbev_cli.cli import main as roadbev
from roadbev_core.config import RoadbevConfig
from roadbev_lab.evaluation.frames import without_timing
from roadbev_lab.fleet.executors import Executor, RayPool, SerialPool
from roadbev_lab.fleet.runner import DONE, run_bags
from roadbev_lab.fleet.store import ResultStore, config_digest
from roadbev_lab.fleet.summary import eval_summary
from roadbev_lab.fleet.tasks import EvalSettings

TARGET_SPEEDUP = 1.7  # two workers on two cores, against the serial loop


def make_bags(count: int, frames: int, image_scale: float) -> list[Path]:
    """``count`` synthetic evaluation bags (seeds 0.. count-1), written once under ``.cache/fleet_bags/``."""
    folder = CACHE / "fleet_bags" / f"f{frames}_s{image_scale:g}"
    folder.mkdir(parents=True, exist_ok=True)
    bags = []
    for seed in range(count):
        bag = folder / f"bag_{seed:03d}.mcap"
        if not bag.exists():
            partial = bag.with_name(f".{bag.name}")
            partial.unlink(missing_ok=True)
            code = roadbev(["synth", str(partial), "--frames", str(frames), "--seed", str(seed), "--image-scale",
                            f"{image_scale:g}", "--quiet"])
            if code != 0:
                raise RuntimeError(f"roadbev synth failed for seed {seed}")
            partial.replace(bag)
        bags.append(bag)
    return bags


def _warm(_item: int) -> int:
    """A task that loads what an evaluation task imports (the worker's start-up, outside the clock)."""
    return os.getpid()


def timed_run(bags: list[Path], settings: EvalSettings, executor: Executor,
              store: Path) -> tuple[float, dict[str, Any]]:
    """Wall time of evaluating every bag on ``executor`` into a fresh store, and the summary."""
    results = ResultStore(store)
    start = time.perf_counter()
    outcomes = run_bags(bags, settings, config_digest({"bench_fleet": True}), executor, results, resume=False)
    wall = time.perf_counter() - start
    failed = [o for o in outcomes if o.status != DONE]
    if failed:
        raise RuntimeError(f"{len(failed)} bag(s) not evaluated: {failed[0].bag}: {failed[0].error}")
    return wall, eval_summary(outcomes, results, {"executor": executor.describe(), "wall_s": wall})


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_fleet", description=__doc__.splitlines()[0])
    parser.add_argument("--bags", type=int, default=20)
    parser.add_argument("--frames", type=int, default=10, help="frames per bag")
    parser.add_argument("--workers", type=int, default=2, help="CPUs of the local Ray cluster")
    parser.add_argument("--backend", default="bm")
    parser.add_argument("--image-scale", type=float, default=1.0, help="of the RSRD half-resolution rig (960 x 528)")
    parser.add_argument("--out", default=str(RESULTS / "fleet.json"))
    args = parser.parse_args(argv)
    if args.bags < 1 or args.frames < 2 or args.workers < 1:
        parser.error("--bags >= 1, --frames >= 2 (the first is the timing warm-up) and --workers >= 1")
    info = machine_info()
    bags = make_bags(args.bags, args.frames, args.image_scale)
    settings = EvalSettings(RoadbevConfig.from_params({"backend": args.backend, "inference_threads": 1}))
    scratch = CACHE / "fleet_bench_store"
    serial_s, serial = timed_run(bags, settings, SerialPool(), scratch / "serial")
    print(f"serial loop: {len(bags)} bags in {serial_s:.1f} s", file=sys.stderr, flush=True)
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    start = time.perf_counter()
    with RayPool("local", workers=args.workers) as ray:
        cluster_s = time.perf_counter() - start
        start = time.perf_counter()
        warm_pids = ray.map(_warm, list(range(4 * args.workers)))
        warm_s = time.perf_counter() - start
        ray_s, on_ray = timed_run(bags, settings, ray, scratch / "ray")
    print(f"Ray, {args.workers} workers: {len(bags)} bags in {ray_s:.1f} s (cluster start {cluster_s:.1f} s, "
          f"warm-up {warm_s:.1f} s)", file=sys.stderr, flush=True)
    same_bags = all(without_timing(a["result"]) == without_timing(b["result"])
                    for a, b in zip(serial["bags"], on_ray["bags"], strict=True))
    same_pooled = without_timing(serial["pooled"]) == without_timing(on_ray["pooled"])
    frames = int(serial["pooled"]["frames"])
    data = {
        "what": "roadbev eval over many bags: the serial loop against one task per bag on a local Ray cluster "
                "(bench_fleet; see its docstring)",
        "command": "python -m benchmarks.bench_fleet " + " ".join(argv if argv is not None else sys.argv[1:]),
        "machine": info,
        "bags": len(bags),
        "frames_per_bag": args.frames,
        "frames": frames,
        "image_scale": args.image_scale,
        "backend": args.backend,
        "workers": args.workers,
        "serial_s": serial_s,
        "ray_s": ray_s,
        "ray_cluster_start_s": cluster_s,
        "ray_warm_up_s": warm_s,
        "ray_worker_processes": len(set(warm_pids)),
        "speedup": serial_s / ray_s,
        "target_speedup": TARGET_SPEEDUP,
        "identical_per_bag": same_bags,
        "identical_pooled": same_pooled,
        "serial_core_s_per_frame": serial_s / frames,
        "ray_frames_per_s": frames / ray_s,
        "pooled": without_timing(serial["pooled"]),
    }
    write_json(Path(args.out), data)
    print(f"wrote {args.out}: speed-up {data['speedup']:.2f} (target {TARGET_SPEEDUP}), identical per bag "
          f"{same_bags}, pooled {same_pooled}", file=sys.stderr)
    return 0 if same_bags and same_pooled else 1


if __name__ == "__main__":
    raise SystemExit(main())
