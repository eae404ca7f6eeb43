"""ApproximateTimeSync against message_filters' ApproximateTimeSynchronizer semantics."""

from __future__ import annotations

from typing import Any

import pytest

from roadbev_ros.sync import ApproximateTimeSync, DropReason, SyncError

MS = 1_000_000


class Recorder:
    def __init__(self) -> None:
        self.sets: list[tuple[Any, ...]] = []
        self.drops: list[tuple[int, int, str]] = []

    def emit(self, *msgs: object) -> None:
        self.sets.append(msgs)

    def drop(self, topic: int, stamp: int, msg: object, reason: str) -> None:
        self.drops.append((topic, stamp, reason))


def make(n: int = 2, queue: int = 10, slop: float = 0.01) -> tuple[ApproximateTimeSync, Recorder]:
    rec = Recorder()
    return ApproximateTimeSync(n, queue, slop, rec.emit, rec.drop), rec


def test_exact_stamps_emit_once_all_topics_arrived() -> None:
    sync, rec = make(3)
    assert not sync.add(0, 100 * MS, "a")
    assert not sync.add(1, 100 * MS, "b")
    assert sync.add(2, 100 * MS, "c")
    assert rec.sets == [("a", "b", "c")]
    assert sync.queued() == [0, 0, 0]


def test_slop_is_inclusive_and_wider_spreads_never_pair() -> None:
    sync, rec = make(slop=0.010)
    sync.add(0, 100 * MS, "a0")
    assert sync.add(1, 110 * MS, "b0")  # spread == slop: pairs
    sync.add(0, 200 * MS, "a1")
    assert not sync.add(1, 211 * MS, "b1")  # 11 ms > 10 ms slop
    assert rec.sets == [("a0", "b0")]


def test_closest_set_wins() -> None:
    sync, rec = make(slop=0.05)
    sync.add(1, 95 * MS, "b_far")  # alone: nothing to pair with yet
    sync.add(1, 101 * MS, "b_near")
    sync.add(0, 100 * MS, "a")  # pivot: both b within slop; the closer one wins
    assert rec.sets == [("a", "b_near")]
    # b_far is older than the emitted set: it can never be emitted in order, so it is dropped
    assert (1, 95 * MS, DropReason.SUPERSEDED) in rec.drops


def test_tie_prefers_the_newest_set() -> None:
    sync, rec = make(slop=0.05)
    sync.add(1, 90 * MS, "b_old")
    sync.add(1, 110 * MS, "b_new")
    sync.add(0, 100 * MS, "a")
    assert rec.sets == [("a", "b_new")]


def test_queue_size_drops_oldest() -> None:
    sync, rec = make(queue=3, slop=0.001)
    for k in range(5):
        sync.add(0, (k + 1) * 100 * MS, f"a{k}")
    assert sync.queued() == [3, 0]
    assert [d[1] for d in rec.drops] == [100 * MS, 200 * MS]
    assert all(d[2] == DropReason.OVERFLOW for d in rec.drops)
    assert not sync.add(1, 100 * MS, "b0")  # its partner overflowed
    assert sync.add(1, 300 * MS, "b2")
    assert rec.sets == [("a2", "b2")]


def test_left_without_right_is_dropped_when_the_next_set_completes() -> None:
    sync, rec = make()
    sync.add(0, 100 * MS, "a0")  # its right image never comes
    sync.add(0, 200 * MS, "a1")
    sync.add(1, 200 * MS, "b1")
    assert rec.sets == [("a1", "b1")]
    assert rec.drops == [(0, 100 * MS, DropReason.SUPERSEDED)]
    assert sync.stats.emitted == 1 and sync.stats.dropped == 1


def test_out_of_order_and_duplicate_stamps_are_refused() -> None:
    sync, rec = make()
    sync.add(0, 200 * MS, "a")
    sync.add(1, 200 * MS, "b")
    assert not sync.add(0, 150 * MS, "late")
    assert not sync.add(1, 200 * MS, "again")
    assert rec.drops == [(0, 150 * MS, DropReason.OUT_OF_ORDER), (1, 200 * MS, DropReason.DUPLICATE)]
    # a duplicate while still queued replaces the queued message (message_filters keys by stamp)
    sync.add(0, 300 * MS, "x")
    sync.add(0, 300 * MS, "y")
    sync.add(1, 300 * MS, "b3")
    assert rec.sets[-1] == ("y", "b3")


def test_reset_forgets_history() -> None:
    sync, _ = make()
    sync.add(0, 200 * MS, "a")
    sync.add(1, 200 * MS, "b")
    sync.add(0, 300 * MS, "q")
    sync.reset()
    assert sync.queued() == [0, 0]
    sync.add(0, 100 * MS, "a0")  # earlier than before the reset: accepted again
    assert sync.add(1, 100 * MS, "b0")


def test_bad_configuration_is_refused() -> None:
    with pytest.raises(SyncError):
        make(queue=0)
    with pytest.raises(SyncError):
        make(slop=-1.0)
    with pytest.raises(SyncError):
        make(slop=float("nan"))
    sync, _ = make()
    with pytest.raises(SyncError):
        sync.add(2, 1, "x")


