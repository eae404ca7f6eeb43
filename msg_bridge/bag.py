"""rosbag2 MCAP bags through rosbags, with the project's custom message types registered.

* A BAG path is either a rosbag2 directory (with ``metadata.yaml``) or a single ``.mcap`` file
  (contract, "Command line"); both read the same way.
* :class:`BagWriter` writes rosbag2 MCAP (``version=9``) with zstd *chunk* compression or none,
  never rosbags' per-message compression (other MCAP readers cannot read that). A path ending in
  ``.mcap`` becomes a single MCAP file (no ``metadata.yaml``; ``ros2 bag`` and rosbags read it
  directly); any other path becomes a rosbag2 directory. Bags carry no wall-clock time: writing
  the same messages with the same log times gives byte-identical files.
* A truncated or corrupt bag raises :class:`BagError`, naming the file and saying what was
  readable before the damage.

The typestore is ROS 2 Jazzy's plus ``grid_map_msgs`` and ``roadbev_msgs`` from their ``.msg``
files (the repository's ``interfaces/`` or an installed ``share/<package>/msg``).
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from collections import Counter
from collections.abc import Iterable, Iterator
from contextlib import suppress
from functools import lru_cache
from pathlib import Path
from types import TracebackType
from typing import Any, NamedTuple

from msg_bridge._common import MessageError

__all__ = [
    "CUSTOM_PACKAGES",
    "BagError",
    "BagMessage",
    "BagWriter",
    "TopicInfo",
    "bag_topics",
    "deserialize",
    "read_messages",
    "serialize",
    "typestore",
]

CUSTOM_PACKAGES = ("grid_map_msgs", "roadbev_msgs")
COMPRESSIONS = ("zstd", "none")


class BagError(ValueError):
    """A bag that cannot be read or written; names the file and what went wrong."""


def _interface_dirs(package: str) -> list[Path]:
    """Places that may hold ``<package>/msg/*.msg``, most specific first."""
    candidates = [Path(__file__).resolve().parents[1] / "interfaces" / package]
    prefixes = [sys.prefix, *os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)]
    candidates += [Path(p) / "share" / package for p in prefixes if p]
    return [c for c in candidates if (c / "msg").is_dir()]


@lru_cache(maxsize=1)
def typestore() -> Any:
    """The rosbags typestore: ROS 2 Jazzy + ``grid_map_msgs`` + ``roadbev_msgs``."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict[str, Any] = {}
    for package in CUSTOM_PACKAGES:
        dirs = _interface_dirs(package)
        if not dirs:
            raise BagError(f"cannot find the .msg files of {package} (interfaces/ or share/)")
        for path in sorted((dirs[0] / "msg").glob("*.msg")):
            types.update(get_types_from_msg(path.read_text(), f"{package}/msg/{path.stem}"))
    store.register(types)
    return store


def serialize(msg: Any, msgtype: str | None = None) -> bytes:
    """CDR bytes of a typestore message (as rclpy and ``ros2 bag`` write them)."""
    store = typestore()
    return bytes(store.serialize_cdr(msg, msgtype or msg.__msgtype__))


def deserialize(data: bytes | memoryview, msgtype: str) -> Any:
    """A typestore message from CDR bytes.

    Raises:
        MessageError: unknown type or bytes that are not a CDR ``msgtype``.
    """
    store = typestore()
    if msgtype not in store.types:
        raise MessageError(f"unknown message type {msgtype!r}")
    try:
        return store.deserialize_cdr(data, msgtype)
    except Exception as exc:  # rosbags raises struct/index/value errors on bad bytes
        raise MessageError(f"{len(data)} bytes are not a valid {msgtype}: {exc!r}") from None


def _qos(latched: bool) -> list[Any]:
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )

    durability = QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE
    zero = QosTime(0, 0)
    return [
        Qos(
            QosHistory.KEEP_LAST,
            1 if latched else 10,
            QosReliability.RELIABLE,
            durability,
            zero,
            zero,
            QosLiveliness.AUTOMATIC,
            zero,
            False,
        )
    ]


class BagWriter:
    """Writes a rosbag2 MCAP bag; use as a context manager.

    Args:
        path: ``*.mcap`` for a single MCAP file, anything else for a rosbag2 directory. Must
            not exist yet.
        compression: "zstd" (chunk compression) or "none".

    Example::

        with BagWriter("drive.mcap") as bag:
            bag.add_topic("/imu/data", "sensor_msgs/msg/Imu")
            bag.write("/imu/data", imu_msg, stamp_ns)
    """

    def __init__(self, path: str | os.PathLike[str], *, compression: str = "zstd") -> None:
        if compression not in COMPRESSIONS:
            raise BagError(f"compression must be one of {COMPRESSIONS}, got {compression!r}")
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f"{self.path} exists already; not overwriting it")
        if not self.path.parent.is_dir():
            raise BagError(f"{self.path.parent} is not a directory")
        self.compression = compression
        self.single_file = self.path.suffix == ".mcap"
        self._tmp: Path | None = None
        self._writer: Any = None
        self._connections: dict[str, Any] = {}
        self.counts: Counter[str] = Counter()

    def __enter__(self) -> BagWriter:
        self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def open(self) -> None:
        from rosbags.rosbag2 import Writer
        from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin

        if self.single_file:
            # rosbags writes a directory; write it next to the target, keep only the .mcap.
            self._tmp = Path(tempfile.mkdtemp(prefix=".bagwriter-", dir=self.path.parent))
            target = self._tmp / self.path.stem
        else:
            target = self.path
        writer = Writer(target, version=9, storage_plugin=StoragePlugin.MCAP)
        if self.compression == "zstd":
            writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        writer.open()
        self._writer = writer

    def add_topic(self, topic: str, msgtype: str, *, latched: bool = False) -> None:
        """Declare a topic (``latched``: transient-local durability, as a latched publisher)."""
        if self._writer is None:
            raise BagError(f"{self.path}: the bag is not open")
        if topic in self._connections:
            raise BagError(f"{self.path}: topic {topic} was added twice")
        store = typestore()
        if msgtype not in store.types:
            raise BagError(f"{self.path}: unknown message type {msgtype!r} for {topic}")
        self._connections[topic] = self._writer.add_connection(
            topic, msgtype, typestore=store, offered_qos_profiles=_qos(latched)
        )

    def write(self, topic: str, msg: Any, log_time_ns: int) -> None:
        """Serialise a typestore message and write it with the given log time."""
        connection = self._connection(topic)
        self.write_raw(topic, serialize(msg, connection.msgtype), log_time_ns)

    def write_raw(self, topic: str, data: bytes | memoryview, log_time_ns: int) -> None:
        """Write already serialised CDR bytes (e.g. from a raw subscription)."""
        self._writer.write(self._connection(topic), int(log_time_ns), data)
        self.counts[topic] += 1

    def _connection(self, topic: str) -> Any:
        if topic not in self._connections:
            raise BagError(f"{self.path}: topic {topic} was not added")
        return self._connections[topic]

    def close(self) -> None:
        if self._writer is None:
            return
        writer, self._writer = self._writer, None
        writer.close()
        if self._tmp is not None:
            produced = self._tmp / self.path.stem / f"{self.path.stem}.mcap"
            produced.replace(self.path)
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None

    def abort(self) -> None:
        """Drop everything written (after an error)."""
        if self._writer is not None:
            writer, self._writer = self._writer, None
            with suppress(Exception):  # the original error matters, not this one
                writer.abort()
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None
        elif self.path.is_dir() and not self.single_file:
            shutil.rmtree(self.path, ignore_errors=True)


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


def _check_path(path: Path) -> None:
    if not path.exists():
        raise BagError(f"{path}: no such bag (file or rosbag2 directory)")
    if path.is_dir() and not (path / "metadata.yaml").exists():
        mcaps = sorted(path.glob("*.mcap"))
        hint = f"; give the file instead, e.g. {mcaps[0]}" if mcaps else ""
        raise BagError(f"{path}: a directory without metadata.yaml is not a rosbag2 bag{hint}")
    if path.is_file() and path.suffix != ".mcap":
        raise BagError(f"{path}: not an .mcap file or a rosbag2 directory")


def _mcap_files(path: Path) -> list[Path]:
    return [path] if path.is_file() else sorted(path.glob("*.mcap"))


_MAGIC = b"\x89MCAP0\r\n"
_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 0x03, 0x04, 0x05, 0x06


def _records(buf: bytes, pos: int = 0) -> Iterator[tuple[int, bytes]]:
    """``(opcode, body)`` of the whole MCAP records in ``buf`` from ``pos`` (and a cut chunk)."""
    while pos + 9 <= len(buf):
        opcode = buf[pos]
        length = int.from_bytes(buf[pos + 1 : pos + 9], "little")
        body = buf[pos + 9 : pos + 9 + length]
        if len(body) < length:
            if opcode == _OP_CHUNK:  # a cut chunk still holds the records before the cut
                yield opcode, body
            return
        yield opcode, body
        pos += 9 + length


def _chunk_records(body: bytes) -> bytes:
    """The (possibly partial) uncompressed records of a (possibly cut) Chunk record body."""
    import zstandard

    # start time u64, end time u64, uncompressed size u64, crc u32, compression str, length u64
    if len(body) < 32:
        return b""
    n = int.from_bytes(body[28:32], "little")
    compression = body[32 : 32 + n].decode("utf-8", "replace")
    records = body[32 + n + 8 :]
    if compression == "":
        return records
    if compression == "zstd":
        try:
            return zstandard.ZstdDecompressor().decompressobj().decompress(records)
        except zstandard.ZstdError:
            return b""
    return b""


def _salvage(path: Path) -> str:
    """What a forward scan of the MCAP file(s) can still read: '<n> messages (topic: count...)'.

    Walks the records by hand (the MCAP readers give up on the first cut chunk) and counts the
    messages that are complete, also inside a cut or damaged chunk.
    """
    counts: Counter[str] = Counter()
    for file in _mcap_files(path):
        buf = file.read_bytes()
        if not buf.startswith(_MAGIC):
            continue
        channels: dict[int, str] = {}

        def visit(opcode: int, body: bytes, channels: dict[int, str] = channels) -> None:
            if opcode == _OP_CHANNEL and len(body) >= 8:
                n = int.from_bytes(body[4:8], "little")
                channels[int.from_bytes(body[0:2], "little")] = body[8 : 8 + n].decode("utf-8", "replace")
            elif opcode == _OP_MESSAGE and len(body) >= 22:
                counts[channels.get(int.from_bytes(body[0:2], "little"), "?")] += 1

        for opcode, body in _records(buf, len(_MAGIC)):
            if opcode == _OP_CHUNK:
                inner = _chunk_records(body)
                for inner_opcode, inner_body in _records(inner):
                    visit(inner_opcode, inner_body)
            else:
                visit(opcode, body)
    total = sum(counts.values())
    detail = ", ".join(f"{topic}: {n}" for topic, n in sorted(counts.items()))
    return f"{total} message(s) readable before the damage" + (f" ({detail})" if detail else "")


def _open_reader(path: Path) -> Any:
    from rosbags.rosbag2 import Reader

    _check_path(path)
    reader = Reader(path)
    try:
        reader.open()
    except Exception as exc:  # rosbags raises many kinds on a damaged file
        raise BagError(f"{path}: truncated or corrupt bag ({exc}); {_salvage(path)}") from None
    return reader


def bag_topics(path: str | os.PathLike[str]) -> dict[str, TopicInfo]:
    """Topics of a bag with their types and message counts (from the index; no decoding)."""
    path = Path(path)
    reader = _open_reader(path)
    try:
        counts: Counter[str] = Counter()
        types: dict[str, str] = {}
        for connection in reader.connections:
            counts[connection.topic] += connection.msgcount
            types[connection.topic] = connection.msgtype
        return {t: TopicInfo(types[t], counts[t]) for t in sorted(types)}
    finally:
        reader.close()


def _ensure_types(connections: Iterable[Any]) -> None:
    """Register message types a bag brings along that the typestore does not know yet."""
    from rosbags.typesys import get_types_from_idl, get_types_from_msg

    store = typestore()
    new: dict[str, Any] = {}
    for c in connections:
        if c.msgtype in store.types or c.msgtype in new or not c.msgdef.data:
            continue
        try:
            if c.msgdef.format.name == "IDL":
                new.update(get_types_from_idl(c.msgdef.data))
            else:
                new.update(get_types_from_msg(c.msgdef.data, c.msgtype))
        except Exception as exc:
            raise BagError(f"type {c.msgtype} of {c.topic} has an unreadable definition: {exc}") from None
    if new:
        store.register(new)


def read_messages(
    path: str | os.PathLike[str],
    topics: Iterable[str] | None = None,
    *,
    raw: bool = False,
) -> Iterator[BagMessage]:
    """The messages of a bag in log-time order, decoded (typestore objects) or raw CDR bytes.

    Args:
        path: a rosbag2 directory or an ``.mcap`` file.
        topics: only these topics (all when None).
        raw: yield the serialised bytes instead of decoding them.

    Raises:
        BagError: the bag cannot be opened, or it breaks off while reading (the error says how
            many messages per topic were read before).
    """
    path = Path(path)
    wanted = None if topics is None else set(topics)
    reader = _open_reader(path)
    counts: Counter[str] = Counter()
    try:
        connections = [c for c in reader.connections if wanted is None or c.topic in wanted]
        if not raw:
            _ensure_types(connections)
        store = typestore()
        messages = reader.messages(connections=connections) if connections else iter(())
        while True:
            try:
                connection, log_time, data = next(messages)
            except StopIteration:
                break
            except Exception as exc:
                done = ", ".join(f"{t}: {n}" for t, n in sorted(counts.items())) or "none"
                raise BagError(
                    f"{path}: bag breaks off after {sum(counts.values())} message(s) ({done}): {exc}"
                ) from None
            if raw:
                msg = data
            else:
                try:
                    msg = store.deserialize_cdr(data, connection.msgtype)
                except Exception as exc:
                    raise BagError(
                        f"{path}: message {counts[connection.topic] + 1} on {connection.topic} is "
                        f"not a valid {connection.msgtype}: {exc!r}"
                    ) from None
            counts[connection.topic] += 1
            yield BagMessage(connection.topic, connection.msgtype, int(log_time), msg)
    finally:
        reader.close()
