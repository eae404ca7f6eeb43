"""What a subscriber to ``/roadbev/preview`` receives on a drive, over ROS 2, as a new user runs it.

Run (from the repository root)::

    .venv/bin/python -m benchmarks.bench_preview_stream                 # the default backend
    .venv/bin/python -m benchmarks.bench_preview_stream --backend bm --frames 20 --rate 0.5

A drive bag where the car rides on its road (``bench_node``'s: 10 m/s, 10 Hz camera, class C
with potholes and speed bumps, ``/odom`` and ``/tf_static``) is replayed with ``--clock`` into
three processes started as docs/tutorials/preview.md starts them: ``roadbev node`` (its defaults: the fused map
on), ``roadbev_preview_controller`` and ``roadbev record``. From the recording: every preview's
frame, reference, contact-plane source, vehicle speed and times of arrival (one reference per
drive, docs/concepts/preview.md: all in ``base_link`` against the contact plane, each with a
finite speed and times of arrival), the controller's last diagnostics (messages received and refused) and the median and
p95 of the fused map's ``uncertainty`` layer per message (bounded, and inside the shipped viewers'
0-2 cm colour range). Writes ``benchmarks/results/preview_stream.json``.
"""

from __future__ import annotations

import argparse
import collections
import math
import os
import random
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.bench_node import drive_bag
from benchmarks.common import RESULTS, machine_info, write_json
from msg_bridge.bag import read_messages
from roadbev_core.config import DEFAULT_BACKEND
from roadbev_lab.evaluation.online import PREVIEW_TOPIC, stop_process

MAP_TOPIC = "/roadbev/map"
FORCE_TOPIC = "/roadbev/suspension/force"
VIEWER_SIGMA_RANGE_M = 0.02  # config/roadbev.rviz and config/roadbev.foxglove.json colour the map's sigma over 0-2 cm
CONTROLLER_STATUS = "roadbev: preview controller"


