"""Reading bags: :func:`read_messages` (CRC-checked, in log-time order) and :func:`bag_topics`.

Reading goes through :mod:`msg_bridge.bag.mcap_file`, which checks every chunk before using it
(size, CRC, record structure, and the message index where a writer stored no CRC).
``on_damage="raise"`` (the default) raises :class:`~msg_bridge.bag.errors.DamagedBagError` naming
the file and the chunk; ``on_damage="skip"`` skips the damaged chunk, and the
:class:`~msg_bridge.bag.damage.ReadStats` passed in counts what was lost, per topic and why. A
truncated or unfinished bag is read up to its last complete chunk with ``"skip"``; with
``"raise"`` it is refused at once, saying what is readable. So is a split bag with a file missing
(``"skip"`` reads the other files). Damage that costs no message (a summary whose CRC fails, read
around from the chunks; a damaged message index; a data section CRC mismatch no chunk explains)
is reported in the ``ReadStats`` in both modes. Types a bag brings along that the
typestore does not know are registered from the bag's schemas.
"""

from __future__ import annotations

import os
from collections import Counter
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, Literal, NamedTuple

from msg_bridge.bag.damage import (
    ReadStats,
    count_damage,
    count_undefined_channel,
    describe_damage,
    lost_file_lines,
    note_damage,
    salvage,
)
from msg_bridge.bag.errors import BagError, DamagedBagError
from msg_bridge.bag.files import Bag, open_bag
from msg_bridge.bag.mcap_file import Damage, FileScan, iter_messages, loose_message_channel
from msg_bridge.bag.typestore import typestore

__all__ = ["BagMessage", "OnDamage", "TopicInfo", "bag_topics", "read_messages"]

OnDamage = Literal["raise", "skip"]


class TopicInfo(NamedTuple):
    """A topic of a bag: its type and message count."""

    msgtype: str
    count: int  # type: ignore[assignment]  # shadows tuple.count; the field name is public API


class BagMessage(NamedTuple):
    """One message of a bag: topic, type, log time and the (decoded or raw) message."""

    topic: str
    msgtype: str
    log_time_ns: int
    msg: Any


def bag_topics(path: str | os.PathLike[str]) -> dict[str, TopicInfo]:
    """Topics of a bag with their types and message counts (from the index; no decoding).

    An unfinished or damaged bag gives the topics and counts of its complete chunks.
    """
    bag = open_bag(Path(path), check_data_crc=False)
    bag.ensure_channels()
    counts: Counter[str] = Counter()
    types: dict[str, str] = {}
    for scan in bag.scans:
        for (file, cid), channel in bag.channels.items():
            if file == scan.path:
                types.setdefault(channel.topic, bag.msgtype(scan, cid))
                counts[channel.topic] += 0
        per_channel: Counter[int] = Counter()
        if scan.closed and scan.statistics is not None:
            per_channel.update(scan.statistics)
        else:
            for chunk in scan.chunks:
                if not chunk.cut:
                    per_channel.update(chunk.indexed_counts)
            per_channel.update(loose_message_channel(scan, o) for _t, o, _n in scan.loose)
        for cid, n in per_channel.items():
            topic = bag.topic(scan, cid)
            if topic is not None:
                counts[topic] += n
    return {t: TopicInfo(types[t], counts[t]) for t in sorted(types)}


def _ensure_types(bag: Bag, msgtypes: Iterable[tuple[FileScan, int]]) -> None:
    """Register message types a bag brings along that the typestore does not know yet."""
    # Imported on use: rosbags is slow to import and ``import msg_bridge`` needs no typestore.
    from rosbags.typesys import get_types_from_idl, get_types_from_msg

    store = typestore()
    new: dict[str, Any] = {}
    for scan, cid in msgtypes:
        channel = bag.channels[(scan.path, cid)]
        schema = bag.schemas.get((scan.path, channel.schema_id))
        if schema is None or schema.name in store.types or schema.name in new or not schema.data:
            continue
        try:
            text = schema.data.decode("utf-8")
            if schema.encoding == "ros2idl":
                new.update(get_types_from_idl(text))
            else:
                new.update(get_types_from_msg(text, schema.name))
        except Exception as exc:
            raise BagError(f"type {schema.name} of {channel.topic} has an unreadable definition: {exc}") from None
    if new:
        store.register(new)