def test_many_interleaved_topics_pair_every_frame() -> None:
    """Four streams with jitter and a shuffled arrival order pair frame by frame."""
    import random

    rnd = random.Random(3)
    sync, rec = make(4, queue=5, slop=0.004)
    events = []
    for k in range(50):
        for topic in range(4):
            jitter = rnd.randint(-2, 2) * MS
            arrival = k + rnd.random()  # arrival order shuffled within each frame
            events.append((arrival, topic, k * 200 * MS + jitter, (k, topic)))
    events.sort()
    for _, topic, stamp, msg in events:
        sync.add(topic, stamp, msg)
    assert len(rec.sets) == 50
    assert all(len({m[0] for m in s}) == 1 for s in rec.sets)
    assert rec.drops == []


def test_a_sustained_jump_back_resets_and_keeps_the_new_timelines_first_messages() -> None:
    rec = Recorder()
    resets: list[tuple[int, int]] = []
    sync = ApproximateTimeSync(2, 10, 0.01, rec.emit, rec.drop, jump_back_s=1.0,
                               on_reset=lambda topic, jump: resets.append((topic, jump)))
    sync.add(0, 5_000 * MS, "a")
    sync.add(1, 5_000 * MS, "b")
    sync.add(0, 5_100 * MS, "queued")  # waiting for its partner when the clock jumps back
    assert not sync.add(1, 4_500 * MS, "late")  # half a second back: only out of order
    assert sync.add(1, 100 * MS, "b0") is False  # five seconds back: held, one message never resets
    assert sync.add(0, 100 * MS, "a0") is False  # held as well
    assert resets == [] and rec.sets == [("a", "b")]
    assert sync.add(1, 200 * MS, "b1") is False  # the new timeline goes on: the clock did jump back
    assert resets == [(1, 4_800 * MS)]
    assert (0, 5_100 * MS, DropReason.RESET) in rec.drops
    assert rec.sets[-1] == ("a0", "b0")  # the held messages were not lost
    assert sync.add(0, 200 * MS, "a1")
    assert rec.sets[-1] == ("a1", "b1")
    never = ApproximateTimeSync(2, 10, 0.01, rec.emit, rec.drop, jump_back_s=None)
    never.add(0, 5_000 * MS, "a")
    never.add(1, 5_000 * MS, "b")
    never.add(0, 100 * MS, "x")
    assert rec.drops[-1] == (0, 100 * MS, DropReason.OUT_OF_ORDER)


def test_one_set_stamped_far_ahead_is_an_outlier_not_a_restart() -> None:
    rec = Recorder()
    resets: list[tuple[int, int]] = []
    outliers: list[tuple[int, int]] = []
    sync = ApproximateTimeSync(2, 10, 0.01, rec.emit, rec.drop, jump_back_s=1.0,
                               on_reset=lambda t, j: resets.append((t, j)),
                               on_outlier=lambda t, a: outliers.append((t, a)))
    for k, stamp in enumerate((1_000, 1_100, 1_001_200, 1_300, 1_400)):  # the third stamped 1000 s ahead
        sync.add(0, stamp * MS, f"a{k}")
        sync.add(1, stamp * MS, f"b{k}")
    assert resets == []
    assert outliers == [(0, 999_900 * MS), (1, 999_900 * MS)]
    assert rec.sets == [("a0", "b0"), ("a1", "b1"), ("a2", "b2"), ("a3", "b3"), ("a4", "b4")]


def test_a_stamp_glitch_behind_is_dropped_and_never_resets() -> None:
    rec = Recorder()
    resets: list[tuple[int, int]] = []
    sync = ApproximateTimeSync(2, 10, 0.01, rec.emit, rec.drop, jump_back_s=1.0,
                               on_reset=lambda t, j: resets.append((t, j)))
    for k in range(6):  # every other set stamped 10 s back
        stamp = (10_000 + 100 * k - (10_000 if k % 2 else 0)) * MS
        sync.add(0, stamp, f"a{k}")
        sync.add(1, stamp, f"b{k}")
    assert resets == []
    assert rec.sets == [("a0", "b0"), ("a2", "b2"), ("a4", "b4")]
    glitches = [d for d in rec.drops if d[2] == DropReason.GLITCH]
    assert [(t, s // MS) for t, s, _ in glitches] == [(0, 100), (1, 100), (0, 300), (1, 300)]


def test_the_queues_are_bounded_by_bytes_too() -> None:
    rec = Recorder()
    sync = ApproximateTimeSync(2, 100, 0.01, rec.emit, rec.drop, max_bytes=100)
    for k in range(5):  # unpaired left images of 46 bytes: at most two fit the 100-byte bound
        sync.add(0, (k + 1) * 1000 * MS, f"left{k}", nbytes=46)
    assert sync.queued() == [2, 0] and sync.queued_bytes == 92
    assert [(t, s // MS, r) for t, s, r in rec.drops] == [(0, k * 1000 + 1000, DropReason.OVERFLOW_BYTES)
                                                        for k in range(3)]
    assert sync.add(1, 5000 * MS, "right4", nbytes=8)  # pairs with the newest left image
    assert rec.sets[-1] == ("left4", "right4")
    assert sync.queued_bytes == 0 and sync.queued() == [0, 0]  # left3 was superseded
    sync.configure(100, 0.01, max_bytes=10)
    sync.add(0, 6000 * MS, "a", nbytes=6)
    sync.add(1, 6500 * MS, "b", nbytes=6)  # over the new bound: the oldest of all goes
    assert rec.drops[-1] == (0, 6000 * MS, DropReason.OVERFLOW_BYTES) and sync.queued_bytes == 6
    with pytest.raises(SyncError):
        sync.configure(10, 0.01, max_bytes=0)
