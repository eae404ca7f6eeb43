"""MCAP files read record by record, every chunk checked before anything in it is used.

The MCAP readers stop at the first cut or damaged chunk, and neither checks chunk CRCs by
default; this module is the project's own reader underneath :mod:`msg_bridge.bag`:

* :func:`scan_file` walks the top-level records of one file (chunk *headers* only, no
  decompression): schemas and channels outside chunks, the chunks with the message indexes that
  follow them, the summary, the footer. A record cut by the end of the file (a crashed writer)
  or bytes that are no record (damage) are noted as :class:`Damage`; after garbage the scan
  resynchronises on the next record that parses as a consistent chunk, so one damaged header
  costs one chunk, not the rest of the file.
* :func:`load_chunk` decompresses one chunk and checks it: the decompressed size, the CRC-32 of
  the uncompressed records (when the writer stored one: rosbags writes 0), the record structure,
  the message times against the chunk's header and, for a chunk without CRC, the messages against
  their message index. A chunk that fails is a :class:`Damage` naming the file, the chunk and
  its offset, with the messages lost per channel (from its message index) — never decoded.
* :func:`iter_messages` yields the messages of several scanned files in log-time order (a merge
  over the chunks by their start times, as the MCAP readers do); :func:`loose_message_channel`
  reads the channel of one message outside chunks without reading the message.

Byte layouts follow the MCAP specification (https://mcap.dev/spec); integers little-endian,
strings and byte arrays prefixed with their uint32 length, maps with their uint32 byte length.
"""

from __future__ import annotations

import heapq
import mmap
import struct
import zlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

from roadbev_core.errors import RoadbevError

__all__ = [
    "MAGIC",
    "Channel",
    "ChunkRecord",
    "Damage",
    "FileScan",
    "LoadedChunk",
    "McapFormatError",
    "RawMessage",
    "Schema",
    "iter_messages",
    "load_chunk",
    "loose_message_channel",
    "scan_file",
]

MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_STATISTICS, OP_DATA_END = 0x07, 0x08, 0x0B, 0x0F
_KNOWN_OPS = frozenset(range(0x01, 0x10))
_COMPRESSIONS = ("", "zstd", "lz4")
_CHUNK_FIXED = 8 + 8 + 8 + 4 + 4  # start, end, uncompressed size, crc, compression length


class McapFormatError(RoadbevError, ValueError):
    """Bytes that are not what the MCAP specification says they should be."""


@dataclass(frozen=True)
class Schema:
    """An MCAP Schema record."""

    id: int
    name: str
    encoding: str
    data: bytes


@dataclass(frozen=True)
class Channel:
    """An MCAP Channel record."""

    id: int
    schema_id: int
    topic: str
    message_encoding: str
    metadata: dict[str, str]


@dataclass
class Damage:
    """A part of a file that could not be read, or was read but is suspect.

    Attributes:
        file: the MCAP file.
        offset: byte offset of the damaged part.
        chunk: ordinal of the damaged chunk in its file (0 = first), None outside chunks.
        reason: what is wrong, in words.
        lost: channel id -> messages lost there, as far as an index says; empty when unknown.
        lost_unknown: whether more may be lost than ``lost`` says (the file breaks off, or a
            damaged part had no readable index).
        kept: the data was kept (only its header or index was inconsistent).
    """

    file: Path
    offset: int
    chunk: int | None
    reason: str
    lost: dict[int, int] = field(default_factory=dict)
    lost_unknown: bool = False
    kept: bool = False

    def where(self) -> str:
        part = f"chunk {self.chunk} at byte {self.offset}" if self.chunk is not None else f"byte {self.offset}"
        return f"{self.file.name}: {part}"


@dataclass
class ChunkRecord:
    """A chunk as the scan found it (header fields; the data stays in the file)."""

    file: Path
    ordinal: int
    offset: int
    start_ns: int
    end_ns: int
    uncompressed_size: int
    crc: int
    compression: str
    data_start: int
    data_length: int
    cut: bool = False  # the file ends inside the chunk
    index: dict[int, list[tuple[int, int]]] = field(default_factory=dict)  # channel -> (log time, offset)

    @property
    def indexed_counts(self) -> dict[int, int]:
        return {cid: len(entries) for cid, entries in self.index.items()}


