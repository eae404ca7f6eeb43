"""``roadbev replay BAG``: publish a bag's topics over ROS 2 with their original timing.

Messages go out as the bag's raw CDR bytes (no re-serialisation), paced by their log times and
the rate factor; the Fast DDS profile for large images is applied (``config/fastdds.xml``).

A truncated, unfinished or partly damaged bag is published as far as it is readable; what was
left out is printed, and the exit is 0. Only a bag of which nothing could be published exits 2
(the rule of every command that reads a bag: README, "Damaged and truncated bags").
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

from roadbev_ros.cli import CommandError

HELP = "publish a bag's topics over ROS 2 with their original timing"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", type=Path, help="rosbag2 directory or .mcap file")
    parser.add_argument("--rate", type=float, default=1.0,
                        help="speed factor (default 1.0; 0 = as fast as possible)")
    parser.add_argument("--loop", action="store_true", help="start again at the end (Ctrl-C stops)")
    parser.add_argument("--topics", nargs="+", metavar="TOPIC", help="only these topics")
    parser.add_argument("--restamp", action="store_true",
                        help="set header stamps to the wall-clock publication time")
    parser.add_argument("--clock", action="store_true", help="publish /clock with the bag time")
    parser.add_argument("--wait-for-subscribers", type=float, default=0.0, metavar="S",
                        help="wait up to S seconds for a subscriber on every topic before starting")
    parser.add_argument("--json", type=Path, metavar="OUT", help="write the replay statistics here")
    parser.add_argument("--quiet", action="store_true", help="no progress output")


def run(args: argparse.Namespace) -> int:
    from roadbev_core.evaluation import to_json
    from roadbev_ros.dds import init_ros
    from roadbev_ros.replay import replay_bag

    if args.rate < 0 or args.rate != args.rate:
        raise CommandError(f"--rate must be >= 0, got {args.rate}")
    if not args.bag.exists():
        raise OSError(f"bag not found: {args.bag}")
    rclpy = init_ros(handle_signals=False)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    node = rclpy.create_node("roadbev_replay")
    bar = None
    if not args.quiet and sys.stderr.isatty():
        from tqdm import tqdm

        bar = tqdm(unit="msg", desc="replay")
    try:
        stats = replay_bag(
            node,
            args.bag,
            rate=args.rate,
            loop=args.loop,
            topics=args.topics,
            restamp=args.restamp,
            publish_clock=args.clock,
            wait_for_subscribers=args.wait_for_subscribers,
            stop=stop,
            progress=(lambda n: bar.update(1)) if bar is not None else None,
        )
    finally:
        if bar is not None:
            bar.close()
        node.destroy_node()
        rclpy.try_shutdown()
    for topic, reason in stats.skipped_topics.items():
        print(f"skipped {topic}: {reason}", file=sys.stderr)
    if not stats.bag_complete:
        lost = ", ".join(f"{t}: {n}" for t, n in sorted(stats.lost.items())) or "none known"
        print(f"the bag is not whole: published what is readable; messages left out: {lost}", file=sys.stderr)
        for problem in stats.read_problems:
            print(f"  {problem}", file=sys.stderr)
    if not args.quiet:
        print(
            f"published {stats.messages} messages on {len(stats.per_topic)} topics in "
            f"{stats.duration_s:.2f} s (lateness p95 {stats.late_p95_ms:.2f} ms, "
            f"max {stats.late_max_ms:.2f} ms)"
        )
    if args.json:
        args.json.write_text(to_json(stats.to_dict()))
    if stats.messages == 0 and not stop.is_set():
        raise CommandError(f"nothing could be published from {args.bag}")
    return 0
