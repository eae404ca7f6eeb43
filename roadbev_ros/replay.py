"""Publish a bag's messages over ROS 2 with their original timing, as raw CDR bytes.

The bag's serialised messages go to ``publisher.publish(bytes)`` unchanged (no deserialising and
re-serialising), paced by their log times: message ``k`` is published at
``start + (t_k - t_0) / rate`` on the monotonic clock, so timing errors do not accumulate; the
lateness of every publication is measured and returned. ``restamp`` rewrites the header stamp in
the raw bytes (the 8 bytes after the CDR encapsulation header, for types whose first field is a
``std_msgs/Header``) to the wall-clock time of publication, mapping equal stamps to equal stamps,
so a node's end-to-end latency (now minus header stamp) can be measured from a recorded bag.

A truncated, unfinished or partly damaged bag is replayed as far as it is readable: damaged
chunks are skipped, and :attr:`ReplayStats.read_problems` and :attr:`ReplayStats.lost` say what
was left out and why.
"""

from __future__ import annotations

import math
import struct
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from queue import Empty, Full, Queue
from typing import Any, cast

from msg_bridge import bag
from roadbev_core.errors import RoadbevError
from roadbev_ros.dds import DdsError, message_class

__all__ = [
    "IMAGE_TYPES", "ReplayError", "ReplayStats", "header_stamp_ns", "history_depth", "replay_bag", "restamp_cdr",
    "starts_with_header",
]

# Message types a perception node subscribes to first: ``roadbev replay`` waits for subscribers
# on the bag's topics of these types by default.
IMAGE_TYPES = frozenset({"sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage"})


def history_depth(count: int, span_s: float, min_depth: int, history_s: float) -> int:
    """A publisher's keep-last depth for a topic of ``count`` messages over ``span_s`` seconds of
    bag: at least ``min_depth``, and ``history_s`` seconds of the topic at its mean rate, so that a
    reliable subscriber that falls that far behind (a recorder while its disk flushes, a loaded
    CPU) still receives every sample instead of the writer overwriting the ones it has not acked."""
    if count <= 1 or span_s <= 0:
        return min_depth
    return max(min_depth, math.ceil(count / span_s * history_s))


class ReplayError(RoadbevError, RuntimeError):
    """A bag that cannot be replayed (missing, unreadable, no publishable topic)."""


@dataclass
class ReplayStats:
    """What a replay published and how punctually.

    Attributes:
        messages: messages published.
        per_topic: topic -> messages published.
        duration_s: wall time from the first to the last publication.
        late_p50_ms, late_p95_ms, late_max_ms: publication time minus schedule.
        skipped_topics: topic -> why it was not replayed.
        loops: passes over the bag.
        stamp_offset_ns: with restamp, new stamp minus old stamp of the last pass (rate 1).
        lost: topic -> messages of the bag left out because their chunk is damaged (last pass).
        read_problems: what was damaged or missing in the bag (empty for a sound bag).
        bag_complete: the bag was read whole (closed cleanly, nothing damaged).
        waited_s: time spent waiting for subscribers before the first message.
        unmatched: topics waited on that still had no subscriber when the wait timed out.
    """

    messages: int = 0
    per_topic: dict[str, int] = field(default_factory=dict)
    duration_s: float = 0.0
    late_p50_ms: float = 0.0
    late_p95_ms: float = 0.0
    late_max_ms: float = 0.0
    skipped_topics: dict[str, str] = field(default_factory=dict)
    loops: int = 0
    stamp_offset_ns: int = 0
    lost: dict[str, int] = field(default_factory=dict)
    read_problems: list[str] = field(default_factory=list)
    bag_complete: bool = True
    waited_s: float = 0.0
    unmatched: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@cache
def starts_with_header(msgtype: str) -> bool:
    """Whether the first field of ``msgtype`` is a ``std_msgs/Header`` (restampable)."""
    try:
        _consts, fields = bag.typestore().fielddefs[msgtype]
    except KeyError:
        return False
    if not fields:
        return False
    name, (_kind, detail) = fields[0]
    return cast("bool", name == "header" and detail == "std_msgs/msg/Header")


def restamp_cdr(data: bytes, stamp_ns: int) -> bytes:
    """``data`` (a CDR message whose first field is a Header) with its stamp set to ``stamp_ns``."""
    if len(data) < 12:
        raise ReplayError("message too short to carry a header")
    little = data[1] & 1  # encapsulation kind: 0x0001 = CDR_LE, 0x0000 = CDR_BE
    fmt = "<iI" if little else ">iI"
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    return data[:4] + struct.pack(fmt, sec, nsec) + data[12:]


def header_stamp_ns(data: bytes) -> int:
    """The header stamp of a CDR message whose first field is a Header."""
    fmt = "<iI" if data[1] & 1 else ">iI"
    sec, nsec = struct.unpack_from(fmt, data, 4)
    return cast("int", sec * 1_000_000_000 + nsec)