def _wait_for(path: Path, text: str, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if path.exists() and text in path.read_text(errors="replace"):
            return
        time.sleep(0.5)
    raise RuntimeError(f"timed out waiting for {text!r} in {path}")


def run_chain(bag: Path, work: Path, backend: str, rate: float) -> Path:
    """Replay ``bag`` into the node, the reference controller and a recorder; the recording."""
    roadbev = [sys.executable, "-m", "roadbev_cli.cli"]
    recorded = work / "outputs.mcap"
    env = {**os.environ, "ROS_DOMAIN_ID": str(random.SystemRandom().randint(1, 100)),
           "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    logs = {name: work / f"{name}.log" for name in ("record", "controller", "node", "replay")}
    procs: list[subprocess.Popen[bytes]] = []

    def start(name: str, command: list[str]) -> subprocess.Popen[bytes]:
        with logs[name].open("wb") as log:
            proc = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=env)
        procs.append(proc)
        return proc

    try:
        start("record", [*roadbev, "record", str(recorded), "--topics", PREVIEW_TOPIC, MAP_TOPIC, FORCE_TOPIC,
                         "/diagnostics"])
        start("controller", [sys.executable, "-m", "roadbev_ros.preview_controller", "--ros-args",
                             "-p", "use_sim_time:=true"])
        start("node", [*roadbev, "node", "--ros-args", "-p", f"backend:={backend}", "-p", "use_sim_time:=true"])
        _wait_for(logs["record"], f"subscribed to {MAP_TOPIC}", 180.0)
        replay = start("replay", [*roadbev, "replay", str(bag), "--clock", "--rate", f"{rate:g}",
                                  "--wait-for-subscribers", "120"])
        if replay.wait() != 0:
            raise RuntimeError(f"replay failed: {logs['replay'].read_text(errors='replace')[-2000:]}")
        time.sleep(3.0)  # the last frame's outputs and one more second of the controller's diagnostics
    finally:
        for proc in reversed(procs):
            stop_process(proc, timeout=15.0)
    return recorded


def summarise(recorded: Path) -> dict[str, Any]:
    """The preview stream, the controller's last diagnostics and the map's sigma in a recording."""
    frames: collections.Counter[str] = collections.Counter()
    references: collections.Counter[str] = collections.Counter()
    sources: collections.Counter[str] = collections.Counter()
    previews = no_speed = no_arrival = in_stream = 0
    sigma_median_cm: list[float] = []
    sigma_p95_cm: list[float] = []
    controller: dict[str, str] = {}
    forces = 0
    for item in read_messages(recorded, on_damage="skip"):
        msg = item.msg
        if item.topic == PREVIEW_TOPIC:
            previews += 1
            frames[msg.header.frame_id] += 1
            references[msg.reference] += 1
            sources[msg.contact_plane_source] += 1
            arrival = np.asarray(msg.time_of_arrival, float)
            has_speed = math.isfinite(msg.vehicle_speed)
            has_arrival = arrival.size > 0 and bool(np.isfinite(arrival).all())
            no_speed += not has_speed
            no_arrival += not has_arrival
            in_stream += (msg.header.frame_id == "base_link" and msg.reference == "contact_plane"
                          and has_speed and has_arrival)
        elif item.topic == MAP_TOPIC:
            sigma = np.asarray(msg.data[list(msg.layers).index("uncertainty")].data, float)
            sigma = sigma[np.isfinite(sigma)]
            if sigma.size:
                sigma_median_cm.append(float(np.median(sigma)) * 100)
                sigma_p95_cm.append(float(np.percentile(sigma, 95)) * 100)
        elif item.topic == FORCE_TOPIC:
            forces += 1
        elif item.topic == "/diagnostics":
            for status in msg.status:
                if status.name == CONTROLLER_STATUS:
                    controller = {kv.key: kv.value for kv in status.values}
    return {
        "previews": previews,
        "frame_ids": dict(frames),
        "references": dict(references),
        "contact_plane_sources": dict(sources),
        "without_speed": no_speed,
        "without_times_of_arrival": no_arrival,
        # in base_link against the contact plane, with a finite speed and times of arrival
        "in_one_stream_pct": 100.0 * in_stream / previews if previews else math.nan,
        "controller": controller,
        "force_commands": forces,
        "map_messages": len(sigma_median_cm),
        "map_sigma_median_cm": sigma_median_cm,
        "map_sigma_p95_cm": sigma_p95_cm,
        "map_sigma_within_viewer_range": bool(sigma_median_cm) and max(sigma_median_cm) <= VIEWER_SIGMA_RANGE_M * 100,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backend", default=DEFAULT_BACKEND)
    parser.add_argument("--frames", type=int, default=60, help="frames of the drive (10 Hz camera)")
    parser.add_argument("--rate", type=float, default=1.0, help="replay rate factor (1: the bag's timing)")
    parser.add_argument("--out", type=Path, default=RESULTS / "preview_stream.json")
    args = parser.parse_args(argv)
    bag = drive_bag(args.frames, 1.0, riding=True, rate=10.0)
    start = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="preview_stream_") as tmp:
        summary = summarise(run_chain(bag, Path(tmp), args.backend, args.rate))
    result = {
        "what": "the preview stream a subscriber receives on a replayed drive (node defaults, map on), "
                "the reference controller's diagnostics and the fused map's sigma",
        "command": "python -m benchmarks.bench_preview_stream " + " ".join(sys.argv[1:] if argv is None else argv),
        "backend": args.backend,
        "bag": bag.name,
        "machine": machine_info(),
        "wall_s": round(time.monotonic() - start, 1),
        **summary,
    }
    write_json(args.out, result)
    print(f"{summary['previews']} previews: frames {summary['frame_ids']}, references {summary['references']}, "
          f"sources {summary['contact_plane_sources']}, without speed {summary['without_speed']}, without times "
          f"of arrival {summary['without_times_of_arrival']}; controller received "
          f"{summary['controller'].get('received')} refused {summary['controller'].get('refused')}; map sigma "
          f"median {min(summary['map_sigma_median_cm'], default=math.nan):.2f}-"
          f"{max(summary['map_sigma_median_cm'], default=math.nan):.2f} cm")
    return 0


if __name__ == "__main__":
    sys.exit(main())
