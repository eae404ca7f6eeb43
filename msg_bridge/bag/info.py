"""What a bag holds: :func:`bag_info` (per topic, whether it was closed cleanly, what is damaged),
the report of ``roadbev bag info``.
"""

from __future__ import annotations

import os
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from msg_bridge.bag.damage import ReadStats, count_damage, lost_file_lines, note_damage
from msg_bridge.bag.files import open_bag
from msg_bridge.bag.reader import TopicInfo, bag_topics, read_messages

__all__ = ["BagInfo", "bag_info"]


@dataclass
class BagInfo:
    """What a bag holds (see :func:`bag_info`).

    Attributes:
        path: the bag.
        files: its MCAP files.
        closed: every file has its summary and footer and no ``.recording`` marker is left.
        marker: a ``.recording`` marker lies next to the bag (its writer did not close it).
        topics: topic -> (type, messages readable); with ``verify`` every chunk was checked.
        lost: topic -> messages known to be lost.
        damage: one line per damaged part.
        lost_unknown: the bag breaks off (how much followed is unknown).
        chunks: chunks in the files; ``chunks_without_crc``: of them, written without a CRC
            (rosbags' writer): only their structure and index could be checked.
        start_ns, end_ns: log times of the first and last readable message (0 when none).
        library: the writer that made the (first) file.
        verified: every chunk was decompressed and checked.
    """

    path: Path
    files: list[Path]
    closed: bool
    marker: bool
    topics: dict[str, TopicInfo]
    lost: dict[str, int]
    damage: list[str]
    lost_unknown: bool
    chunks: int
    chunks_without_crc: int
    start_ns: int
    end_ns: int
    library: str
    verified: bool

    def lines(self) -> list[str]:
        """The report of ``roadbev bag info``."""
        if self.closed:
            state = "closed cleanly"
        elif self.marker:
            state = "NOT closed cleanly: its writer is still running or was killed (a .recording marker is left)"
        else:
            state = "NOT closed cleanly: no summary/footer (the writer did not finish)"
        total = sum(i.count for i in self.topics.values())
        span = (self.end_ns - self.start_ns) * 1e-9
        out = [
            f"bag:      {self.path}",
            f"files:    {', '.join(f.name for f in self.files)} ({sum(f.stat().st_size for f in self.files)} bytes)",
            f"state:    {state}",
            f"writer:   {self.library or '?'}",
            f"chunks:   {self.chunks} ({self.chunks_without_crc} without CRC)"
            + ("" if self.verified else " (not verified)"),
            f"messages: {total} readable over {span:.3f} s",
        ]
        width = max((len(t) for t in self.topics), default=5)
        for topic, info in self.topics.items():
            lost = self.lost.get(topic, 0)
            out.append(f"  {topic:<{width}}  {info.count:>8}  {info.msgtype}" + (f"  ({lost} lost)" if lost else ""))
        if self.damage:
            out.append(f"damage:   {len(self.damage)} part(s); `roadbev bag recover` copies what is readable")
            out += [f"  {line}" for line in self.damage]
        if self.lost_unknown:
            out.append("  the bag breaks off: what followed the cut is unknown")
        return out

    def to_dict(self) -> dict[str, Any]:
        return {
            "path": str(self.path), "files": [str(f) for f in self.files], "closed": self.closed,
            "marker": self.marker,
            "topics": {t: {"type": i.msgtype, "count": i.count} for t, i in self.topics.items()},
            "lost": dict(self.lost), "damage": list(self.damage), "lost_unknown": self.lost_unknown,
            "chunks": self.chunks, "chunks_without_crc": self.chunks_without_crc,
            "start_ns": self.start_ns, "end_ns": self.end_ns, "library": self.library, "verified": self.verified,
        }


def bag_info(path: str | os.PathLike[str], *, verify: bool = True) -> BagInfo:
    """What a bag holds per topic, whether it was closed cleanly, and what is damaged.

    Args:
        path: a rosbag2 directory or an ``.mcap`` file.
        verify: decompress and check every chunk (CRC, structure); else counts come from the
            indexes and only damage the file structure shows is found.
    """
    path = Path(path)
    bag = open_bag(path, check_data_crc=False)  # a verified read checks it again, with the chunks
    stats = ReadStats()
    types: dict[str, str] = {t: i.msgtype for t, i in bag_topics(path).items()}
    start = end = 0
    if verify:
        counts: Counter[str] = Counter()
        first: int | None = None
        for message in read_messages(path, raw=True, on_damage="skip", stats=stats):
            counts[message.topic] += 1
            types.setdefault(message.topic, message.msgtype)
            first = message.log_time_ns if first is None else first
            end = message.log_time_ns
        start = first or 0
        topics = {t: TopicInfo(types[t], counts[t]) for t in sorted(types)}
    else:
        topics = bag_topics(path)
        for line in lost_file_lines(bag):
            note_damage(stats, line)
        for damage in (d for s in bag.scans for d in s.damage):
            count_damage(bag, damage, stats, None)
        times = [(c.start_ns, c.end_ns) for s in bag.scans for c in s.chunks if not c.cut]
        if times:
            start, end = min(t[0] for t in times), max(t[1] for t in times)
    chunks = [c for s in bag.scans for c in s.chunks]
    return BagInfo(
        path=path, files=[s.path for s in bag.scans], closed=bag.closed, marker=bag.marker, topics=topics,
        lost=dict(stats.lost + stats.undecodable), damage=list(stats.damage), lost_unknown=stats.lost_unknown,
        chunks=len(chunks), chunks_without_crc=sum(1 for c in chunks if c.crc == 0),
        start_ns=start, end_ns=end, library=bag.scans[0].library, verified=verify,
    )
