"""Test helpers: copies of a bag that are truncated, lack topics, or carry a broken message."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from msg_bridge import bag


def rewrite(
    src: Path,
    dst: Path,
    *,
    chunk_size: int = 32 * 1024,
    drop: Iterable[str] = (),
    change: Callable[[str, int, Any], Any] | None = None,
) -> dict[str, int]:
    """Copy ``src`` to ``dst`` with small chunks, without the ``drop`` topics; ``change(topic,
    index on the topic, decoded message)`` may return a modified message. Returns counts."""
    dropped = set(drop)
    topics = {t: i for t, i in bag.bag_topics(src).items() if t not in dropped}
    seen: Counter[str] = Counter()
    with bag.BagWriter(dst, chunk_size=chunk_size) as writer:
        for topic, info in topics.items():
            writer.add_topic(topic, info.msgtype, latched=info.count == 1)
        for item in bag.read_messages(src, list(topics)):
            msg = item.msg if change is None else change(item.topic, seen[item.topic], item.msg)
            writer.write(item.topic, msg, item.log_time_ns)
            seen[item.topic] += 1
    return dict(seen)


def truncate(src: Path, dst: Path, fraction: float) -> Path:
    """The first ``fraction`` of ``src``'s bytes, as a crash or a full disk leaves a file."""
    data = src.read_bytes()
    dst.write_bytes(data[: int(len(data) * fraction)])
    return dst
