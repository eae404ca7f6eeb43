"""``roadbev record OUT.mcap --topics ...``: record topics to an MCAP bag.

Raw subscriptions (no deserialising), QoS matched to the publishers, each topic subscribed as
soon as it appears. Ctrl-C, SIGTERM or SIGHUP (or ``--duration`` / ``--max-messages``) ends the
recording and the file is closed cleanly. The bag is written in place as it grows (small chunks,
synced every 0.25 s): after a crash or ``kill -9`` the file holds everything received up to a
fraction of a second before, without its summary; ``roadbev bag recover`` makes a complete copy.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

from rclpy.executors import SingleThreadedExecutor

from roadbev_cli.cli import CommandError, add_output_flags, output_path, topic_name, warn
from roadbev_ros.dds import init_ros
from roadbev_ros.record import Recorder

HELP = "record topics to an MCAP bag"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("out", type=output_path, help="output .mcap file (or rosbag2 directory); must not exist")
    parser.add_argument("--topics", nargs="+", type=topic_name, required=True, metavar="TOPIC",
                        help="topics to record (space-separated)")
    parser.add_argument("--duration", type=float, default=0.0, metavar="S", help="stop after S seconds")
    parser.add_argument("--max-messages", type=int, default=0, metavar="N", help="stop after N messages")
    parser.add_argument("--compression", choices=("zstd", "none"), default="zstd",
                        help="MCAP chunk compression (default zstd)")
    add_output_flags(parser, progress=False)


def run(args: argparse.Namespace) -> int:

    if args.out.exists():
        raise OSError(f"{args.out} exists already; not overwriting it")
    if args.duration < 0 or args.max_messages < 0:
        raise CommandError("--duration and --max-messages must be >= 0")
    rclpy = init_ros(handle_signals=False)

    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, lambda *_: stop.set())
    node = rclpy.create_node("roadbev_record")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    recorder = Recorder(node, args.out, args.topics, compression=args.compression)
    print(f"recording {', '.join(args.topics)} to {args.out} (Ctrl-C to stop)", file=sys.stderr, flush=True)
    start = time.monotonic()
    try:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)
            if args.duration and time.monotonic() - start >= args.duration:
                break
            if args.max_messages and recorder.total() >= args.max_messages:
                break
    finally:
        counts = recorder.close()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    if not args.quiet:
        summary = ", ".join(f"{t}: {n}" for t, n in sorted(counts.items())) or "nothing"
        print(f"recorded {sum(counts.values())} messages to {args.out} ({summary})")
    for problem in recorder.problems:
        warn("record", f"not recorded: {problem}")
    subscribed = set(recorder.subscribed)
    for topic in args.topics:
        if counts.get(topic, 0) == 0:
            why = "no message arrived" if topic in subscribed else "nothing published it (never discovered)"
            warn("record", f"{topic}: 0 messages recorded: {why}")
    return 0
