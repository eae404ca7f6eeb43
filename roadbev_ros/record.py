"""Record topics into an MCAP bag from raw subscriptions (no deserialising).

Topics are subscribed as soon as they are discovered (their type comes from the graph), with the
publishers' reliability and durability ("auto" QoS, as ``ros2 bag record`` does) so that both
reliable and best-effort publishers are recorded. Each message is written with its receive time
as log time through :class:`msg_bridge.bag.BagWriter`, straight into the output file.

Crash safety: chunks are small (:data:`CHUNK_SIZE`) and a timer finishes the chunk in progress
and syncs the file to the disk every ``flush_period_s`` (0.25 s), so a recorder killed with
SIGKILL (or a power loss) leaves a bag that holds every message received more than about
``flush_period_s`` before; it lacks only its summary, and ``roadbev bag recover`` makes a
complete, indexed copy of it. Until :meth:`Recorder.close` finishes the file, a marker
``OUT.mcap.recording`` lies next to it. The ``roadbev record`` command closes the file on Ctrl-C,
SIGTERM and SIGHUP (a closed terminal).
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from msg_bridge.bag import BagWriter
from roadbev_core.errors import RoadbevError
from roadbev_ros.dds import DdsError, message_class

__all__ = ["CHUNK_SIZE", "RecordError", "Recorder"]

CHUNK_SIZE = 256 * 1024  # uncompressed bytes per chunk: what a crash can cost at most, besides the time bound


class RecordError(RoadbevError, RuntimeError):
    """A recording that cannot start (output exists, no topics)."""


class Recorder:
    """Records ``topics`` through ``node`` into ``out_path`` (spin the node to record).

    Args:
        node: an rclpy node; its executor must be spinning for messages to arrive.
        out_path: ``*.mcap`` file (or a rosbag2 directory), must not exist.
        topics: topic names to record.
        compression: "zstd" (chunk compression) or "none".
        depth: subscription queue depth.
        discovery_period_s: how often not yet seen topics are looked up.
        listener: called ``(topic, data)`` with every recorded message (raw CDR), after writing.
        flush_period_s: how often the chunk in progress is written and the file synced to the disk.
    """

    def __init__(
        self,
        node: Any,
        out_path: str | Path,
        topics: Sequence[str],
        *,
        compression: str = "zstd",
        depth: int = 100,
        discovery_period_s: float = 0.1,
        listener: Callable[[str, bytes], None] | None = None,
        flush_period_s: float = 0.25,
    ) -> None:
        if not topics:
            raise RecordError("no topics to record")
        self.node = node
        self.path = Path(out_path)
        self._writer = BagWriter(self.path, compression=compression, chunk_size=CHUNK_SIZE)
        self._writer.open()
        self._lock = threading.Lock()
        self._pending = [t if t.startswith("/") else f"/{t}" for t in topics]
        self._depth = depth
        self._listener = listener
        self._subs: dict[str, Any] = {}
        self.counts: Counter[str] = Counter()
        self.problems: list[str] = []
        self._closed = False
        self._timer = node.create_timer(discovery_period_s, self._discover)
        self._flush_timer = node.create_timer(flush_period_s, self._flush)
        self._discover()

    @property
    def subscribed(self) -> list[str]:
        return sorted(self._subs)

    def _qos_for(self, infos: Sequence[Any]) -> tuple[Any, bool]:
        """The subscription QoS matching a topic's publishers (their ``TopicEndpointInfo``), and
        whether they are all latched."""
        # lazy: rclpy loads after the caller chose its DDS domain (roadbev_ros.dds.init_ros)
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

        reliable = bool(infos) and all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos)
        latched = bool(infos) and all(
            i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos
        )
        return QoSProfile(
            depth=self._depth,
            reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
            durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
        ), latched

    def _discover(self) -> None:
        if not self._pending or self._closed:
            return
        graph = dict(self.node.get_topic_names_and_types())
        for topic in list(self._pending):
            types = graph.get(topic)
            if not types:
                continue
            infos = self.node.get_publishers_info_by_topic(topic)
            if not infos:
                continue
            msgtype = types[0]
            try:
                cls = message_class(msgtype)
            except DdsError as exc:
                self.problems.append(f"{topic}: {exc}")
                self._pending.remove(topic)
                continue
            qos, latched = self._qos_for(infos)
            with self._lock:
                self._writer.add_topic(topic, msgtype, latched=latched)
                self._subs[topic] = self.node.create_subscription(
                    cls, topic, lambda data, t=topic: self._write(t, data), qos, raw=True
                )
            self._pending.remove(topic)
            publishers = len(infos)
            self.node.get_logger().info(
                f"subscribed to {topic} ({msgtype}, {publishers} publisher{'s' if publishers != 1 else ''}, "
                f"{qos.reliability.name.lower()}{', latched' if latched else ''})"
            )
        if not self._pending:
            self._timer.cancel()

    def _write(self, topic: str, data: bytes) -> None:
        with self._lock:
            if self._closed:
                return
            self._writer.write_raw(topic, data, time.time_ns())
            self.counts[topic] += 1
        if self._listener is not None:
            self._listener(topic, data)

    def _flush(self) -> None:
        """Write the chunk in progress and sync the file (a crash then loses nothing older)."""
        with self._lock:
            if not self._closed and self._writer.pending:
                self._writer.flush(fsync=True)

    def total(self) -> int:
        """Messages recorded so far."""
        return sum(self.counts.values())

    def close(self) -> dict[str, int]:
        """Stop recording and finish the file; returns messages per topic."""
        with self._lock:
            if self._closed:
                return dict(self.counts)
            self._closed = True
            for timer in (self._timer, self._flush_timer):
                timer.cancel()
                self.node.destroy_timer(timer)
            for sub in self._subs.values():
                self.node.destroy_subscription(sub)
            self._writer.close()
        return dict(self.counts)
