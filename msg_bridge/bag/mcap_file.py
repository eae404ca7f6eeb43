"""MCAP files read record by record, every chunk checked before anything in it is used.

The MCAP readers stop at the first cut or damaged chunk, and neither checks chunk CRCs by
default; this module is the project's own reader underneath :mod:`msg_bridge.bag`:

* :func:`scan_file` walks the top-level records of one file (chunk *headers* only, no
  decompression): schemas and channels outside chunks, the chunks with the message indexes that
  follow them, the summary, the footer. A record cut by the end of the file (a crashed writer)
  or bytes that are no record (damage) are noted as :class:`Damage`; after garbage the scan
  resynchronises on the next record that parses as a consistent chunk, so one damaged header
  costs one chunk, not the rest of the file. The reader never jumps by an index: every offset
  it uses comes from this linear walk.
* The summary (schemas, channels, statistics, chunk indexes) is used only when it can be
  trusted: its CRC matches (``Footer.summary_crc``, when non-zero), every record in it parses
  and the footer says where it starts. Otherwise it is ignored as a whole (one
  :class:`Damage`), and channels and counts come from the data section and the chunks. A footer
  whose summary CRC matches also fixes where the data section ends, so a damaged length or
  opcode inside the data section is skipped as garbage, not taken for the end of the data.
* The data section's CRC (``DataEnd.data_section_crc``, when non-zero) covers what no chunk CRC
  does: message indexes, the metadata record, records outside chunks. When it does not match
  and nothing else in the data section explains it, :func:`iter_messages` reports it once the
  chunks are read; messages outside chunks, which nothing else checks, are then not trusted.
* :func:`load_chunk` decompresses one chunk and checks it: the decompressed size, the CRC-32 of
  the uncompressed records (when the writer stored one: rosbags writes 0), the record structure,
  the message times against the chunk's header and the messages against their message index
  (for a chunk without CRC the index is the only check; for one with CRC a mismatch means the
  index is damaged). A chunk that fails is a :class:`Damage` naming the file, the chunk and its
  offset, with the messages lost per channel (from its message index) — never decoded.
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
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_ATTACHMENT, OP_ATTACHMENT_INDEX = 0x07, 0x08, 0x09, 0x0A
OP_STATISTICS, OP_METADATA, OP_METADATA_INDEX, OP_SUMMARY_OFFSET, OP_DATA_END = 0x0B, 0x0C, 0x0D, 0x0E, 0x0F
_KNOWN_OPS = frozenset(range(0x01, 0x10))
# records the specification places in the summary section only
_SUMMARY_OPS = frozenset({OP_SCHEMA, OP_CHANNEL, OP_CHUNK_INDEX, OP_ATTACHMENT_INDEX, OP_METADATA_INDEX,
                          OP_STATISTICS, OP_SUMMARY_OFFSET})
_FOOTER_LENGTH = 8 + 8 + 4  # summary start, summary offset start, summary CRC
_DATA_END_RECORD = 1 + 8 + 4  # opcode, length, data section CRC
_CRC_BLOCK = 1 << 24  # bytes per zlib.crc32 call over a mapped file (no copy of the whole file)
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
    data_end_offset: int | None = None  # byte offset of the DataEnd record
    data_crc_ok: bool | None = None  # None: no data section CRC stored, or not checked
    footer: bool = False
    summary_crc_ok: bool | None = None  # None: no summary CRC stored
    summary_used: bool = False  # the summary's schemas, channels, statistics and chunk indexes were taken
    damage: list[Damage] = field(default_factory=list)

    @property
    def closed(self) -> bool:
        """Whether the writer finished the file (data end, footer, closing magic); a damaged
        summary is a :class:`Damage` of its own."""
        return self.data_end and self.footer

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

    def u8(self) -> int:
        return int(self.buf[self._take(1)])

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


def _resync(buf: mmap.mmap, pos: int, limit: int) -> int | None:
    """The offset of the next consistent chunk record or data-end record in ``[pos, limit)``."""
    candidates = []
    chunk_at = buf.find(bytes([OP_CHUNK]), pos, limit)
    while chunk_at != -1:
        if _chunk_header(buf, chunk_at, limit) is not None:
            candidates.append(chunk_at)
            break
        chunk_at = buf.find(bytes([OP_CHUNK]), chunk_at + 1, limit)
    data_end = buf.find(bytes([OP_DATA_END]) + (4).to_bytes(8, "little"), pos, limit)
    if data_end != -1:
        candidates.append(data_end)
    return min(candidates) if candidates else None


def _crc32(buf: mmap.mmap, start: int, end: int) -> int:
    """CRC-32 of ``buf[start:end]``, read in blocks."""
    crc = 0
    for at in range(start, end, _CRC_BLOCK):
        crc = zlib.crc32(buf[at : min(end, at + _CRC_BLOCK)], crc)
    return crc


# ------------------------------------------------------------------------------------------------
# the footer and the summary
# ------------------------------------------------------------------------------------------------
class _Footer(NamedTuple):
    offset: int
    end: int
    summary_start: int
    summary_crc: int

    @property
    def first(self) -> int:
        """Where the summary starts by this footer (the footer itself when there is none)."""
        return self.summary_start or self.offset


def _read_footer(buf: mmap.mmap, pos: int, end: int) -> _Footer:
    c = _Cursor(buf, pos + 9, end)
    summary_start, _summary_offset_start, summary_crc = c.u64(), c.u64(), c.u32()
    return _Footer(pos, end, summary_start, summary_crc)


def _trailing_footer(buf: mmap.mmap, size: int) -> _Footer | None:
    """The footer where a finished file has it, right before the closing magic; None if it is not there."""
    pos = size - len(MAGIC) - 9 - _FOOTER_LENGTH
    if pos < len(MAGIC) or buf[size - len(MAGIC) :] != MAGIC or buf[pos] != OP_FOOTER:
        return None
    if int.from_bytes(buf[pos + 1 : pos + 9], "little") != _FOOTER_LENGTH:
        return None
    return _read_footer(buf, pos, pos + 9 + _FOOTER_LENGTH)


def _summary_crc_matches(buf: mmap.mmap, footer: _Footer) -> bool:
    """Whether ``footer.summary_crc`` is the CRC of the summary and the footer's own fields."""
    return footer.first <= footer.offset and _crc32(buf, footer.first, footer.offset + 25) == footer.summary_crc


