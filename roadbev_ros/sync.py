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
  one older by more than ``jump_back_s`` is judged by the rules of the input clock:

  - it continues the timeline from before the last emitted set (newer than the set emitted
    before that one, which lies more than ``jump_back_s`` behind the last): the last set was a
    single stamp outlier ahead of time; the topic goes on from the set before it (reported
    through ``on_outlier``), nothing is reset;
  - otherwise it is held, not yet believed: when the next message of its topic continues the new,
    earlier timeline (newer than the held one, still far behind the last set), the clock did jump
    back (a bag started again, a ``/clock`` reset): the synchroniser resets itself (reported
    through ``on_reset``) and goes on from the held messages of every topic, so that no frame of
    the new timeline is lost; when the next message continues the old timeline instead, the held
    one was a glitch and is dropped (:attr:`DropReason.GLITCH`). One message never resets;
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
    GLITCH = "a stamp far behind the others, not followed by more (a glitch)"


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
        on_reset: called ``(topic_index, jump_ns)`` when a jump back reset the synchroniser
            (:attr:`restart_span` then holds the new timeline's stamps seen so far).
        on_outlier: called ``(topic_index, ahead_ns)`` when the last emitted set of a topic turned
            out to be a stamp outlier ahead of its timeline (module docstring).
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
        on_outlier: Callable[[int, int], None] | None = None,
    ) -> None:
        if n_topics < 1:
            raise SyncError(f"need at least one topic, got {n_topics}")
        self._queues: list[dict[int, Any]] = [{} for _ in range(n_topics)]
        self._sizes: list[dict[int, int]] = [{} for _ in range(n_topics)]
        self.queued_bytes = 0
        self.max_bytes = max_bytes
        self._last_emitted: list[int | None] = [None] * n_topics
        self._emitted_before: list[int | None] = [None] * n_topics  # the set emitted before the last
        self._held: dict[int, tuple[int, Any, int]] = {}  # topic -> a jumped-back message not yet believed
        # the stamps of the new timeline seen when the last jump back was believed (oldest held
        # message, the message that confirmed it): what the caller's other inputs must keep
        self.restart_span: tuple[int, int] | None = None
        self._on_outlier = on_outlier
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
            before = self._emitted_before[topic]
            if before is not None and before < stamp_ns and last - before > self._jump_ns:
                # the last set was one outlier ahead of the timeline this message continues
                self._last_emitted[topic], self._emitted_before[topic] = before, None
                if self._on_outlier is not None:
                    self._on_outlier(topic, last - stamp_ns)
                last = before
            else:
                return self._jumped_back(topic, stamp_ns, msg, nbytes, last)
        elif topic in self._held:  # the old timeline goes on: the held message was a glitch
            held_stamp, held_msg, _ = self._held.pop(topic)
            self._drop(topic, held_stamp, held_msg, DropReason.GLITCH)
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

    def _jumped_back(self, topic: int, stamp_ns: int, msg: Any, nbytes: int, last: int) -> bool:
        """A message far behind its topic's last set: held until the next one says whether the
        clock jumped back (then reset and replay the held messages) or it was a glitch."""
        held = self._held.get(topic)
        if held is None or not held[0] < stamp_ns:
            if held is not None:
                self._drop(topic, held[0], held[1], DropReason.GLITCH)
            self._held[topic] = (stamp_ns, msg, int(nbytes))
            return False
        waiting = sorted((h[0], index, h[1], h[2]) for index, h in self._held.items())
        self._held.clear()
        self.restart_span = (waiting[0][0], stamp_ns)
        self.reset()
        if self._on_reset is not None:
            self._on_reset(topic, last - stamp_ns)
        for held_stamp, index, held_msg, held_bytes in waiting:
            self.add(index, held_stamp, held_msg, held_bytes)
        return self.add(topic, stamp_ns, msg, nbytes)

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
            self._emitted_before[index] = self._last_emitted[index]
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
        for index, (stamp, msg, _) in sorted(self._held.items()):
            self._drop(index, stamp, msg, DropReason.RESET)
        self._held.clear()
        self._last_emitted = [None] * self.n_topics
        self._emitted_before = [None] * self.n_topics
