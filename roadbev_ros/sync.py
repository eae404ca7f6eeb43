"""Approximate-time synchronisation of several topics, with ROS ``message_filters`` semantics.

``message_filters`` has no wheel on PyPI, so this is a small, dependency-free equivalent of its
``ApproximateTimeSynchronizer`` (the rclpy implementation):

* every topic keeps a queue of at most ``queue_size`` messages keyed by stamp; a message with a
  stamp already queued on its topic replaces the queued one, and the oldest message is dropped
  when the queue overflows;
* each arriving message is the pivot: the synchroniser looks for one message per other topic
  whose stamps, together with the pivot's, span at most ``slop``; the closest set (smallest span;
  on a tie the newest) wins and is emitted at once, and its messages leave the queues.

Two additions make it suitable for a node that must account for every frame:

* after a set is emitted, messages older than that set can never be emitted in stamp order, so
  they are discarded and reported through ``on_drop`` (``message_filters`` keeps them until they
  overflow the queue);
* a message older than the last emitted set on its topic (out of order) is refused and reported;
  one older by more than ``jump_back_s`` means the clock jumped back (a bag started again): the
  synchroniser resets itself (reported through ``on_reset``) and goes on from that message;
* the queues are bounded by bytes as well as by count (``max_bytes``, all topics together): large
  unpaired images are dropped, oldest first, before they can hold the memory of a whole queue.

Stamps are integer nanoseconds; ``slop`` is in seconds like ``message_filters``. Not thread-safe:
call :meth:`ApproximateTimeSync.add` from one thread (an rclpy single-threaded executor).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from roadbev_core.errors import RoadbevError

__all__ = ["ApproximateTimeSync", "DropReason", "SyncError"]


class SyncError(RoadbevError, ValueError):
    """A synchroniser configuration or message that cannot be used."""


class DropReason:
    """Why a message left a queue without being emitted (strings, for diagnostics)."""

    OVERFLOW = "queue overflow"
    OVERFLOW_BYTES = "queue over its byte bound"
    SUPERSEDED = "older than an emitted set"
    OUT_OF_ORDER = "out of order"
    DUPLICATE = "duplicate stamp"
    RESET = "the clock jumped back (reset)"


@dataclass
class _Stats:
    emitted: int = 0
    dropped: int = 0


class ApproximateTimeSync:
    """Pairs messages of ``n_topics`` topics whose stamps are within ``slop`` of each other.

    Args:
        n_topics: number of synchronised inputs (>= 1).
        queue_size: messages kept per topic (>= 1).
        slop: largest allowed spread of a set's stamps, seconds (>= 0).
        callback: called with the set's messages (in topic order) when a set is found.
        on_drop: called ``(topic_index, stamp_ns, message, reason)`` for every message that leaves
            a queue without being emitted.
        jump_back_s: a stamp this much older than its topic's last emitted one resets the
            synchroniser (None: never; such messages are refused as out of order).
        on_reset: called ``(topic_index, jump_ns)`` when a jump back reset the synchroniser.
        max_bytes: largest total size of the queued messages (as given to :meth:`add`); beyond
            it the oldest messages are dropped (None: no bound).
    """

    def __init__(
        self,
        n_topics: int,
        queue_size: int,
        slop: float,
        callback: Callable[..., None],
        on_drop: Callable[[int, int, Any, str], None] | None = None,
        jump_back_s: float | None = 1.0,
        on_reset: Callable[[int, int], None] | None = None,
        max_bytes: int | None = None,
    ) -> None:
        if n_topics < 1:
            raise SyncError(f"need at least one topic, got {n_topics}")
        self._queues: list[dict[int, Any]] = [{} for _ in range(n_topics)]
        self._sizes: list[dict[int, int]] = [{} for _ in range(n_topics)]
        self.queued_bytes = 0
        self.max_bytes = max_bytes
        self._last_emitted: list[int | None] = [None] * n_topics
        self._callback = callback
        self._on_drop = on_drop
        self._jump_ns = None if jump_back_s is None else int(jump_back_s * 1e9)
        self._on_reset = on_reset
        self.stats = _Stats()
        self.queue_size = 1
        self.slop_ns = 0
        self.configure(queue_size, slop)

    def configure(self, queue_size: int, slop: float, max_bytes: int | None = None) -> None:
        """Change queue size, slop and byte bound (queues are trimmed at the next message)."""
        if int(queue_size) < 1:
            raise SyncError(f"queue size must be >= 1, got {queue_size}")
        if not slop >= 0:  # also refuses NaN
            raise SyncError(f"slop must be >= 0 s, got {slop}")
        if max_bytes is not None and max_bytes < 1:
            raise SyncError(f"byte bound must be >= 1, got {max_bytes}")
        self.queue_size = int(queue_size)
        self.slop_ns = int(round(slop * 1e9))
        if max_bytes is not None:
            self.max_bytes = int(max_bytes)

    @property
    def n_topics(self) -> int:
        return len(self._queues)

    def queued(self) -> list[int]:
        """Number of messages waiting per topic."""
        return [len(q) for q in self._queues]

    def _pop(self, topic: int, stamp: int) -> Any:
        self.queued_bytes -= self._sizes[topic].pop(stamp)
        return self._queues[topic].pop(stamp)

    def _drop(self, topic: int, stamp: int, msg: Any, reason: str) -> None:
        self.stats.dropped += 1
        if self._on_drop is not None:
            self._on_drop(topic, stamp, msg, reason)

    def add(self, topic: int, stamp_ns: int, msg: Any, nbytes: int = 0) -> bool:
        """Queue one message of input ``topic`` (``nbytes``: its size, for the byte bound); emit a
        set if it completes one.

        Returns:
            True when a set was emitted.
        """
        if not 0 <= topic < self.n_topics:
            raise SyncError(f"topic index {topic} out of range 0..{self.n_topics - 1}")
        stamp_ns = int(stamp_ns)
        last = self._last_emitted[topic]
        if last is not None and self._jump_ns is not None and stamp_ns < last - self._jump_ns:
            self.reset()
            if self._on_reset is not None:
                self._on_reset(topic, last - stamp_ns)
            last = None
        if last is not None and stamp_ns <= last:
            reason = DropReason.DUPLICATE if stamp_ns == last else DropReason.OUT_OF_ORDER
            self._drop(topic, stamp_ns, msg, reason)
            return False
        queue = self._queues[topic]
        if stamp_ns in queue:  # message_filters: the newer message replaces the queued one
            self._drop(topic, stamp_ns, self._pop(topic, stamp_ns), DropReason.DUPLICATE)
        queue[stamp_ns] = msg
        self._sizes[topic][stamp_ns] = int(nbytes)
        self.queued_bytes += int(nbytes)
        while len(queue) > self.queue_size:
            oldest = min(queue)
            self._drop(topic, oldest, self._pop(topic, oldest), DropReason.OVERFLOW)
        while self.max_bytes is not None and self.queued_bytes > self.max_bytes:
            # the oldest message of all (on a tie, of the lowest topic); the new one last
            index, oldest = min(((i, min(q)) for i, q in enumerate(self._queues) if q), key=lambda t: (t[1], t[0]))
            self._drop(index, oldest, self._pop(index, oldest), DropReason.OVERFLOW_BYTES)
        if stamp_ns not in queue:  # the new message itself was the oldest
            return False
        return self._try_emit(topic, stamp_ns)

    def _try_emit(self, pivot_topic: int, pivot_stamp: int) -> bool:
        # Candidates per other topic: stamps within slop of the pivot (a wider one cannot be in
        # a set whose spread is <= slop).
        candidates: list[Sequence[int]] = []
        for index, queue in enumerate(self._queues):
            if index == pivot_topic:
                candidates.append((pivot_stamp,))
                continue
            near = [s for s in queue if abs(s - pivot_stamp) <= self.slop_ns]
            if not near:
                return False
            candidates.append(near)
        best: tuple[int, int, tuple[int, ...]] | None = None  # (spread, -newest, stamps)
        for stamps in itertools.product(*candidates):
            spread = max(stamps) - min(stamps)
            if spread > self.slop_ns:
                continue
            key = (spread, -max(stamps), stamps)
            if best is None or key < best:
                best = key
        if best is None:
            return False
        chosen = best[2]
        msgs = [self._pop(i, s) for i, s in enumerate(chosen)]
        for index, stamp in enumerate(chosen):
            self._last_emitted[index] = stamp
            queue = self._queues[index]
            for old in sorted(s for s in queue if s < stamp):
                self._drop(index, old, self._pop(index, old), DropReason.SUPERSEDED)
        self.stats.emitted += 1
        self._callback(*msgs)
        return True

    def reset(self) -> None:
        """Forget every queued message (reported as :attr:`DropReason.RESET`) and the emitted
        history (e.g. after a clock jump back)."""
        for index, queue in enumerate(self._queues):
            for stamp in sorted(queue):
                self._drop(index, stamp, self._pop(index, stamp), DropReason.RESET)
        self._last_emitted = [None] * self.n_topics
