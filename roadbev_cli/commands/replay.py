"""``roadbev replay BAG``: publish a bag's topics over ROS 2 with their original timing.

Messages go out as the bag's raw CDR bytes (no re-serialisation), paced by their log times and
the rate factor; the Fast DDS profile for large images is applied (``config/fastdds.xml``). The
publishers are reliable, keep-last: 10 samples, or a second of the topic at its rate in the bag
where that is more (a 100 Hz IMU keeps 100), so a subscriber that falls behind for up to a second
misses nothing.

Before the first message the replay waits (``--wait-for-subscribers S``, default 10 s;
``--no-wait`` to start at once) until every replayed image topic has a subscriber (every replayed
topic when the bag has no images), so a node started just before misses no frame. When the wait
times out the replay says which topics have no subscriber (and when a subscriber listens on the
other transport: ``/compressed`` versus raw) and starts anyway: a viewer alone still gets the bag.

A truncated, unfinished or partly damaged bag is published as far as it is readable; what was
left out is printed, and the exit is 0. Only a bag of which nothing could be published exits 2
(the rule of every command that reads a bag: docs/tutorials/faults.md, "Crashes, damaged and truncated bags").
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from msg_bridge.bag import bag_topics
from roadbev_cli.cli import (
    CommandError,
    add_output_flags,
    output_path,
    progress_bar,
    shows_progress,
    topic_name,
    warn,
)
from roadbev_core.errors import RoadbevError
from roadbev_lab.evaluation.frames import to_json
from roadbev_ros.dds import init_ros
from roadbev_ros.diagnostics import COMPRESSED_SUFFIX, other_transport
from roadbev_ros.replay import IMAGE_TYPES, replay_bag

HELP = "publish a bag's topics over ROS 2 with their original timing"
DEFAULT_WAIT_S = 10.0
MIN_RATE, MAX_RATE = 1e-3, 1000.0  # speed factors a replay can keep (a slower one would seem to hang)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", type=Path, help="rosbag2 directory or .mcap file")
    parser.add_argument("--rate", type=float, default=1.0,
                        help=f"speed factor in [{MIN_RATE:g}, {MAX_RATE:g}] (default 1.0; 0 = as fast as possible)")
    parser.add_argument("--loop", action="store_true", help="start again at the end (Ctrl-C stops)")
    parser.add_argument("--topics", nargs="+", type=topic_name, metavar="TOPIC",
                        help="only these topics (space-separated)")
    parser.add_argument("--restamp", action="store_true",
                        help="set header stamps to the wall-clock publication time")
    parser.add_argument("--clock", action="store_true", help="publish /clock with the bag time")
    wait = parser.add_mutually_exclusive_group()
    wait.add_argument("--wait-for-subscribers", type=float, default=DEFAULT_WAIT_S, metavar="S",
                      help="wait up to S seconds for a subscriber on every replayed image topic (every "
                           f"topic when the bag has no images) before starting (default {DEFAULT_WAIT_S:g}); "
                           "on a timeout say which topics have none and replay anyway")
    wait.add_argument("--no-wait", action="store_true", help="start at once, subscribed or not")
    parser.add_argument("--json", type=output_path, metavar="OUT", help="write the replay statistics here")
    add_output_flags(parser)


def waited_topics(bag_path: Path, topics: list[str] | None) -> list[str] | None:
    """The topics the replay waits for: the replayed image topics (None = all, when none)."""

    available = bag_topics(bag_path)
    images = [t for t, info in available.items() if info.msgtype in IMAGE_TYPES and (topics is None or t in topics)]
    return images or None


def transport_hint(node: Any, topic: str) -> str:
    """Why ``topic`` may have no subscriber: someone listens on its other image transport."""

    other = other_transport(topic)
    if node.count_subscribers(other) == 0:
        return ""
    transport = "compressed" if topic.endswith(COMPRESSED_SUFFIX) else "raw"
    return (f" ({other} has a subscriber: the bag's images are {transport}, start the node with "
            f"-p image_transport:={transport})")


def published_of_bag(bag: Path, per_topic: Mapping[str, int]) -> str:
    """What a stopped replay published of each topic of the bag: ``/a 12 of 40, /b 0 of 3``."""
    try:
        totals = {topic: info.count for topic, info in bag_topics(bag).items()}
    except (RoadbevError, OSError):
        totals = {}
    topics = sorted(set(totals) | set(per_topic))
    return ", ".join(f"{t} {per_topic.get(t, 0)}" + (f" of {totals[t]}" if t in totals else "") for t in topics)


def run(args: argparse.Namespace) -> int:

    if not (args.rate == 0 or MIN_RATE <= args.rate <= MAX_RATE):
        raise CommandError(f"--rate must be 0 (as fast as possible) or in [{MIN_RATE:g}, {MAX_RATE:g}], "
                           f"got {args.rate}")
    if not args.wait_for_subscribers >= 0:
        raise CommandError(f"--wait-for-subscribers must be >= 0 s, got {args.wait_for_subscribers}")
    if not args.bag.exists():
        raise OSError(f"bag not found: {args.bag}")
    wait_s = 0.0 if args.no_wait else args.wait_for_subscribers
    wait_topics = waited_topics(args.bag, args.topics) if wait_s > 0 else None
    rclpy = init_ros(handle_signals=False)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    node = rclpy.create_node("roadbev_replay")
    bar = progress_bar(unit="msg", desc="replay", disable=not shows_progress(args))

    def unmatched(topics: list[str]) -> None:
        for topic in topics:
            warn("replay", f"no subscriber on {topic} after {wait_s:g} s{transport_hint(node, topic)}; "
                 "replaying anyway")

    try:
        stats = replay_bag(
            node,
            args.bag,
            rate=args.rate,
            loop=args.loop,
            topics=args.topics,
            restamp=args.restamp,
            publish_clock=args.clock,
            wait_for_subscribers=wait_s,
            wait_topics=wait_topics,
            stop=stop,
            progress=lambda n: bar.update(1),
            on_wait_timeout=unmatched,
        )
    finally:
        bar.close()
        node.destroy_node()
        rclpy.try_shutdown()
    for topic, reason in stats.skipped_topics.items():
        warn("replay", f"skipped {topic}: {reason}")
    if not stats.bag_complete:
        lost = ", ".join(f"{t}: {n}" for t, n in sorted(stats.lost.items())) or "none known"
        warn("replay", f"the bag is not whole: published what is readable; messages left out: {lost}")
        for problem in stats.read_problems:
            print(f"  {problem}", file=sys.stderr)
    if stop.is_set():
        warn("replay", f"interrupted after {stats.duration_s:.2f} s: {published_of_bag(args.bag, stats.per_topic)}")
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