@dataclass
class FileScan:
    """What :func:`scan_file` found in one file."""

    path: Path
    size: int
    profile: str = ""
    library: str = ""
    chunks: list[ChunkRecord] = field(default_factory=list)
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    # (log time, offset, length) of the messages outside chunks
    loose: list[tuple[int, int, int]] = field(default_factory=list)
    statistics: dict[int, int] | None = None  # channel -> messages (the summary's Statistics record)
    data_end: bool = False
    footer: bool = False
    summary_crc_ok: bool | None = None  # None: no summary CRC stored
    damage: list[Damage] = field(default_factory=list)

    @property
    def closed(self) -> bool:
        """Whether the writer finished the file (data end, summary, footer, closing magic)."""
        return self.data_end and self.footer and self.summary_crc_ok is not False

    @property
    def truncated(self) -> bool:
        return any(d.lost_unknown for d in self.damage)


class RawMessage(NamedTuple):
    """One message record: its channel, times and the serialised bytes."""

    channel_id: int
    sequence: int
    log_time_ns: int
    publish_time_ns: int
    data: memoryview


class LoadedChunk(NamedTuple):
    """The content of a checked chunk."""

    schemas: list[Schema]
    channels: list[Channel]
    messages: list[RawMessage]


# ------------------------------------------------------------------------------------------------
# record fields
# ------------------------------------------------------------------------------------------------
class _Cursor:
    """Reads little-endian fields from a buffer, raising McapFormatError past its end."""

    __slots__ = ("buf", "end", "pos")

    def __init__(self, buf: bytes | memoryview | mmap.mmap, pos: int = 0, end: int | None = None) -> None:
        self.buf = buf
        self.pos = pos
        self.end = len(buf) if end is None else end

    def _take(self, n: int) -> int:
        start = self.pos
        if n < 0 or start + n > self.end:
            raise McapFormatError(f"a field runs past its record ({n} bytes at {start}, record ends at {self.end})")
        self.pos = start + n
        return start

    def u16(self) -> int:
        return int.from_bytes(self.buf[self._take(2) : self.pos], "little")

    def u32(self) -> int:
        return int.from_bytes(self.buf[self._take(4) : self.pos], "little")

    def u64(self) -> int:
        return int.from_bytes(self.buf[self._take(8) : self.pos], "little")

    def raw(self, n: int) -> bytes:
        return bytes(self.buf[self._take(n) : self.pos])

    def string(self) -> str:
        try:
            return self.raw(self.u32()).decode("utf-8")
        except UnicodeDecodeError as exc:
            raise McapFormatError(f"a string is not UTF-8: {exc}") from None

    def bytes_(self) -> bytes:
        return self.raw(self.u32())

    def string_map(self) -> dict[str, str]:
        size = self.u32()
        stop = self.pos + size
        if stop > self.end:
            raise McapFormatError("a map runs past its record")
        out: dict[str, str] = {}
        while self.pos < stop:
            key = self.string()
            out[key] = self.string()
        if self.pos != stop:
            raise McapFormatError("a map's entries do not fill its length")
        return out


def _schema(buf: bytes | memoryview | mmap.mmap, start: int, end: int) -> Schema:
    c = _Cursor(buf, start, end)
    return Schema(c.u16(), c.string(), c.string(), c.bytes_())


def _channel(buf: bytes | memoryview | mmap.mmap, start: int, end: int) -> Channel:
    c = _Cursor(buf, start, end)
    return Channel(c.u16(), c.u16(), c.string(), c.string(), c.string_map())


