"""A one-slot mailbox between the executor thread and the inference worker: the newest item wins.

The node's callbacks must never block on inference, and a controller wants the newest frame,
not a queue of old ones: :meth:`Mailbox.put` replaces a waiting item (and says so, so the node can
count the replaced set as dropped), :meth:`Mailbox.take` waits for the next one.
"""

from __future__ import annotations

import threading
import time
from typing import Generic, TypeVar

__all__ = ["Mailbox"]

T = TypeVar("T")


class Mailbox(Generic[T]):
    """One slot, newest wins; thread-safe for one producer and one consumer."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._item: tuple[T, float] | None = None  # (item, monotonic arrival time)
        self._closed = False

    def put(self, item: T) -> bool:
        """Leave ``item`` for the consumer; True when it replaced one that was still waiting."""
        with self._cond:
            replaced = self._item is not None
            self._item = (item, time.monotonic())
            self._cond.notify()
        return replaced

    def take(self) -> tuple[T, float] | None:
        """The waiting item and its arrival time (waits for one); None once closed."""
        with self._cond:
            while self._item is None and not self._closed:
                self._cond.wait(0.5)
            if self._closed:
                return None
            item, self._item = self._item, None
        return item

    def clear(self) -> bool:
        """Discard the waiting item; True when there was one."""
        with self._cond:
            had, self._item = self._item is not None, None
        return had

    @property
    def waiting(self) -> bool:
        """Whether an item waits."""
        return self._item is not None

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        """Wake the consumer for good (:meth:`take` returns None)."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
