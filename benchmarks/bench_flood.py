"""The node under an input flood: images and IMU far faster than it can process, overlapping.

Run (from the repository root)::

    .venv/bin/python -m benchmarks.bench_flood                 # 10x and 12.5x a 5 Hz / 100 Hz drive
    .venv/bin/python -m benchmarks.bench_flood --rates 10 --frames 60

A synthetic drive (5 Hz stereo at 960 x 528, 100 Hz IMU) is replayed into the node (its own
process, default backend and parameters, ``diagnostics.max_latency_s`` at its default) at
``--rates`` times its speed: at 10x that is 50 Hz image pairs and 1 kHz IMU, at 12.5x 62.5 Hz and
1.25 kHz, far more than any backend answers on this machine. The node keeps only the newest
image set (its mailbox) and must not let its outputs go stale: an output ready later than
``max_latency_s`` after its input arrived is not published but counted (``dropped_stale``), and
its diagnostics must say so while it lasts. The IMU flood must not starve the images (both are
served by one executor): outputs keep coming.

Measured per rate, from the recording of the node's outputs (``/roadbev/elevation_map`` and
``/diagnostics``): end-to-end latency of the published outputs (left image leaving the replay
process to its map arriving in the recording process), outputs per second, the node's own
counts (sets taken, dropped for staleness, superseded in the mailbox) and the levels of its
diagnostics during the flood. Writes ``benchmarks/results/flood.json``.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path
from typing import Any

from benchmarks.bench_node import drive_bag
from benchmarks.common import RESULTS, machine_info, write_json
from msg_bridge.bag import read_messages
from roadbev_core.config import DEFAULT_BACKEND, RoadbevConfig
from roadbev_lab.evaluation.online import evaluate_online

BOUND_S = RoadbevConfig().diagnostics.max_latency_s
DIAGNOSTIC_LEVELS = {0: "ok", 1: "warn", 2: "error", 3: "stale"}
PIPELINE_STATUS = "roadbev: pipeline"  # the node's overall status (roadbev_ros.diagnostics)


def diagnostics_levels(recorded: Path, status_name: str = PIPELINE_STATUS) -> dict[str, Any]:
    """The node's pipeline status on ``/diagnostics`` in a recording: how many reports at each
    level, how many of them named the flood (sets dropped while the backend was busy) and the
    latency bound (outputs late or not published), their distinct messages, and the last
    report's values."""
    counts = dict.fromkeys(DIAGNOSTIC_LEVELS.values(), 0)
    latency_reports = flood_reports = 0
    messages: dict[str, int] = {}
    last: dict[str, str] = {}
    for message in read_messages(recorded, ["/diagnostics"]):
        for status in message.msg.status:
            if status.name != status_name:
                continue
            level = int.from_bytes(status.level, "little") if isinstance(status.level, bytes) else int(status.level)
            counts[DIAGNOSTIC_LEVELS.get(level, "stale")] += 1
            text = str(status.message)
            messages[text] = messages.get(text, 0) + 1
            latency_reports += int(level > 0 and "max_latency_s" in text)
            flood_reports += int(level > 0 and "dropped while the backend was busy" in text)
            last = {kv.key: kv.value for kv in status.values}
    return {"reports": counts, "flood_reports": flood_reports, "latency_reports": latency_reports,
            "messages": messages, "last_values": last}


def _int(values: dict[str, str], key: str) -> int | None:
    try:
        return int(values[key])
    except (KeyError, ValueError):
        return None


def run_rate(bag: Path, rate: float, work: Path, backend: str) -> dict[str, Any]:
    """One flood: the drive replayed at ``rate`` times its speed into the node."""
    result = evaluate_online(bag, work / f"rate_{rate:g}", backend=backend, rate=rate)
    online = result.metrics["online"]
    diagnostics = diagnostics_levels(result.recorded)
    last = diagnostics["last_values"]
    wall = online["wall_s"]
    latency = online["latency_ms"]
    return {
        "rate_factor": rate,
        "image_hz": 5.0 * rate,
        "imu_hz": 100.0 * rate,
        "frames_published": online["frames_published"],
        "outputs": online["outputs_matched"],
        "outputs_per_s": online["outputs_matched"] / wall if wall > 0 else math.nan,
        "latency_ms": latency,
        "dropped_stale": _int(last, "dropped_stale"),
        "node_values": last,
        "diagnostics": {k: diagnostics[k] for k in ("reports", "flood_reports", "latency_reports", "messages")},
        "targets": {
            "published_latency_p95_under_bound": bool(latency["p95"] < BOUND_S * 1e3),
            "outputs_keep_coming": online["outputs_matched"] > 0,
            "diagnostics_warn_of_the_flood": diagnostics["flood_reports"] > 0,
            # whenever an output was late, the diagnostics named the bound while it lasted
            "diagnostics_name_the_bound_when_outputs_are_late": (
                diagnostics["latency_reports"] > 0 or not _int(last, "dropped_stale")),
        },
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rates", type=float, nargs="+", default=[10.0, 12.5],
                        help="replay speed factors of the 5 Hz / 100 Hz drive (default 10 12.5)")
    parser.add_argument("--frames", type=int, default=200, help="frames of the drive (default 200: a 4 s flood at 10x)")
    parser.add_argument("--backend", default=DEFAULT_BACKEND, help=f"the node's backend (default {DEFAULT_BACKEND})")
    parser.add_argument("--out", type=Path, default=RESULTS / "flood.json", help="result file")
    args = parser.parse_args(argv)
    if not all(r > 0 and math.isfinite(r) for r in args.rates):
        parser.error("--rates must be finite and > 0")
    bag = drive_bag(args.frames, 1.0)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for rate in args.rates:
            row = run_rate(bag, rate, Path(tmp), args.backend)
            rows.append(row)
            print(f"x{rate:g} ({row['image_hz']:g} Hz images, {row['imu_hz']:g} Hz IMU): "
                  f"{row['outputs']}/{row['frames_published']} outputs, {row['outputs_per_s']:.1f}/s, "
                  f"latency p50 {row['latency_ms']['p50']:.0f} ms p95 {row['latency_ms']['p95']:.0f} ms, "
                  f"dropped stale {row['dropped_stale']}, diagnostics {row['diagnostics']['reports']} "
                  f"({row['diagnostics']['flood_reports']} naming the flood, "
                  f"{row['diagnostics']['latency_reports']} max_latency_s)",
                  flush=True)
    command = "python -m benchmarks.bench_flood " + " ".join(sys.argv[1:] if argv is None else argv)
    write_json(args.out, {"command": command.strip(), "machine": machine_info(), "backend": args.backend,
                          "max_latency_s": BOUND_S, "drive": {"frames": args.frames, "image_hz": 5.0, "imu_hz": 100.0},
                          "rows": rows})
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