def _message_index(buf: bytes | memoryview | mmap.mmap, start: int, end: int) -> tuple[int, list[tuple[int, int]]]:
    c = _Cursor(buf, start, end)
    channel_id = c.u16()
    size = c.u32()
    if size % 16 or c.pos + size > end:
        raise McapFormatError("a message index's entries do not fit its record")
    entries = []
    for _ in range(size // 16):
        entries.append((c.u64(), c.u64()))
    return channel_id, entries


def _chunk_header(buf: mmap.mmap | bytes, pos: int, size: int) -> ChunkRecord | None:
    """The chunk record at ``pos`` if its header is self-consistent, else None.

    Consistent: the opcode is a chunk, the compression is one the spec names and the record's
    length equals its fields' lengths. A record cut by the end of the file is returned with
    ``cut=True`` when its header is complete and consistent.
    """
    if pos + 9 + _CHUNK_FIXED > size or buf[pos] != OP_CHUNK:
        return None
    length = int.from_bytes(buf[pos + 1 : pos + 9], "little")
    c = _Cursor(buf, pos + 9, size)
    try:
        start_ns, end_ns, uncompressed, crc = c.u64(), c.u64(), c.u64(), c.u32()
        n = c.u32()
        if n > 8:
            return None
        compression = c.raw(n).decode("ascii")
        data_length = c.u64()
    except (McapFormatError, UnicodeDecodeError):
        return None
    if compression not in _COMPRESSIONS or end_ns < start_ns:
        return None
    data_start = c.pos
    if length != data_start - (pos + 9) + data_length:
        return None
    if compression == "" and data_length != uncompressed:
        return None
    cut = pos + 9 + length > size
    return ChunkRecord(Path(), 0, pos, start_ns, end_ns, uncompressed, crc, compression, data_start,
                       data_length, cut)


def _resync(buf: mmap.mmap, pos: int, size: int) -> int | None:
    """The offset of the next consistent chunk record or data-end record after ``pos``."""
    candidates = []
    chunk_at = buf.find(bytes([OP_CHUNK]), pos)
    while chunk_at != -1:
        if _chunk_header(buf, chunk_at, size) is not None:
            candidates.append(chunk_at)
            break
        chunk_at = buf.find(bytes([OP_CHUNK]), chunk_at + 1)
    data_end = buf.find(bytes([OP_DATA_END]) + (4).to_bytes(8, "little"), pos)
    if data_end != -1:
        candidates.append(data_end)
    return min(candidates) if candidates else None


# ------------------------------------------------------------------------------------------------
# the scan
# ------------------------------------------------------------------------------------------------
def scan_file(path: Path) -> FileScan:
    """Walk the top-level records of one MCAP file (see the module docstring).

    Raises:
        McapFormatError: the file does not start with the MCAP magic.
        OSError: the file cannot be read.
    """
    with path.open("rb") as stream:
        size = path.stat().st_size
        if size < len(MAGIC):
            raise McapFormatError(f"{size} bytes, too short for an MCAP file")
        with mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ) as buf:
            if buf[: len(MAGIC)] != MAGIC:
                raise McapFormatError("no MCAP magic at the start: not an MCAP file")
            scan = FileScan(path, size)
            _walk(buf, scan)
            return scan