def read_messages(
    path: str | os.PathLike[str],
    topics: Iterable[str] | None = None,
    *,
    raw: bool = False,
    on_damage: OnDamage = "raise",
    stats: ReadStats | None = None,
) -> Iterator[BagMessage]:
    """The messages of a bag in log-time order, decoded (typestore objects) or raw CDR bytes.

    Args:
        path: a rosbag2 directory or an ``.mcap`` file.
        topics: only these topics (all when None).
        raw: yield the serialised bytes instead of decoding them.
        on_damage: "raise": a damaged chunk raises :class:`DamagedBagError` where it is met, and
            an unfinished or cut bag is refused at once; "skip": damaged chunks and undecodable
            messages are skipped and counted in ``stats``, an unfinished bag is read to its last
            complete chunk.
        stats: filled with what was read and lost (a fresh one is used when None).

    Raises:
        BagError: the bag cannot be opened (no MCAP file, no readable record).
        DamagedBagError: with ``on_damage="raise"``, the first damage met.
    """
    if on_damage not in ("raise", "skip"):
        raise ValueError(f"on_damage must be 'raise' or 'skip', got {on_damage!r}")
    path = Path(path)
    stats = stats if stats is not None else ReadStats()
    wanted = None if topics is None else set(topics)
    bag = open_bag(path)
    stats.unfinished = stats.unfinished or not bag.closed
    scan_damage = [d for s in bag.scans for d in s.damage]
    if on_damage == "raise" and (bag.lost_files or any(not d.kept for d in scan_damage)):
        lines = lost_file_lines(bag) + [describe_damage(bag, d)[0] for d in scan_damage if not d.kept]
        raise DamagedBagError(f"{path}: truncated or corrupt bag ({lines[0]}); {salvage(bag)}; "
                              "`roadbev bag recover` copies what is readable", lines)
    if on_damage == "raise" and not bag.closed:
        why = "a .recording marker is left" if bag.marker else "it has no summary/footer"
        line = f"{path}: the bag was not closed cleanly ({why}): its end may be missing"
        raise DamagedBagError(f"{line}; {salvage(bag)}; `roadbev bag recover` makes a complete copy", [line])
    for line in lost_file_lines(bag):
        note_damage(stats, line)
    for damage in scan_damage:
        count_damage(bag, damage, stats, wanted)
    stats.unverified_chunks += sum(1 for s in bag.scans for c in s.chunks if c.crc == 0 and not c.cut)
    store = typestore()
    registered: set[tuple[Path, int]] = set()

    def on_chunk_damage(damage: Damage) -> None:
        line = count_damage(bag, damage, stats, wanted)
        if on_damage == "raise" and not damage.kept:
            done = ", ".join(f"{t}: {n}" for t, n in sorted(stats.read.items())) or "none"
            raise DamagedBagError(f"{path}: {line}; {sum(stats.read.values())} message(s) read before it ({done})",
                                  [line])

    messages = iter_messages(bag.scans, on_damage=on_chunk_damage, on_channels=bag.add)
    for scan, message in messages:
        key = (scan.path, message.channel_id)
        channel = bag.channels.get(key)
        if channel is None:
            if wanted is None:
                count_undefined_channel(stats, scan.path, message.channel_id)
            continue
        if wanted is not None and channel.topic not in wanted:
            continue
        msgtype = bag.msgtype(scan, message.channel_id)
        if raw:
            msg: Any = message.data
        else:
            if key not in registered:
                _ensure_types(bag, [(scan, message.channel_id)])
                registered.add(key)
            try:
                msg = store.deserialize_cdr(message.data, msgtype)
            except Exception as exc:  # rosbags raises struct/index/value errors on bad bytes
                line = (f"{scan.path.name}: message {stats.read[channel.topic] + 1} on {channel.topic} is not a valid "
                        f"{msgtype}: {exc!r}")
                if on_damage == "raise":
                    raise DamagedBagError(f"{path}: {line}", [line]) from None
                stats.undecodable[channel.topic] += 1
                note_damage(stats, line)
                continue
        stats.read[channel.topic] += 1
        yield BagMessage(channel.topic, msgtype, int(message.log_time_ns), msg)
