"""Damage accounting: what a damaged, cut or unfinished part of a bag costs, per topic, and the
:class:`ReadStats` of a read that records it.

A damaged part (a :class:`~msg_bridge.bag.mcap_file.Damage`) is described in one line naming the
file, the chunk, its byte offset, the reason and the messages lost per topic (by the chunk's
message index); :func:`count_damage` adds it to a :class:`ReadStats`, and :func:`salvage` says
what of a damaged bag can still be read. The files of a split bag that are missing or unreadable
are one line each (:func:`lost_file_lines`).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from msg_bridge.bag.files import Bag
from msg_bridge.bag.mcap_file import Damage, loose_message_channel

__all__ = [
    "ReadStats",
    "count_damage",
    "count_undefined_channel",
    "describe_damage",
    "lost_file_lines",
    "note_damage",
    "salvage",
]


@dataclass
class ReadStats:
    """What a read delivered and what it lost (filled by :func:`~msg_bridge.bag.read_messages`).

    Attributes:
        read: topic -> messages delivered.
        lost: topic -> messages known to be lost (in damaged chunks, by their index).
        undecodable: topic -> messages whose bytes are not a valid message of their type.
        damage: one line per damaged part: file, chunk, byte offset, reason, messages lost.
        lost_unknown: the bag breaks off or has unreadable stretches: more may be lost than
            ``lost`` says (what followed the cut is not known).
        unfinished: the bag was not closed by its writer (no footer, or a ``.recording`` marker).
        unverified_chunks: chunks written without a CRC (rosbags' writer): only their structure
            and message index can be checked, so damage inside their data may go unnoticed.
    """

    read: Counter[str] = field(default_factory=Counter)
    lost: Counter[str] = field(default_factory=Counter)
    undecodable: Counter[str] = field(default_factory=Counter)
    damage: list[str] = field(default_factory=list)
    lost_unknown: bool = False
    unfinished: bool = False
    unverified_chunks: int = 0

    @property
    def complete(self) -> bool:
        """Nothing was lost (the bag may still be unfinished: then its end is not known)."""
        return not (self.damage or self.lost or self.undecodable or self.lost_unknown)

    def summary(self) -> str:
        """One line: delivered, lost (per topic), and why."""
        read = sum(self.read.values())
        if self.complete and not self.unfinished and not self.unverified_chunks:
            return f"{read} message(s) read, nothing lost"
        parts = [f"{read} message(s) read"]
        lost = self.lost + self.undecodable
        if lost:
            detail = ", ".join(f"{t}: {n}" for t, n in sorted(lost.items()))
            parts.append(f"{sum(lost.values())} lost ({detail})")
        if self.lost_unknown:
            parts.append("the bag breaks off: what followed is unknown")
        elif self.unfinished:
            parts.append("the bag was not closed cleanly")
        if self.unverified_chunks:
            parts.append(f"{self.unverified_chunks} chunk(s) without CRC could not be verified")
        why = "; ".join(self.damage[:3]) + (f"; and {len(self.damage) - 3} more" if len(self.damage) > 3 else "")
        return ", ".join(parts) + (f" [{why}]" if why else "")


def describe_damage(bag: Bag, damage: Damage) -> tuple[str, Counter[str]]:
    """A line naming the damaged part and what it cost, and the loss per topic."""
    lost: Counter[str] = Counter()
    scan_path = damage.file
    for cid, n in damage.lost.items():
        channel = bag.channels.get((scan_path, cid))
        lost[channel.topic if channel is not None else f"channel {cid}"] += n
    if damage.kept:
        cost = "nothing lost"
    elif lost:
        detail = ", ".join(f"{t}: {n}" for t, n in sorted(lost.items()))
        cost = f"{sum(lost.values())} message(s) lost ({detail})"
        if damage.lost_unknown:
            cost += " and whatever followed"
    else:
        cost = "its messages are lost (no index says how many)"
        if damage.chunk is None:
            cost = "what it held is lost"
    return f"{damage.where()}: {damage.reason}; {cost}", lost


def note_damage(stats: ReadStats, line: str) -> None:
    """Add ``line`` to ``stats.damage`` unless it is there already."""
    if line not in stats.damage:
        stats.damage.append(line)


def count_damage(bag: Bag, damage: Damage, stats: ReadStats, wanted: set[str] | None) -> str:
    """Add a damaged part to ``stats`` (its losses on the ``wanted`` topics, all when None); its line."""
    line, lost = describe_damage(bag, damage)
    if not damage.kept:
        for topic, n in lost.items():
            if wanted is None or topic in wanted:
                stats.lost[topic] += n
        stats.lost_unknown = stats.lost_unknown or damage.lost_unknown
    note_damage(stats, line)
    return line


def lost_file_lines(bag: Bag) -> list[str]:
    """One line per file of a split bag that is missing or cannot be read."""
    return [f"{file.name}: {why}" for file, why in bag.lost_files.items()]


def count_undefined_channel(stats: ReadStats, file: Path, channel_id: int) -> None:
    """Count a message on a channel whose definition is lost (under ``channel <id>``)."""
    stats.lost[f"channel {channel_id}"] += 1
    note_damage(stats, f"{file.name}: messages on channel {channel_id}, whose definition is lost")


def salvage(bag: Bag) -> str:
    """What can still be read, by the index: '<n> message(s) readable before the damage (topic: n, ...)'."""
    bag.ensure_channels()
    counts: Counter[str] = Counter()
    for scan in bag.scans:
        for chunk in scan.chunks:
            if not chunk.cut:
                for cid, n in chunk.indexed_counts.items():
                    counts[bag.topic(scan, cid) or f"channel {cid}"] += n
        for cid, n in Counter(loose_message_channel(scan, o) for _t, o, _n in scan.loose).items():
            counts[bag.topic(scan, cid) or f"channel {cid}"] += n
    total = sum(counts.values())
    detail = ", ".join(f"{topic}: {n}" for topic, n in sorted(counts.items()))
    return f"{total} message(s) readable before the damage" + (f" ({detail})" if detail else "")