def _walk(buf: mmap.mmap, scan: FileScan) -> None:
    size, path = scan.size, scan.path
    pos = len(MAGIC)
    summary_chunk_index: list[tuple[int, dict[int, int]]] = []  # (chunk offset, channel -> index offset)
    while pos < size:
        if size - pos < 9:
            if size - pos == len(MAGIC) and buf[pos:] == MAGIC:
                break  # closing magic without a footer before it (checked below)
            scan.damage.append(Damage(path, pos, None, "the file ends inside a record", lost_unknown=True))
            break
        op = buf[pos]
        length = int.from_bytes(buf[pos + 1 : pos + 9], "little")
        end = pos + 9 + length
        if op == OP_CHUNK:
            chunk = _chunk_header(buf, pos, size)
            if chunk is None:
                pos = _skip_garbage(buf, scan, pos, "a chunk header that does not parse")
                if pos < 0:
                    break
                continue
            chunk.file, chunk.ordinal = path, len(scan.chunks)
            scan.chunks.append(chunk)
            if chunk.cut:
                scan.damage.append(Damage(path, pos, chunk.ordinal,
                                          f"the file ends inside this chunk ({size - pos} of {9 + length} bytes)",
                                          lost_unknown=True))
                break
            pos = end
            continue
        if op not in _KNOWN_OPS:
            pos = _skip_garbage(buf, scan, pos, f"no record (opcode 0x{op:02x})")
            if pos < 0:
                break
            continue
        if end > size:
            what = "the summary" if scan.data_end else "a record"
            scan.damage.append(Damage(path, pos, None, f"the file ends inside {what} (opcode 0x{op:02x})",
                                      lost_unknown=not scan.data_end))
            break
        try:
            if op == OP_HEADER:
                c = _Cursor(buf, pos + 9, end)
                scan.profile, scan.library = c.string(), c.string()
            elif op == OP_SCHEMA:
                schema = _schema(buf, pos + 9, end)
                scan.schemas.setdefault(schema.id, schema)
            elif op == OP_CHANNEL:
                channel = _channel(buf, pos + 9, end)
                scan.channels.setdefault(channel.id, channel)
            elif op == OP_MESSAGE:
                c = _Cursor(buf, pos + 9, end)
                c.u16(), c.u32()
                scan.loose.append((c.u64(), pos, length))
            elif op == OP_MESSAGE_INDEX:
                channel_id, entries = _message_index(buf, pos + 9, end)
                if scan.chunks and not scan.data_end:
                    scan.chunks[-1].index[channel_id] = entries
            elif op == OP_CHUNK_INDEX:
                c = _Cursor(buf, pos + 9, end)
                c.u64(), c.u64()
                offset = c.u64()
                c.u64()
                n = c.u32()
                offsets = {}
                for _ in range(n // 10):
                    cid = c.u16()
                    offsets[cid] = c.u64()
                summary_chunk_index.append((offset, offsets))
            elif op == OP_STATISTICS:
                c = _Cursor(buf, pos + 9, end)
                c.u64(), c.u16(), c.u32(), c.u32(), c.u32(), c.u32(), c.u64(), c.u64()
                n = c.u32()
                counts = {}
                for _ in range(n // 10):
                    cid = c.u16()
                    counts[cid] = c.u64()
                scan.statistics = counts
            elif op == OP_DATA_END:
                scan.data_end = True
            elif op == OP_FOOTER:
                _footer(buf, scan, pos, end)
                break
        except McapFormatError as exc:  # an index or summary record: the data itself is elsewhere
            scan.damage.append(Damage(path, pos, None, f"a malformed record (opcode 0x{op:02x}): {exc}",
                                      kept=op not in (OP_SCHEMA, OP_CHANNEL, OP_MESSAGE)))
        pos = end
    _lost_chunks_from_summary(buf, scan, summary_chunk_index)


def _skip_garbage(buf: mmap.mmap, scan: FileScan, pos: int, why: str) -> int:
    """Note unreadable bytes from ``pos`` and return where reading resumes (-1: nowhere)."""
    resume = _resync(buf, pos + 1, scan.size)
    if resume is None:
        scan.damage.append(Damage(scan.path, pos, None, f"{why}; nothing readable follows", lost_unknown=True))
        return -1
    scan.damage.append(Damage(scan.path, pos, None, f"{why}; {resume - pos} unreadable bytes skipped",
                              lost_unknown=True))
    return resume


def _footer(buf: mmap.mmap, scan: FileScan, pos: int, end: int) -> None:
    c = _Cursor(buf, pos + 9, end)
    summary_start, _summary_offset_start, summary_crc = c.u64(), c.u64(), c.u32()
    scan.footer = end + len(MAGIC) == scan.size and buf[end:] == MAGIC
    if summary_crc:
        first = summary_start if summary_start else pos
        scan.summary_crc_ok = zlib.crc32(buf[first : pos + 25]) == summary_crc
        if not scan.summary_crc_ok:
            scan.damage.append(Damage(scan.path, first, None, "the summary's CRC does not match", kept=True))


def _lost_chunks_from_summary(buf: mmap.mmap, scan: FileScan, index: list[tuple[int, dict[int, int]]]) -> None:
    """Chunks the summary lists that the scan could not read: count their messages from their index."""
    if not index or scan.summary_crc_ok is False:
        return
    found = {c.offset for c in scan.chunks}
    for offset, offsets in index:
        if offset in found:
            continue
        lost: dict[int, int] = {}
        for channel_id, at in offsets.items():
            try:
                length = int.from_bytes(buf[at + 1 : at + 9], "little")
                if buf[at] == OP_MESSAGE_INDEX and at + 9 + length <= scan.size:
                    lost[channel_id] = len(_message_index(buf, at + 9, at + 9 + length)[1])
            except (McapFormatError, IndexError):
                continue
        swallowed = [d for d in scan.damage if d.chunk is None and not d.kept and d.offset <= offset]
        if swallowed:  # the unreadable stretch that took this chunk with it
            for cid, n in lost.items():
                swallowed[-1].lost[cid] = swallowed[-1].lost.get(cid, 0) + n
        else:
            scan.damage.append(Damage(scan.path, offset, None, "a chunk the summary lists is unreadable", lost))


# ------------------------------------------------------------------------------------------------
# chunks
# ------------------------------------------------------------------------------------------------
def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if compression == "":
        return data
    if compression == "zstd":
        # lazy: only a zstd-compressed chunk needs it
        import zstandard

        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    try:
        import lz4.frame  # type: ignore[import-not-found,import-untyped,unused-ignore]
    except ImportError:
        raise McapFormatError("lz4 chunks need the lz4 package") from None
    return bytes(lz4.frame.decompress(data))


def _parse_records(data: bytes) -> LoadedChunk:
    view = memoryview(data)
    schemas: list[Schema] = []
    channels: list[Channel] = []
    messages: list[RawMessage] = []
    pos, size = 0, len(data)
    while pos < size:
        if size - pos < 9:
            raise McapFormatError(f"{size - pos} stray bytes at the end")
        op = data[pos]
        length = int.from_bytes(data[pos + 1 : pos + 9], "little")
        end = pos + 9 + length
        if end > size:
            raise McapFormatError(f"a record at {pos} runs past the chunk")
        if op == OP_MESSAGE:
            if length < 22:
                raise McapFormatError(f"a message record of {length} bytes")
            channel_id, sequence, log_time, publish_time = struct.unpack_from("<HIQQ", data, pos + 9)
            messages.append(RawMessage(channel_id, sequence, log_time, publish_time, view[pos + 31 : end]))
        elif op == OP_SCHEMA:
            schemas.append(_schema(data, pos + 9, end))
        elif op == OP_CHANNEL:
            channels.append(_channel(data, pos + 9, end))
        elif op not in _KNOWN_OPS:
            raise McapFormatError(f"no record at {pos} (opcode 0x{op:02x})")
        pos = end
    return LoadedChunk(schemas, channels, messages)


def _message_offsets(data: bytes) -> dict[int, list[tuple[int, int]]]:
    out: dict[int, list[tuple[int, int]]] = {}
    pos = 0
    while pos + 9 <= len(data):
        length = int.from_bytes(data[pos + 1 : pos + 9], "little")
        if data[pos] == OP_MESSAGE and pos + 31 <= len(data):
            channel_id, _seq, log_time = struct.unpack_from("<HIQ", data, pos + 9)
            out.setdefault(channel_id, []).append((log_time, pos))
        pos += 9 + length
    return out


def load_chunk(chunk: ChunkRecord) -> tuple[LoadedChunk | None, Damage | None]:
    """Decompress and check one chunk.

    Returns:
        (content, None) for a sound chunk; (content, damage with ``kept=True``) when only its
        header times or its index disagree with CRC-checked content; (None, damage) when the
        content cannot be trusted (the damage names the chunk and counts its messages from the
        chunk's message index).
    """
    def damaged(reason: str) -> tuple[None, Damage]:
        return None, Damage(chunk.file, chunk.offset, chunk.ordinal, reason, chunk.indexed_counts,
                            lost_unknown=chunk.cut or not chunk.index)

    if chunk.cut:
        return damaged("the file ends inside this chunk")
    with chunk.file.open("rb") as stream:
        stream.seek(chunk.data_start)
        packed = stream.read(chunk.data_length)
    if len(packed) != chunk.data_length:
        return damaged("the file ends inside this chunk")
    try:
        data = _decompress(chunk.compression, packed, chunk.uncompressed_size)
    except McapFormatError:
        raise
    except Exception as exc:  # zstandard / lz4 raise their own error types
        return damaged(f"its {chunk.compression} data does not decompress ({exc})")
    if len(data) != chunk.uncompressed_size:
        return damaged(f"it decompresses to {len(data)} bytes, its header says {chunk.uncompressed_size}")
    verified = chunk.crc != 0
    if verified and zlib.crc32(data) != chunk.crc:
        return damaged("its CRC does not match its content")
    try:
        content = _parse_records(data)
    except McapFormatError as exc:
        return damaged(f"its records are malformed ({exc})")
    if not verified and chunk.index:
        # No CRC (rosbags writes none): the message index is the only independent check.
        listed = {cid: sorted(entries) for cid, entries in chunk.index.items()}
        found = {cid: sorted(entries) for cid, entries in _message_offsets(data).items()}
        if listed != found:
            return damaged("its messages do not match its message index (and it has no CRC)")
    if content.messages:
        low = min(m.log_time_ns for m in content.messages)
        high = max(m.log_time_ns for m in content.messages)
        if low < chunk.start_ns or high > chunk.end_ns:
            if not verified:
                return damaged("its message times lie outside its header's time range (and it has no CRC)")
            return content, Damage(chunk.file, chunk.offset, chunk.ordinal,
                                   "its header's time range does not match its (CRC-checked) messages; "
                                   "messages kept", kept=True)
    return content, None


# ------------------------------------------------------------------------------------------------
# messages in log-time order
# ------------------------------------------------------------------------------------------------
class _Group(NamedTuple):
    start_ns: int
    order: int
    scan: FileScan
    load: Callable[[], list[RawMessage]]


def iter_messages(
    scans: Iterable[FileScan],
    *,
    on_damage: Callable[[Damage], None],
    on_channels: Callable[[FileScan, list[Schema], list[Channel]], None],
) -> Iterator[tuple[FileScan, RawMessage]]:
    """Every message of sound chunks (and outside chunks) of ``scans``, in log-time order.

    Chunks are decompressed one at a time, when the merge reaches their start time, so memory
    holds about one chunk per overlapping chunk, not the bag.

    Args:
        scans: the files of one bag.
        on_damage: called with every damaged chunk met (its messages are not yielded).
        on_channels: called with the schemas and channels a chunk defines, before its messages.
    """
    groups: list[_Group] = []
    for scan in scans:
        for chunk in scan.chunks:
            if chunk.cut:
                continue  # already a Damage of the scan

            def load(chunk: ChunkRecord = chunk, scan: FileScan = scan) -> list[RawMessage]:
                content, damage = load_chunk(chunk)
                if damage is not None:
                    on_damage(damage)
                if content is None:
                    return []
                on_channels(scan, content.schemas, content.channels)
                return content.messages

            groups.append(_Group(chunk.start_ns, len(groups), scan, load))
        if scan.loose:
            def load_loose(scan: FileScan = scan) -> list[RawMessage]:
                return _loose_messages(scan)

            groups.append(_Group(min(t for t, _o, _n in scan.loose), len(groups), scan, load_loose))
    by_order = {g.order: g.scan for g in groups}
    groups.sort(key=lambda g: (g.start_ns, g.order))
    heap: list[tuple[int, int, int, RawMessage]] = []
    i = 0
    while i < len(groups) or heap:
        while i < len(groups) and (not heap or groups[i].start_ns <= heap[0][0]):
            group = groups[i]
            for seq, message in enumerate(group.load()):
                heapq.heappush(heap, (message.log_time_ns, group.order, seq, message))
            i += 1
        if heap:
            _t, order, _seq, message = heapq.heappop(heap)
            yield by_order[order], message


def _loose_messages(scan: FileScan) -> list[RawMessage]:
    with scan.path.open("rb") as stream:
        out = []
        for _log_time, offset, length in scan.loose:
            stream.seek(offset + 9)
            body = stream.read(length)
            channel_id, sequence, log_time, publish_time = struct.unpack_from("<HIQQ", body, 0)
            out.append(RawMessage(channel_id, sequence, log_time, publish_time, memoryview(body)[22:]))
        return out


def loose_message_channel(scan: FileScan, offset: int) -> int:
    """The channel id of the message outside chunks whose record starts at byte ``offset``."""
    with scan.path.open("rb") as stream:
        stream.seek(offset + 9)
        return int.from_bytes(stream.read(2), "little")