def _prefetched(messages: Iterator[Any], stop: threading.Event, depth: int = 256) -> Iterator[Any]:
    """``messages`` read ahead on a thread, so decompressing a chunk never delays a publication."""
    queue: Queue[Any] = Queue(maxsize=depth)
    done = object()
    halt = threading.Event()  # the consumer has left
    failure: list[BaseException] = []

    def read() -> None:
        try:
            for item in messages:
                while not (stop.is_set() or halt.is_set()):
                    try:
                        queue.put(item, timeout=0.1)
                        break
                    except Full:
                        continue
                if stop.is_set() or halt.is_set():
                    return
        except BaseException as exc:  # handed to the consumer, raised there
            failure.append(exc)
        queue.put(done)

    reader = threading.Thread(target=read, name="replay-reader", daemon=True)
    reader.start()
    try:
        while not stop.is_set():
            try:
                item = queue.get(timeout=0.1)
            except Empty:
                continue
            if item is done:
                break
            yield item
        if failure:
            raise failure[0]
    finally:
        halt.set()
        reader.join(timeout=1.0)


def _percentile(values: list[float], q: float) -> float:
    if not values:
        return 0.0
    values = sorted(values)
    return values[min(len(values) - 1, int(round((len(values) - 1) * q / 100.0)))]


