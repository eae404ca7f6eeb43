"""Which image sizes the shipped Fast DDS profile (``config/fastdds.xml``) delivers between processes.

Run (from the repository root)::

    .venv/bin/python -m benchmarks.bench_dds_sizes                      # 4 .. 190 MiB, both QoS
    .venv/bin/python -m benchmarks.bench_dds_sizes --sizes 8 48 70 --repeat 3

A subscriber process (this module with ``--subscriber``) listens on ``/bench_dds/image`` with a
reliable or a best-effort (the node's sensor-data QoS) subscription; this process publishes one
``sensor_msgs/Image`` (rgb8, square) per size, ``--gap`` seconds apart, reliable, and waits for the
acknowledgements. Every image is counted as delivered or lost. Private domain id, localhost only.
Writes ``benchmarks/results/dds_sizes.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from benchmarks.common import RESULTS, machine_info, write_json

TOPIC = "/bench_dds/image"


def subscribe(best_effort: bool, seconds: float) -> None:
    """The subscriber process: prints the size of every image it receives, one per line."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    from roadbev_ros.dds import init_ros

    rclpy = init_ros()
    node = rclpy.create_node("bench_dds_subscriber")
    reliability = ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE
    node.create_subscription(Image, TOPIC, lambda m: print(len(m.data), flush=True),
                             QoSProfile(depth=2, reliability=reliability))
    print("ready", flush=True)
    from rclpy.executors import ExternalShutdownException

    end = time.monotonic() + seconds
    try:
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.1)
    except (ExternalShutdownException, KeyboardInterrupt):  # terminated by the publisher
        pass
    node.destroy_node()
    rclpy.try_shutdown()


def image(mib: float) -> Any:
    from sensor_msgs.msg import Image

    side = int((mib * 2**20 / 3) ** 0.5)
    msg = Image()
    msg.height = msg.width = side
    msg.encoding = "rgb8"
    msg.step = 3 * side
    msg.data = bytes(3 * side * side)
    return msg


def run(sizes: list[float], best_effort: bool, gap_s: float, env: dict[str, str]) -> list[dict[str, Any]]:
    from rclpy.duration import Duration
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    from roadbev_ros.dds import init_ros

    seconds = len(sizes) * (gap_s + 3.0) + 20.0
    args = [sys.executable, "-m", "benchmarks.bench_dds_sizes", "--subscriber", str(seconds)]
    sub = subprocess.Popen(args + (["--best-effort"] if best_effort else []), stdout=subprocess.PIPE, text=True,
                           env=env)
    assert sub.stdout is not None
    assert sub.stdout.readline().strip() == "ready"
    rclpy = init_ros()
    node = rclpy.create_node("bench_dds_publisher")
    pub = node.create_publisher(Image, TOPIC, QoSProfile(depth=2, reliability=ReliabilityPolicy.RELIABLE))
    while pub.get_subscription_count() == 0:
        time.sleep(0.05)
    time.sleep(1.0)
    sent = []
    for mib in sizes:
        msg = image(mib)
        pub.publish(msg)
        pub.wait_for_all_acked(Duration(seconds=10))
        sent.append(len(msg.data))
        time.sleep(gap_s)
    node.destroy_node()
    sub.terminate()
    received = [int(line) for line in sub.stdout.read().split() if line.isdigit()]
    sub.wait(10)
    out = []
    for mib, nbytes in zip(sizes, sent, strict=True):
        delivered = nbytes in received
        if delivered:
            received.remove(nbytes)
        out.append({"mib": mib, "bytes": nbytes, "delivered": delivered})
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=float, nargs="+", default=[4, 8, 16, 32, 48, 60, 63, 65, 70, 100, 190])
    parser.add_argument("--repeat", type=int, default=2, help="passes over the sizes per QoS")
    parser.add_argument("--gap", type=float, default=1.0, help="seconds between two images")
    parser.add_argument("--subscriber", type=float, metavar="S", help=argparse.SUPPRESS)
    parser.add_argument("--best-effort", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, default=RESULTS / "dds_sizes.json")
    args = parser.parse_args(argv)
    if args.subscriber is not None:
        subscribe(args.best_effort, args.subscriber)
        return 0
    domain = str(random.SystemRandom().randint(101, 200))
    os.environ.update(ROS_DOMAIN_ID=domain, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    from roadbev_ros.dds import child_env, profile_path

    env = child_env()
    results: dict[str, Any] = {"profile": str(profile_path().name), "gap_s": args.gap, "machine": machine_info()}
    for qos in ("reliable", "best_effort"):
        runs = [run(list(args.sizes), qos == "best_effort", args.gap, env) for _ in range(args.repeat)]
        per_size = {f"{mib:g}": sum(r[i]["delivered"] for r in runs) for i, mib in enumerate(args.sizes)}
        results[qos] = {"delivered_of": args.repeat, "delivered_by_mib": per_size}
        print(qos, json.dumps(per_size))
    write_json(args.out, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
