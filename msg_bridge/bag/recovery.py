"""Recovery: :func:`recover_bag` writes a complete, indexed copy of everything readable in a bag
(a damaged one, or one whose writer was killed).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from msg_bridge.bag.damage import ReadStats, count_damage, count_undefined_channel, lost_file_lines, note_damage
from msg_bridge.bag.errors import BagError
from msg_bridge.bag.files import open_bag
from msg_bridge.bag.mcap_file import Damage, iter_messages
from msg_bridge.bag.typestore import typestore
from msg_bridge.bag.writer import BagWriter

__all__ = ["recover_bag"]


def recover_bag(
    path: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    compression: str = "zstd",
    progress: Any = None,
) -> ReadStats:
    """Write a complete, indexed copy of everything readable in ``path`` to ``out``.

    Every message of every sound chunk is copied byte for byte with its log and publish time and
    sequence, on channels with the original topics, schemas and metadata (QoS); damaged chunks
    are left out and counted, and so are the files of a split bag that are missing or unreadable.
    ``out`` (``.mcap`` or a directory) must not exist.

    Args:
        progress: called with 1 per message copied (e.g. ``tqdm.update``).

    Returns:
        What was copied and what was lost.

    Raises:
        BagError: ``path`` holds nothing readable, or ``out`` exists.
    """
    path, out = Path(path), Path(out)
    if out.resolve() == path.resolve():
        raise BagError(f"{out}: the copy must not replace the bag it is made from")
    bag = open_bag(path)
    stats = ReadStats()
    for line in lost_file_lines(bag):
        note_damage(stats, line)
    for damage in (d for s in bag.scans for d in s.damage):
        count_damage(bag, damage, stats, None)
    stats.unverified_chunks = sum(1 for s in bag.scans for c in s.chunks if c.crc == 0 and not c.cut)
    ids: dict[tuple[Path, int], int] = {}

    def on_chunk_damage(damage: Damage) -> None:
        count_damage(bag, damage, stats, None)

    with BagWriter(out, compression=compression) as writer:
        for scan, message in iter_messages(bag.scans, on_damage=on_chunk_damage, on_channels=bag.add):
            key = (scan.path, message.channel_id)
            channel = bag.channels.get(key)
            if channel is None:
                count_undefined_channel(stats, scan.path, message.channel_id)
                continue
            if key not in ids:
                schema = bag.schemas.get((scan.path, channel.schema_id))
                ids[key] = writer.add_channel(
                    channel.topic, schema.name if schema else "", schema.encoding if schema else "",
                    schema.data if schema else b"", channel.metadata, message_encoding=channel.message_encoding,
                    digest=_digest(schema.name) if schema else "",
                )
            writer.write_channel(ids[key], message.data, message.log_time_ns, message.publish_time_ns,
                                 message.sequence)
            writer.counts[channel.topic] += 1
            stats.read[channel.topic] += 1
            if progress is not None:
                progress(1)
        if not stats.read:  # leaving the block with an error removes the empty copy
            raise BagError(f"{path}: nothing readable to recover ({stats.summary()})")
    stats.unfinished = not bag.closed
    return stats


def _digest(msgtype: str) -> str:
    """The RIHS01 type hash of ``msgtype``; "" for a type the typestore does not know or cannot hash."""
    store = typestore()
    try:
        return str(store.hash_rihs01(msgtype)) if msgtype in store.types else ""
    except Exception:  # a type the store holds but cannot hash (a foreign definition)
        return ""