def replay_bag(
    node: Any,
    path: str | Path,
    *,
    rate: float = 1.0,
    loop: bool = False,
    topics: Sequence[str] | None = None,
    restamp: bool = False,
    publish_clock: bool = False,
    wait_for_subscribers: float = 0.0,
    wait_topics: Sequence[str] | None = None,
    on_wait_timeout: Callable[[list[str]], object] | None = None,
    qos_depth: int = 10,
    history_s: float = 1.0,
    stop: threading.Event | None = None,
    progress: Callable[[int], object] | None = None,
    before_publish: Callable[[str, int, bytes], None] | None = None,
    linger_s: float = 0.5,
    settle_s: float = 0.5,
) -> ReplayStats:
    """Publish the bag through ``node``'s publishers with the original timing.

    Args:
        node: an rclpy node (its publishers are created here and destroyed at the end).
        path: a rosbag2 directory or ``.mcap`` file.
        rate: speed factor; 0 or less = as fast as possible.
        loop: start again at the end until ``stop`` is set.
        topics: only these topics (None = all topics whose message type is installed).
        restamp: set header stamps to the wall-clock publication time.
        publish_clock: publish ``/clock`` (rosgraph_msgs/Clock) with the bag time.
        wait_for_subscribers: wait up to this many seconds until every topic of ``wait_topics``
            has a subscriber before starting (0 = do not wait); on a timeout the replay starts
            anyway and :attr:`ReplayStats.unmatched` names the topics still without one.
        wait_topics: the topics to wait for (None = every replayed topic; topics not replayed
            are ignored). ``/clock`` is not waited for: a node on ``use_sim_time`` subscribes to
            it as it starts, before its own subscriptions.
        on_wait_timeout: called with the topics still without a subscriber when the wait timed
            out, before the first message goes out.
        qos_depth: reliable keep-last depth of the publishers, at least.
        history_s: a topic's publisher keeps this many seconds of it at its rate in the bag, when
            that is more than ``qos_depth`` (:func:`history_depth`: a 100 Hz IMU keeps 100).
        stop: set it to end the replay early.
        progress: called with the number of messages published so far, every message.
        before_publish: called ``(topic, log_time_ns, data)`` just before each publication; it
            may block (the online evaluation holds each image back until the node has answered
            the previous one).
        linger_s: how long the publishers stay up after the last message, so that best-effort
            subscribers still receive it.
        settle_s: with ``wait_for_subscribers``, how long to wait once every topic has a
            subscriber, so that the subscribers have matched the new publishers too.

    Raises:
        ReplayError: unreadable bag, or none of the asked topics can be published.
    """
    # lazy: rclpy loads after the caller chose its DDS domain (roadbev_ros.dds.init_ros)
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    path = Path(path)
    try:
        info = bag.bag_info(path, verify=False)
    except bag.BagError as exc:
        raise ReplayError(str(exc)) from None
    available, span_s = info.topics, (info.end_ns - info.start_ns) * 1e-9
    stats = ReplayStats()
    wanted = list(available) if topics is None else list(topics)
    for topic in wanted:
        if topic not in available:
            stats.skipped_topics[topic] = "not in the bag"
    qos = QoSProfile(depth=qos_depth, reliability=ReliabilityPolicy.RELIABLE)
    # a topic with a single message is taken for a latched one (configuration): late joiners get it
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    publishers: dict[str, Any] = {}
    for topic in wanted:
        if topic not in available:
            continue
        topic_info = available[topic]
        try:
            publishers[topic] = node.create_publisher(
                message_class(topic_info.msgtype), topic,
                latched if topic_info.count == 1 else
                QoSProfile(depth=history_depth(topic_info.count, span_s, qos_depth, history_s),
                           reliability=ReliabilityPolicy.RELIABLE),
            )
        except DdsError as exc:
            stats.skipped_topics[topic] = str(exc)
    if not publishers:
        if not stats.skipped_topics:
            raise ReplayError(f"nothing to replay from {path}: the bag holds no messages")
        reasons = "; ".join(f"{t}: {why}" for t, why in stats.skipped_topics.items())
        raise ReplayError(f"nothing to replay from {path} ({reasons}); the bag holds {', '.join(sorted(available))}"
                          if available else f"nothing to replay from {path} ({reasons})")
    clock_pub = None
    clock_msg = None
    if publish_clock:
        # lazy: rclpy loads after the caller chose its DDS domain (roadbev_ros.dds.init_ros)
        from rosgraph_msgs.msg import Clock

        clock_pub = node.create_publisher(Clock, "/clock", qos)
        clock_msg = Clock()
    stop = stop or threading.Event()
    waited_on = [publishers[t] for t in (publishers if wait_topics is None else wait_topics) if t in publishers]
    named = {id(p): t for t, p in publishers.items()}
    if wait_for_subscribers > 0 and waited_on:
        began = time.monotonic()
        deadline = began + wait_for_subscribers
        while not stop.is_set():
            if all(p.get_subscription_count() > 0 for p in waited_on):
                # Discovery is two-sided: the writer seeing a reader does not mean that reader
                # has matched the writer yet, and best-effort samples sent before it has are
                # lost (at times the first frames of a replay).
                time.sleep(settle_s)
                break
            if time.monotonic() >= deadline:
                stats.unmatched = [named[id(p)] for p in waited_on if p.get_subscription_count() == 0]
                if on_wait_timeout is not None:
                    on_wait_timeout(stats.unmatched)
                break
            time.sleep(0.02)
        stats.waited_s = time.monotonic() - began
    per_topic: Counter[str] = Counter()
    lateness_ms: list[float] = []
    first_wall = None
    last_wall = 0.0
    try:
        while not stop.is_set():
            stats.loops += 1
            bag_start: int | None = None
            read = bag.ReadStats()
            messages = bag.read_messages(path, list(publishers), raw=True, on_damage="skip", stats=read)
            for msg in _prefetched(messages, stop):
                if stop.is_set():
                    break
                if bag_start is None:  # the clock starts with the first message, after opening
                    bag_start = msg.log_time_ns
                    start_wall = time.monotonic()
                    start_unix_ns = time.time_ns()
                offset_s = (msg.log_time_ns - bag_start) * 1e-9
                if rate > 0:
                    target = start_wall + offset_s / rate
                    delay = target - time.monotonic()
                    while delay > 0 and not stop.is_set():
                        time.sleep(min(delay, 0.1))
                        delay = target - time.monotonic()
                    lateness_ms.append(max(0.0, -delay) * 1e3)
                data = bytes(msg.msg)
                if restamp and starts_with_header(msg.msgtype):
                    scale = rate if rate > 0 else 1.0
                    old = header_stamp_ns(data)
                    new = start_unix_ns + int((old - bag_start) / scale)
                    stats.stamp_offset_ns = new - old
                    data = restamp_cdr(data, new)
                if before_publish is not None:
                    before_publish(msg.topic, msg.log_time_ns, data)
                if clock_pub is not None and clock_msg is not None:
                    sec, nsec = divmod(msg.log_time_ns, 1_000_000_000)
                    clock_msg.clock.sec, clock_msg.clock.nanosec = sec, nsec
                    clock_pub.publish(clock_msg)
                publishers[msg.topic].publish(data)
                last_wall = time.monotonic()
                first_wall = first_wall if first_wall is not None else last_wall
                per_topic[msg.topic] += 1
                stats.messages += 1
                if progress is not None:
                    progress(stats.messages)
            stats.lost = dict(read.lost + read.undecodable)
            stats.read_problems = list(read.damage) + (
                ["the bag breaks off: what followed the cut is unknown"] if read.lost_unknown else [])
            stats.bag_complete = read.complete and not read.unfinished
            if read.unfinished and not read.lost_unknown:
                stats.read_problems.append("the bag was not closed cleanly (no summary)")
            if not loop or bag_start is None:
                break
    finally:
        # lazy: rclpy loads after the caller chose its DDS domain (roadbev_ros.dds.init_ros)
        from rclpy.duration import Duration

        for publisher in publishers.values():
            # reliable subscribers may still be fetching the last samples
            publisher.wait_for_all_acked(Duration(seconds=1.0))
        if stats.messages and not stop.is_set():
            # Best-effort subscribers (sensor-data QoS, as the node's) send no acks, and a writer
            # destroyed right after its last publish can take those samples with it (the bag's
            # last stereo set would then never complete in a lockstep replay).
            time.sleep(linger_s)
        for publisher in publishers.values():
            node.destroy_publisher(publisher)
        if clock_pub is not None:
            node.destroy_publisher(clock_pub)
    stats.per_topic = dict(per_topic)
    stats.duration_s = 0.0 if first_wall is None else last_wall - first_wall
    stats.late_p50_ms = _percentile(lateness_ms, 50)
    stats.late_p95_ms = _percentile(lateness_ms, 95)
    stats.late_max_ms = max(lateness_ms, default=0.0)
    return stats