class _ChunkIndex(NamedTuple):
    offset: int
    length: int
    message_index_offsets: dict[int, int]  # channel -> offset of its message index
    message_index_length: int


@dataclass
class _Summary:
    """The records of a summary section, held back until the summary is known to be sound."""

    start: int
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    statistics: dict[int, int] | None = None
    chunk_indexes: list[_ChunkIndex] = field(default_factory=list)
    # [start, end) of the data section's records that the summary indexes besides chunks
    indexed_spans: list[tuple[int, int]] = field(default_factory=list)
    end: int = 0  # where the walk through it stopped
    cut: bool = False  # the file ends inside it
    problem: str = ""  # why it cannot be read (a record that does not parse, bytes that are no record)


def _id_map(c: _Cursor, what: str) -> dict[int, int]:
    """A map<uint16, uint64> (channel -> offset or count)."""
    size = c.u32()
    if size % 10:
        raise McapFormatError(f"{what} of {size} bytes is not a whole number of entries")
    out = {}
    for _ in range(size // 10):
        key = c.u16()
        out[key] = c.u64()
    return out


def _summary_record(buf: mmap.mmap, op: int, start: int, end: int, summary: _Summary) -> None:
    """Add one summary record to ``summary`` (McapFormatError: it does not parse)."""
    c = _Cursor(buf, start, end)
    if op == OP_SCHEMA:
        schema = _schema(buf, start, end)
        summary.schemas.setdefault(schema.id, schema)
    elif op == OP_CHANNEL:
        channel = _channel(buf, start, end)
        summary.channels.setdefault(channel.id, channel)
    elif op == OP_STATISTICS:
        c.u64(), c.u16(), c.u32(), c.u32(), c.u32(), c.u32(), c.u64(), c.u64()
        summary.statistics = _id_map(c, "a channel message count map")
    elif op == OP_CHUNK_INDEX:
        c.u64(), c.u64()
        offset, length = c.u64(), c.u64()
        offsets = _id_map(c, "a message index offset map")
        index_length = c.u64()
        c.string(), c.u64(), c.u64()
        summary.chunk_indexes.append(_ChunkIndex(offset, length, offsets, index_length))
        summary.indexed_spans.append((offset + length, offset + length + index_length))
    elif op in (OP_METADATA_INDEX, OP_ATTACHMENT_INDEX):
        offset, length = c.u64(), c.u64()
        if op == OP_ATTACHMENT_INDEX:
            c.u64(), c.u64(), c.u64()
        c.string()
        summary.indexed_spans.append((offset, offset + length))
    elif op == OP_SUMMARY_OFFSET:
        c.u8(), c.u64(), c.u64()


def _walk_summary(buf: mmap.mmap, start: int, stop: int, find_footer: bool) -> tuple[_Summary, _Footer | None]:
    """The summary records in ``[start, stop)``; with ``find_footer`` (no footer where a finished
    file has it) the walk also looks for the footer."""
    summary = _Summary(start)
    pos = start
    footer = None
    while pos < stop:
        op = buf[pos]
        length = int.from_bytes(buf[pos + 1 : pos + 9], "little")
        end = pos + 9 + length
        if find_footer and op == OP_FOOTER and stop - pos >= 9 and end <= stop:
            try:
                footer = _read_footer(buf, pos, end)
            except McapFormatError as exc:
                summary.problem = f"its footer is malformed: {exc}"
            break
        if stop - pos < 9 or end > stop:
            if find_footer:
                summary.cut = True
                summary.problem = f"the file ends inside the summary (opcode 0x{op:02x})"
            else:
                summary.problem = f"a record (opcode 0x{op:02x}) runs past the footer"
            break
        if op not in _SUMMARY_OPS:
            summary.problem = f"bytes at {pos} are no summary record (opcode 0x{op:02x})"
            break
        try:
            _summary_record(buf, op, pos + 9, end, summary)
        except McapFormatError as exc:
            summary.problem = f"a summary record at {pos} is malformed (opcode 0x{op:02x}): {exc}"
            break
        pos = end
    summary.end = pos
    return summary, footer


def _covered(spans: list[tuple[int, int]], start: int, end: int) -> bool:
    """Whether ``spans`` cover every byte of ``[start, end)``."""
    reached = start
    for first, last in sorted(spans):
        if last <= reached:
            continue
        if first > reached:
            return False
        reached = last
        if reached >= end:
            return True
    return reached >= end


# ------------------------------------------------------------------------------------------------
# the scan
# ------------------------------------------------------------------------------------------------
def scan_file(path: Path, *, check_data_crc: bool = True) -> FileScan:
    """Walk the top-level records of one MCAP file (see the module docstring).

    Args:
        path: the MCAP file.
        check_data_crc: check the data section's CRC (reads the whole file; an index-only look
            at a bag can skip it).

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
            _Walk(buf, scan, check_data_crc).run()
            return scan


class _Walk:
    """One walk through a file's records: the data section, then the summary and the footer."""

    def __init__(self, buf: mmap.mmap, scan: FileScan, check_data_crc: bool) -> None:
        self.buf, self.scan, self.check_data_crc = buf, scan, check_data_crc
        self.footer = _trailing_footer(buf, scan.size)
        self.summary_crcs: dict[_Footer, bool] = {}
        # A footer whose summary CRC matches says where the data section ends: no damaged
        # length or opcode before that is taken for the end of the data.
        verified = self.footer is not None and self.footer.summary_crc != 0 and self._summary_crc_ok(self.footer)
        self.data_limit = self.footer.first if self.footer is not None and verified else scan.size
        self.bounded = self.data_limit < scan.size
        self.garbage: list[tuple[Damage, str, int]] = []  # (damage, why, where reading resumed)

    def _summary_crc_ok(self, footer: _Footer) -> bool:
        if footer not in self.summary_crcs:
            self.summary_crcs[footer] = _summary_crc_matches(self.buf, footer)
        return self.summary_crcs[footer]

    def run(self) -> None:
        end = self._data_section()
        if end is None and self.bounded:
            # The data end itself is damaged, but the footer's CRC-checked summary says where
            # the data section ends and that the writer finished the file.
            scan = self.scan
            scan.data_end = True
            end = self.data_limit
            if not any(resume == end for _d, _why, resume in self.garbage):
                scan.damage.append(Damage(scan.path, end, None, "no data-end record where the footer's (CRC-checked) "
                                          "summary starts: the data section's CRC cannot be checked", kept=True))
        if end is not None:
            self._summary(end)
        if self.scan.data_crc_ok is False and self.scan.loose:
            self._distrust_loose_messages()

    def _skip_garbage(self, pos: int, why: str) -> int:
        """Note unreadable bytes from ``pos`` and return where reading resumes (-1: nowhere)."""
        scan = self.scan
        resume = _resync(self.buf, pos + 1, self.data_limit)
        if resume is None and self.bounded:
            resume = self.data_limit  # the summary, which a CRC-checked footer places there
        if resume is None:
            scan.damage.append(Damage(scan.path, pos, None, f"{why}; nothing readable follows", lost_unknown=True))
            return -1
        damage = Damage(scan.path, pos, None, f"{why}; {resume - pos} unreadable bytes skipped", lost_unknown=True)
        scan.damage.append(damage)
        self.garbage.append((damage, why, resume))
        return resume

    def _misplaced(self, op: int, pos: int, end: int) -> str:
        """Why the record at ``pos`` cannot be what its opcode says (""; it can)."""
        if op not in _KNOWN_OPS:
            return f"no record (opcode 0x{op:02x})"
        if op == OP_HEADER and pos != len(MAGIC):
            return "a header record after the start of the file"
        if op == OP_FOOTER and self.footer is not None and pos != self.footer.offset:
            return "a footer record inside the data section"
        if op == OP_DATA_END and self.bounded and end != self.data_limit:
            return "a data-end record inside the data section"
        if end > self.data_limit and self.bounded:
            return f"a record (opcode 0x{op:02x}) that runs past the data section"
        return ""

    def _data_section(self) -> int | None:
        """Walk the data section; where the summary starts (None: no data end reached)."""
        buf, scan = self.buf, self.scan
        size, path, limit = scan.size, scan.path, self.data_limit
        pos = len(MAGIC)
        while pos < limit:
            if limit - pos < 9:
                if not self.bounded:
                    if limit - pos == len(MAGIC) and buf[pos:limit] == MAGIC:
                        return None  # closing magic without a footer before it
                    scan.damage.append(Damage(path, pos, None, "the file ends inside a record", lost_unknown=True))
                    return None
                pos = self._skip_garbage(pos, f"{limit - pos} stray bytes")
                if pos < 0:
                    return None
                continue
            op = buf[pos]
            length = int.from_bytes(buf[pos + 1 : pos + 9], "little")
            end = pos + 9 + length
            if op == OP_CHUNK:
                chunk = _chunk_header(buf, pos, limit)
                if chunk is None or (chunk.cut and self.bounded):
                    pos = self._skip_garbage(pos, "a chunk header that does not parse")
                    if pos < 0:
                        return None
                    continue
                chunk.file, chunk.ordinal = path, len(scan.chunks)
                scan.chunks.append(chunk)
                if chunk.cut:
                    scan.damage.append(Damage(path, pos, chunk.ordinal,
                                              f"the file ends inside this chunk ({size - pos} of {9 + length} bytes)",
                                              lost_unknown=True))
                    return None
                pos = end
                continue
            why = self._misplaced(op, pos, end)
            if not why and end > size:
                if _resync(buf, pos + 1, limit) is None:  # nothing follows: the file was cut here
                    scan.damage.append(Damage(path, pos, None, f"the file ends inside a record (opcode 0x{op:02x})",
                                              lost_unknown=True))
                    return None
                why = f"a record (opcode 0x{op:02x}) whose length runs past the end of the file"
            if why:
                pos = self._skip_garbage(pos, why)
                if pos < 0:
                    return None
                continue
            try:
                if op == OP_DATA_END:
                    self._data_end(pos, end)
                    return end
                if op == OP_FOOTER:  # no data end before it: the footer closes the file all the same
                    self._footer(_read_footer(buf, pos, end))
                    return None
                self._data_record(op, pos, end)
            except McapFormatError as exc:  # an index or summary record: the data itself is elsewhere
                scan.damage.append(Damage(path, pos, None, f"a malformed record (opcode 0x{op:02x}): {exc}",
                                          kept=op not in (OP_SCHEMA, OP_CHANNEL, OP_MESSAGE)))
            pos = end
        return None

    def _data_record(self, op: int, pos: int, end: int) -> None:
        buf, scan = self.buf, self.scan
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
            scan.loose.append((c.u64(), pos, end - pos - 9))
        elif op == OP_MESSAGE_INDEX:
            channel_id, entries = _message_index(buf, pos + 9, end)
            if scan.chunks:
                scan.chunks[-1].index[channel_id] = entries
        # Summary records (statistics, indexes) count only in the summary; metadata and
        # attachments are not read.

    def _data_end(self, pos: int, end: int) -> None:
        scan = self.scan
        scan.data_end, scan.data_end_offset = True, pos
        crc = _Cursor(self.buf, pos + 9, end).u32() if end - pos - 9 >= 4 else 0
        if crc and self.check_data_crc:
            scan.data_crc_ok = _crc32(self.buf, 0, pos) == crc

    def _footer(self, footer: _Footer) -> None:
        scan = self.scan
        scan.footer = footer.end + len(MAGIC) == scan.size and self.buf[footer.end :] == MAGIC
        if not scan.footer:
            scan.damage.append(Damage(scan.path, footer.end, None,
                                      "the file does not end with the MCAP magic right after its footer", kept=True))
        if footer.summary_crc:
            scan.summary_crc_ok = self._summary_crc_ok(footer)

    def _summary(self, start: int) -> None:
        """Walk the summary from ``start``; take it if it is sound, else note why it is ignored."""
        scan, footer = self.scan, self.footer
        stop = footer.offset if footer is not None else scan.size
        summary, found = _walk_summary(self.buf, start, stop, find_footer=footer is None)
        footer = footer or found
        if footer is not None:
            self._footer(footer)
        if footer is None:
            why = summary.problem or "no footer follows it"
        elif scan.summary_crc_ok is False:
            why = "the summary's CRC does not match"
        elif summary.problem:
            why = summary.problem
        elif footer.first != start:
            why = f"the footer puts the summary at byte {footer.first}, the data section ends at byte {start}"
        else:
            self._take(summary)
            return
        if summary.cut or summary.end > start or footer is not None:
            scan.damage.append(Damage(scan.path, start, None,
                                      f"{why}: the summary is ignored, channels and counts come from the data section",
                                      kept=not summary.cut))

    def _take(self, summary: _Summary) -> None:
        scan = self.scan
        scan.summary_used = True
        for schema in summary.schemas.values():
            scan.schemas.setdefault(schema.id, schema)
        for channel in summary.channels.values():
            scan.channels.setdefault(channel.id, channel)
        scan.statistics = summary.statistics
        self._lost_chunks(summary.chunk_indexes)
        # Unreadable stretches that the summary shows held only message indexes, metadata or
        # the data end: no message was lost there (the chunks' CRCs check what they hold).
        spans = [*summary.indexed_spans, (summary.start - _DATA_END_RECORD, summary.start)]
        for damage, why, resume in self.garbage:
            if _covered(spans, damage.offset, resume):
                damage.reason = (f"{why}; {resume - damage.offset} bytes skipped, which by the summary's index "
                                 "hold only message indexes or metadata")
                damage.kept, damage.lost_unknown = True, False

    def _lost_chunks(self, indexes: list[_ChunkIndex]) -> None:
        """Chunks the summary lists that the scan could not read: count their messages from their index."""
        buf, scan = self.buf, self.scan
        found = {c.offset for c in scan.chunks}
        for index in indexes:
            if index.offset in found:
                continue
            lost: dict[int, int] = {}
            for channel_id, at in index.message_index_offsets.items():
                try:
                    length = int.from_bytes(buf[at + 1 : at + 9], "little")
                    if buf[at] == OP_MESSAGE_INDEX and at + 9 + length <= scan.size:
                        lost[channel_id] = len(_message_index(buf, at + 9, at + 9 + length)[1])
                except (McapFormatError, IndexError):
                    continue
            swallowed = [d for d in scan.damage if d.chunk is None and not d.kept and d.offset <= index.offset]
            if swallowed:  # the unreadable stretch that took this chunk with it
                for cid, n in lost.items():
                    swallowed[-1].lost[cid] = swallowed[-1].lost.get(cid, 0) + n
            else:
                scan.damage.append(Damage(scan.path, index.offset, None, "a chunk the summary lists is unreadable",
                                          lost))

    def _distrust_loose_messages(self) -> None:
        """Messages outside chunks have no CRC but the data section's: when it fails, drop them."""
        scan = self.scan
        lost: dict[int, int] = {}
        for _t, offset, _n in scan.loose:
            cid = int.from_bytes(self.buf[offset + 9 : offset + 11], "little")
            lost[cid] = lost.get(cid, 0) + 1
        scan.damage.append(Damage(scan.path, scan.loose[0][1], None,
                                  f"{len(scan.loose)} message(s) outside chunks, which only the data section's CRC "
                                  "covers, and it does not match", lost))
        scan.loose = []


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


def _parse_records(data: bytes) -> tuple[LoadedChunk, dict[int, list[tuple[int, int]]]]:
    """The records of a chunk, and channel -> (log time, offset) of its messages (what its
    message index should say)."""
    view = memoryview(data)
    schemas: list[Schema] = []
    channels: list[Channel] = []
    messages: list[RawMessage] = []
    offsets: dict[int, list[tuple[int, int]]] = {}
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
            offsets.setdefault(channel_id, []).append((log_time, pos))
        elif op == OP_SCHEMA:
            schemas.append(_schema(data, pos + 9, end))
        elif op == OP_CHANNEL:
            channels.append(_channel(data, pos + 9, end))
        elif op not in _KNOWN_OPS:
            raise McapFormatError(f"no record at {pos} (opcode 0x{op:02x})")
        pos = end
    return LoadedChunk(schemas, channels, messages), offsets


def load_chunk(chunk: ChunkRecord) -> tuple[LoadedChunk | None, Damage | None]:
    """Decompress and check one chunk.

    Returns:
        (content, None) for a sound chunk; (content, damage with ``kept=True``) when only its
        header times or its message index disagree with CRC-checked content (the index is
        damaged, never trusted over the content); (None, damage) when the
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
        content, offsets = _parse_records(data)
    except McapFormatError as exc:
        return damaged(f"its records are malformed ({exc})")
    disagree = []
    if chunk.index:
        listed = {cid: sorted(entries) for cid, entries in chunk.index.items() if entries}
        if listed != {cid: sorted(entries) for cid, entries in offsets.items()}:
            if not verified:  # no CRC (rosbags writes none): the index is the only independent check
                return damaged("its messages do not match its message index (and it has no CRC)")
            disagree.append("its message index does not match its (CRC-checked) messages")
    if content.messages:
        low = min(m.log_time_ns for m in content.messages)
        high = max(m.log_time_ns for m in content.messages)
        if low < chunk.start_ns or high > chunk.end_ns:
            if not verified:
                return damaged("its message times lie outside its header's time range (and it has no CRC)")
            disagree.append("its header's time range does not match its (CRC-checked) messages")
    if disagree:
        return content, Damage(chunk.file, chunk.offset, chunk.ordinal, "; ".join(disagree) + "; messages kept",
                               kept=True)
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
        on_damage: called with every damaged chunk met (its messages are not yielded) and, after
            the last message, with a data section CRC mismatch that no damage found explains.
        on_channels: called with the schemas and channels a chunk defines, before its messages.
    """
    scans = list(scans)
    # files with damage found in their data section: it explains a data section CRC mismatch
    explained = {d.file for s in scans for d in s.damage if s.data_end_offset is None or d.offset < s.data_end_offset}
    groups: list[_Group] = []
    for scan in scans:
        for chunk in scan.chunks:
            if chunk.cut:
                continue  # already a Damage of the scan

            def load(chunk: ChunkRecord = chunk, scan: FileScan = scan) -> list[RawMessage]:
                content, damage = load_chunk(chunk)
                if damage is not None:
                    explained.add(damage.file)
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
    for scan in scans:
        if scan.data_crc_ok is False and scan.path not in explained:
            on_damage(_data_crc_damage(scan))


def _data_crc_damage(scan: FileScan) -> Damage:
    """The damage a data section CRC mismatch is when every chunk read was sound: something
    outside the chunks (a message index, the metadata record) is damaged; what was still checked."""
    unchecked = sum(1 for c in scan.chunks if c.crc == 0)
    checked = ("every chunk passed its own CRC, so every message read is sound" if not unchecked else
               f"{unchecked} chunk(s) without a CRC of their own were checked against their message index only")
    return Damage(scan.path, scan.data_end_offset or 0, None,
                  f"the data section's CRC does not match: a record outside the chunks (a message index, the "
                  f"metadata) is damaged; {checked}", kept=True)


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
