"""Mailbox: the newest item wins, a replaced item is reported, close wakes the consumer."""

from __future__ import annotations

import threading

from roadbev_ros.mailbox import Mailbox


def test_the_newest_item_wins_and_a_replacement_is_reported() -> None:
    box: Mailbox[int] = Mailbox()
    assert not box.waiting
    assert box.put(1) is False
    assert box.put(2) is True  # 1 was still waiting: the node counts it as dropped
    assert box.waiting
    taken = box.take()
    assert taken is not None and taken[0] == 2 and taken[1] > 0
    assert not box.waiting


def test_close_wakes_a_waiting_consumer() -> None:
    box: Mailbox[int] = Mailbox()
    results: list[object] = []
    consumer = threading.Thread(target=lambda: results.append(box.take()))
    consumer.start()
    box.close()
    consumer.join(5.0)
    assert not consumer.is_alive() and results == [None] and box.closed


def test_an_item_put_from_another_thread_reaches_the_consumer() -> None:
    box: Mailbox[str] = Mailbox()
    threading.Timer(0.05, lambda: box.put("set")).start()
    taken = box.take()
    assert taken is not None and taken[0] == "set"
