"""rosbag2 MCAP bags: writing, CRC-checked reading, partial reads of damaged bags, recovery.

* A BAG path is either a rosbag2 directory (with ``metadata.yaml``) or a single ``.mcap`` file
  (contract, "Command line"); both read the same way.
* :class:`BagWriter` writes rosbag2 MCAP (version 9 metadata) through the ``mcap`` writer, with
  zstd *chunk* compression or none, a CRC-32 on every chunk and on the summary. A path ending in
  ``.mcap`` becomes a single MCAP file (no ``metadata.yaml``; ``ros2 bag`` and rosbags read it
  directly); any other path becomes a rosbag2 directory. The file is written in place from the
  start: every finished chunk is in the file (and, with ``flush(fsync=True)``, on the disk), so a
  writer killed mid-way leaves a bag that is readable up to its last complete chunk. While the
  writer is open a marker ``<bag>.recording`` lies next to the bag (it also keeps the channel
  definitions); :meth:`BagWriter.close` removes it. Bags carry no wall-clock time: writing the
  same messages with the same log times gives byte-identical files.
* Reading (:func:`read_messages`) goes through :mod:`msg_bridge.mcap_file`, which checks every
  chunk before using it (size, CRC, record structure, and the message index where a writer
  stored no CRC). ``on_damage="raise"`` (the default) raises :class:`DamagedBagError` naming the
  file and the chunk; ``on_damage="skip"`` skips the damaged chunk, and the :class:`ReadStats`
  passed in counts what was lost, per topic and why. A truncated or unfinished bag is read up to
  its last complete chunk with ``"skip"``; with ``"raise"`` it is refused at once, saying what is
  readable.
* :func:`bag_info` says what a bag holds and whether it was closed cleanly;
  :func:`recover_bag` writes a complete, indexed copy of everything readable in a bag.

The typestore is ROS 2 Jazzy's plus ``grid_map_msgs`` and ``roadbev_msgs`` from their ``.msg``
files (the repository's ``interfaces/`` or an installed ``share/<package>/msg``).
"""

from __future__ import annotations

import json
import os
import shutil
import sys
from collections import Counter
from collections.abc import Iterable, Iterator, Mapping
from contextlib import suppress
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from types import TracebackType
from typing import Any, Literal, NamedTuple

from msg_bridge._common import MessageError
from msg_bridge.mcap_file import (
    Channel,
    Damage,
    FileScan,
    McapFormatError,
    Schema,
    iter_messages,
    load_chunk,
    scan_file,
)
from roadbev_core.errors import RoadbevError

__all__ = [
    "CUSTOM_PACKAGES",
    "MARKER_SUFFIX",
    "BagError",
    "BagInfo",
    "BagMessage",
    "BagWriter",
    "DamagedBagError",
    "ReadStats",
    "TopicInfo",
    "bag_info",
    "bag_topics",
    "deserialize",
    "marker_path",
    "read_messages",
    "recover_bag",
    "serialize",
    "typestore",
]

CUSTOM_PACKAGES = ("grid_map_msgs", "roadbev_msgs")
COMPRESSIONS = ("zstd", "none")
MARKER_SUFFIX = ".recording"
DEFAULT_CHUNK_SIZE = 1 << 20
OnDamage = Literal["raise", "skip"]


class BagError(RoadbevError, ValueError):
    """A bag that cannot be read or written; names the file and what went wrong."""


class DamagedBagError(BagError):
    """A bag with a damaged, cut or unfinished part, met while reading with ``on_damage="raise"``.

    Attributes:
        damage: the damaged part(s), as lines naming the file, the chunk and the reason.
    """

    def __init__(self, message: str, damage: list[str]) -> None:
        super().__init__(message)
        self.damage = damage


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


def marker_path(path: str | os.PathLike[str]) -> Path:
    """The ``<bag>.recording`` marker that lies next to a bag while its writer is open."""
    path = Path(path)
    return path.with_name(path.name + MARKER_SUFFIX)


def _schema_of(msgtype: str) -> tuple[str, bytes]:
    """(encoding, data) of the MCAP schema for ``msgtype``, as ``ros2 bag`` writes it."""
    text, _digest = typestore().generate_msgdef(msgtype, ros_version=2)
    encoding = "ros2idl" if text.startswith("=" * 80 + "\nIDL: ") else "ros2msg"
    return encoding, text.encode()


def _qos_text(latched: bool) -> str:
    """``offered_qos_profiles`` as rosbag2 (format 9) stores it in the channel metadata."""
    import yaml
    from rosbags.rosbag2.metadata import dump_qos_v9

    return yaml.safe_dump(dump_qos_v9(_qos(latched)), default_flow_style=False, sort_keys=False).strip()


class _FileStream:
    """An unbuffered, exclusive-create output file for the ``mcap`` writer.

    Every ``write`` goes to the operating system at once (the ``mcap`` writer writes a whole
    chunk record per call), so a process killed after a chunk was written has it in the file.
    """

    def __init__(self, path: Path) -> None:
        self.fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        self.position = 0

    def write(self, data: bytes | bytearray | memoryview) -> int:
        view = memoryview(data)
        while view:
            n = os.write(self.fd, view)
            view = view[n:]
            self.position += n
        return len(data)

    def tell(self) -> int:
        return self.position

    def flush(self) -> None:
        """Nothing is buffered here."""

    def fsync(self) -> None:
        os.fsync(self.fd)

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1


class _Topic(NamedTuple):
    channel_id: int
    msgtype: str
    digest: str
    qos: str


class BagWriter:
    """Writes a rosbag2 MCAP bag with real chunk CRCs; use as a context manager.

    Args:
        path: ``*.mcap`` for a single MCAP file, anything else for a rosbag2 directory. Must
            not exist yet.
        compression: "zstd" (chunk compression) or "none".
        chunk_size: uncompressed bytes after which a chunk is finished and written; smaller
            chunks lose less in a crash (see :meth:`flush` for a time bound).

    Example::

        with BagWriter("drive.mcap") as bag:
            bag.add_topic("/imu/data", "sensor_msgs/msg/Imu")
            bag.write("/imu/data", imu_msg, stamp_ns)
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        compression: str = "zstd",
        chunk_size: int = DEFAULT_CHUNK_SIZE,
    ) -> None:
        if compression not in COMPRESSIONS:
            raise BagError(f"compression must be one of {COMPRESSIONS}, got {compression!r}")
        if chunk_size < 1:
            raise BagError(f"chunk_size must be >= 1, got {chunk_size}")
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f"{self.path} exists already; not overwriting it")
        if not self.path.parent.is_dir():
            raise BagError(f"{self.path.parent} is not a directory")
        self.compression = compression
        self.chunk_size = chunk_size
        self.single_file = self.path.suffix == ".mcap"
        self.file = self.path if self.single_file else self.path / f"{self.path.name}.mcap"
        self.marker = marker_path(self.path)
        self._stream: _FileStream | None = None
        self._writer: Any = None
        self._topics: dict[str, _Topic] = {}
        self._channels: list[dict[str, Any]] = []  # for the marker
        self._channel_counts: Counter[int] = Counter()
        self._times: list[int] = []  # [first, last] log time
        self._unflushed = 0
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
        from mcap.writer import CompressionType, Writer

        if self.marker.exists() and not self.path.exists():
            self.marker.unlink()  # left by a writer that died before writing anything
        if not self.single_file:
            try:
                self.path.mkdir()
            except FileExistsError:
                raise BagError(f"{self.path} exists already; not overwriting it") from None
        self._write_marker()
        try:
            self._stream = _FileStream(self.file)
        except FileExistsError:
            raise BagError(f"{self.file} exists already; not overwriting it") from None
        compression = CompressionType.ZSTD if self.compression == "zstd" else CompressionType.NONE
        stream: Any = self._stream  # the writer needs write/tell/flush only
        self._writer = Writer(stream, chunk_size=self.chunk_size, compression=compression, enable_crcs=True)
        self._writer.start(profile="ros2", library=_library())

    def _write_marker(self) -> None:
        text = json.dumps({"bag": self.path.name, "file": self.file.name, "channels": self._channels})
        tmp = self.marker.with_name(self.marker.name + ".tmp")
        tmp.write_text(text)
        tmp.replace(self.marker)

    def add_topic(self, topic: str, msgtype: str, *, latched: bool = False) -> None:
        """Declare a topic (``latched``: transient-local durability, as a latched publisher)."""
        if self._writer is None:
            raise BagError(f"{self.path}: the bag is not open")
        if topic in self._topics:
            raise BagError(f"{self.path}: topic {topic} was added twice")
        store = typestore()
        if msgtype not in store.types:
            raise BagError(f"{self.path}: unknown message type {msgtype!r} for {topic}")
        encoding, data = _schema_of(msgtype)
        channel_id = self.add_channel(topic, msgtype, encoding, data, {"offered_qos_profiles": _qos_text(latched)},
                                      digest=store.hash_rihs01(msgtype))
        self._topics[topic] = self._topics[topic]._replace(channel_id=channel_id)

    def add_channel(
        self,
        topic: str,
        msgtype: str,
        schema_encoding: str,
        schema_data: bytes,
        metadata: Mapping[str, str],
        *,
        message_encoding: str = "cdr",
        digest: str = "",
    ) -> int:
        """Declare a channel with a given schema (e.g. copied from another bag); returns its id.

        The first channel of a topic is the one :meth:`write` and :meth:`write_raw` use.
        """
        if self._writer is None:
            raise BagError(f"{self.path}: the bag is not open")
        schema_id = self._writer.register_schema(msgtype, schema_encoding, bytes(schema_data))
        channel_id = int(self._writer.register_channel(topic, message_encoding, schema_id, dict(metadata)))
        self._topics.setdefault(topic, _Topic(channel_id, msgtype, digest, metadata.get("offered_qos_profiles", "")))
        schema = {"name": msgtype, "encoding": schema_encoding, "data": bytes(schema_data).decode("utf-8", "replace")}
        self._channels.append({"id": channel_id, "topic": topic, "message_encoding": message_encoding,
                               "metadata": dict(metadata), "schema": schema})
        self._write_marker()
        return channel_id

    def write(self, topic: str, msg: Any, log_time_ns: int) -> None:
        """Serialise a typestore message and write it with the given log time."""
        info = self._topic(topic)
        self.write_raw(topic, serialize(msg, info.msgtype), log_time_ns)

    def write_raw(self, topic: str, data: bytes | memoryview, log_time_ns: int) -> None:
        """Write already serialised CDR bytes (e.g. from a raw subscription)."""
        self.write_channel(self._topic(topic).channel_id, data, log_time_ns)
        self.counts[topic] += 1

    def write_channel(self, channel_id: int, data: bytes | memoryview, log_time_ns: int,
                      publish_time_ns: int | None = None, sequence: int = 0) -> None:
        """Write serialised bytes on a channel from :meth:`add_channel`."""
        if self._writer is None:
            raise BagError(f"{self.path}: the bag is not open")
        log_time = int(log_time_ns)
        self._writer.add_message(channel_id, log_time, bytes(data),
                                 log_time if publish_time_ns is None else int(publish_time_ns), sequence)
        self._channel_counts[channel_id] += 1
        self._times = [min(self._times[0], log_time), max(self._times[1], log_time)] if self._times else [log_time] * 2
        self._unflushed += 1

    @property
    def pending(self) -> int:
        """Messages written since the last :meth:`flush` (some may be in finished chunks already)."""
        return self._unflushed

    def flush(self, *, fsync: bool = False) -> None:
        """Finish the chunk in progress and write it (``fsync``: and make the file durable)."""
        if self._writer is None or self._stream is None:
            return
        self._writer.flush()
        if fsync:
            self._stream.fsync()
        self._unflushed = 0

    def _topic(self, topic: str) -> _Topic:
        if topic not in self._topics:
            raise BagError(f"{self.path}: topic {topic} was not added")
        return self._topics[topic]

    def close(self) -> None:
        """Write the summary and footer, make the file durable and remove the marker."""
        if self._writer is None or self._stream is None:
            return
        writer, self._writer = self._writer, None
        stream, self._stream = self._stream, None
        info = self._bag_information()
        try:
            writer.flush()
            writer.add_metadata("rosbag2", {"serialized_metadata": _yaml(info)})
            writer.finish()
            stream.fsync()
        finally:
            stream.close()
        if not self.single_file:
            tmp = self.path / "metadata.yaml.tmp"
            tmp.write_text(_yaml({"rosbag2_bagfile_information": info}))
            tmp.replace(self.path / "metadata.yaml")
        with suppress(FileNotFoundError):
            self.marker.unlink()

    def _bag_information(self) -> dict[str, Any]:
        start, end = self._times if self._times else (0, 0)
        count = sum(self._channel_counts.values())
        topics = []
        for c in self._channels:
            info = self._topics.get(c["topic"])
            qos = c["metadata"].get("offered_qos_profiles", "")
            topics.append({
                "topic_metadata": {
                    "name": c["topic"],
                    "type": c["schema"]["name"],
                    "serialization_format": c["message_encoding"],
                    "offered_qos_profiles": _qos_list(qos),
                    "type_description_hash": info.digest if info is not None and info.channel_id == c["id"] else "",
                },
                "message_count": self._channel_counts[c["id"]],
            })
        window = {"starting_time": {"nanoseconds_since_epoch": start}, "duration": {"nanoseconds": end - start}}
        return {
            "version": 9,
            "storage_identifier": "mcap",
            "relative_file_paths": [self.file.name],
            **window,
            "message_count": count,
            "topics_with_message_count": topics,
            "compression_format": "",
            "compression_mode": "",
            "files": [{"path": self.file.name, **window, "message_count": count}],
            "custom_data": None,
            "ros_distro": "roadbev",
        }

    def abort(self) -> None:
        """Drop everything written (after an error)."""
        if self._stream is not None:
            self._stream.close()
        self._writer, self._stream = None, None
        if self.single_file:
            with suppress(FileNotFoundError):
                self.path.unlink()
        elif self.path.is_dir():
            shutil.rmtree(self.path, ignore_errors=True)
        with suppress(FileNotFoundError):
            self.marker.unlink()


def _library() -> str:
    from mcap.writer import LIBRARY_IDENTIFIER

    return f"roadbev msg_bridge.bag ({LIBRARY_IDENTIFIER})"


def _yaml(value: Any) -> str:
    import yaml

    return yaml.safe_dump(value, default_flow_style=False, sort_keys=False)


def _qos_list(text: str) -> Any:
    import yaml

    try:
        return yaml.safe_load(text) if text else []
    except yaml.YAMLError:
        return []


# ------------------------------------------------------------------------------------------------
# reading
# ------------------------------------------------------------------------------------------------
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


@dataclass
class ReadStats:
    """What a read delivered and what it lost (filled by :func:`read_messages`).

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


def _check_path(path: Path) -> None:
    if not path.exists():
        raise BagError(f"{path}: no such bag (file or rosbag2 directory)")
    if path.is_dir() and not (path / "metadata.yaml").exists() and not any(path.glob("*.mcap")):
        raise BagError(f"{path}: a directory without metadata.yaml or .mcap files is not a rosbag2 bag")
    if path.is_file() and path.suffix != ".mcap":
        raise BagError(f"{path}: not an .mcap file or a rosbag2 directory")


def _metadata(path: Path) -> dict[str, Any] | None:
    import yaml

    meta = path / "metadata.yaml"
    if not meta.is_file():
        return None
    try:
        info = yaml.safe_load(meta.read_text(encoding="utf-8"))["rosbag2_bagfile_information"]
    except UnicodeDecodeError as exc:
        raise BagError(f"{meta}: not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    except (yaml.YAMLError, KeyError, TypeError) as exc:
        flat = " ".join(line.strip() for line in str(exc).splitlines() if line.strip())
        raise BagError(f"{meta}: not a rosbag2 metadata file ({flat})") from None
    if not isinstance(info, dict):
        raise BagError(f"{meta}: not a rosbag2 metadata file")
    return info


def _mcap_files(path: Path) -> list[Path]:
    if path.is_file():
        return [path]
    meta = _metadata(path)
    if meta is not None:
        storage = str(meta.get("storage_identifier", "mcap"))
        if storage != "mcap":
            raise BagError(f"{path}: storage {storage!r} is not supported (only MCAP bags)")
        names = [Path(str(p)).name for p in meta.get("relative_file_paths", [])]
        files = [path / n for n in names if (path / n).is_file()]
        missing = [n for n in names if not (path / n).is_file()]
        if missing:
            raise BagError(f"{path}: files listed in metadata.yaml are missing: {', '.join(missing)}")
        if files:
            return files
    return sorted(path.glob("*.mcap"))


@dataclass
class _Bag:
    """The scanned files of a bag and every channel known so far."""

    path: Path
    scans: list[FileScan]
    schemas: dict[tuple[Path, int], Schema]
    channels: dict[tuple[Path, int], Channel]
    marker: bool

    @property
    def closed(self) -> bool:
        return not self.marker and all(s.closed for s in self.scans)

    def add(self, scan: FileScan, schemas: Iterable[Schema], channels: Iterable[Channel]) -> None:
        for s in schemas:
            self.schemas.setdefault((scan.path, s.id), s)
        for c in channels:
            self.channels.setdefault((scan.path, c.id), c)

    def topic(self, scan: FileScan, channel_id: int) -> str | None:
        channel = self.channels.get((scan.path, channel_id))
        return None if channel is None else channel.topic

    def msgtype(self, scan: FileScan, channel_id: int) -> str:
        channel = self.channels[(scan.path, channel_id)]
        schema = self.schemas.get((scan.path, channel.schema_id))
        return schema.name if schema is not None else ""

    def describe(self, damage: Damage) -> tuple[str, Counter[str]]:
        """A line naming the damaged part and what it cost, and the loss per topic."""
        lost: Counter[str] = Counter()
        scan_path = damage.file
        for cid, n in damage.lost.items():
            channel = self.channels.get((scan_path, cid))
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

    def ensure_channels(self) -> None:
        """Load chunks until every channel an index mentions is defined (an unfinished bag has
        its channel definitions inside its chunks only)."""
        for scan in self.scans:
            wanted = {cid for chunk in scan.chunks for cid in chunk.index} | set(scan.statistics or {})
            missing = {cid for cid in wanted if (scan.path, cid) not in self.channels}
            if not missing and (wanted or not scan.chunks):
                continue
            for chunk in scan.chunks:
                if chunk.cut:
                    continue
                content, _damage = load_chunk(chunk)
                if content is not None:
                    self.add(scan, content.schemas, content.channels)
                missing = {cid for cid in wanted if (scan.path, cid) not in self.channels}
                if wanted and not missing:
                    break


def _marker_channels(path: Path, bag: _Bag) -> bool:
    """Channel definitions from a ``.recording`` marker; whether there is one."""
    marker = marker_path(path)
    if not marker.is_file():
        return False
    try:
        content = json.loads(marker.read_text())
        file_name = str(content.get("file", path.name))
        scan = next((s for s in bag.scans if s.path.name == file_name), None)
        if scan is not None:
            for c in content.get("channels", []):
                schema = c["schema"]
                bag.add(scan, [Schema(int(c["id"]), str(schema["name"]), str(schema["encoding"]),
                                      str(schema["data"]).encode())],
                        [Channel(int(c["id"]), int(c["id"]), str(c["topic"]), str(c["message_encoding"]),
                                 {str(k): str(v) for k, v in dict(c["metadata"]).items()})])
    except (ValueError, KeyError, TypeError, AttributeError):
        pass  # a marker from elsewhere, or cut itself: it still says the bag is unfinished
    return True


def _open_bag(path: Path) -> _Bag:
    _check_path(path)
    scans: list[FileScan] = []
    for file in _mcap_files(path):
        try:
            scan = scan_file(file)
        except McapFormatError as exc:
            raise BagError(f"{file}: {exc}") from None
        except OSError as exc:
            raise BagError(f"{file}: cannot read: {exc}") from None
        if not scan.profile and not scan.chunks and not scan.loose:
            reason = "; ".join(d.reason for d in scan.damage) or "no records"
            raise BagError(f"{file}: truncated or corrupt bag, nothing readable ({reason})")
        scans.append(scan)
    if not scans:
        raise BagError(f"{path}: no .mcap files")
    # Schemas and channels, as the writer left them: outside chunks or in the summary; by index
    # ids, so that the summary's copies serve when the chunk that held them is damaged.
    bag = _Bag(path, scans, {}, {}, False)
    for scan in scans:
        bag.add(scan, scan.schemas.values(), scan.channels.values())
    bag.marker = _marker_channels(path, bag)
    return bag


def _salvage(bag: _Bag) -> str:
    """What can still be read: '<n> messages in complete chunks (topic: count...)', by the index."""
    bag.ensure_channels()
    counts: Counter[str] = Counter()
    for scan in bag.scans:
        for chunk in scan.chunks:
            if not chunk.cut:
                for cid, n in chunk.indexed_counts.items():
                    counts[bag.topic(scan, cid) or f"channel {cid}"] += n
        for cid, n in Counter(_loose_channel(scan, o) for _t, o, _n in scan.loose).items():
            counts[bag.topic(scan, cid) or f"channel {cid}"] += n
    total = sum(counts.values())
    detail = ", ".join(f"{topic}: {n}" for topic, n in sorted(counts.items()))
    return f"{total} message(s) readable before the damage" + (f" ({detail})" if detail else "")


def _loose_channel(scan: FileScan, offset: int) -> int:
    with scan.path.open("rb") as stream:
        stream.seek(offset + 9)
        return int.from_bytes(stream.read(2), "little")


def bag_topics(path: str | os.PathLike[str]) -> dict[str, TopicInfo]:
    """Topics of a bag with their types and message counts (from the index; no decoding).

    An unfinished or damaged bag gives the topics and counts of its complete chunks.
    """
    bag = _open_bag(Path(path))
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
            per_channel.update(_loose_channel(scan, o) for _t, o, _n in scan.loose)
        for cid, n in per_channel.items():
            topic = bag.topic(scan, cid)
            if topic is not None:
                counts[topic] += n
    return {t: TopicInfo(types[t], counts[t]) for t in sorted(types)}


def _ensure_types(bag: _Bag, msgtypes: Iterable[tuple[FileScan, int]]) -> None:
    """Register message types a bag brings along that the typestore does not know yet."""
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
    bag = _open_bag(path)
    stats.unfinished = stats.unfinished or not bag.closed
    scan_damage = [d for s in bag.scans for d in s.damage]
    if on_damage == "raise" and any(not d.kept for d in scan_damage):
        lines = [bag.describe(d)[0] for d in scan_damage if not d.kept]
        raise DamagedBagError(f"{path}: truncated or corrupt bag ({lines[0]}); {_salvage(bag)}; "
                              "`roadbev bag recover` copies what is readable", lines)
    if on_damage == "raise" and not bag.closed:
        why = "a .recording marker is left" if bag.marker else "it has no summary/footer"
        line = f"{path}: the bag was not closed cleanly ({why}): its end may be missing"
        raise DamagedBagError(f"{line}; {_salvage(bag)}; `roadbev bag recover` makes a complete copy", [line])
    for damage in scan_damage:
        _count_damage(bag, damage, stats, wanted)
    stats.unverified_chunks += sum(1 for s in bag.scans for c in s.chunks if c.crc == 0 and not c.cut)
    store = typestore()
    registered: set[tuple[Path, int]] = set()

    def on_chunk_damage(damage: Damage) -> None:
        line = _count_damage(bag, damage, stats, wanted)
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
                stats.lost[f"channel {message.channel_id}"] += 1
                _note(stats, f"{scan.path.name}: messages on channel {message.channel_id}, whose definition is lost")
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
                _note(stats, line)
                continue
        stats.read[channel.topic] += 1
        yield BagMessage(channel.topic, msgtype, int(message.log_time_ns), msg)


def _note(stats: ReadStats, line: str) -> None:
    if line not in stats.damage:
        stats.damage.append(line)


def _count_damage(bag: _Bag, damage: Damage, stats: ReadStats, wanted: set[str] | None) -> str:
    line, lost = bag.describe(damage)
    if not damage.kept:
        for topic, n in lost.items():
            if wanted is None or topic in wanted:
                stats.lost[topic] += n
        stats.lost_unknown = stats.lost_unknown or damage.lost_unknown
    _note(stats, line)
    return line


# ------------------------------------------------------------------------------------------------
# info and recovery
# ------------------------------------------------------------------------------------------------
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
    bag = _open_bag(path)
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
        for damage in (d for s in bag.scans for d in s.damage):
            _count_damage(bag, damage, stats, None)
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
    are left out and counted. ``out`` (``.mcap`` or a directory) must not exist.

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
    bag = _open_bag(path)
    stats = ReadStats()
    for damage in (d for s in bag.scans for d in s.damage):
        _count_damage(bag, damage, stats, None)
    stats.unverified_chunks = sum(1 for s in bag.scans for c in s.chunks if c.crc == 0 and not c.cut)
    ids: dict[tuple[Path, int], int] = {}

    def on_chunk_damage(damage: Damage) -> None:
        _count_damage(bag, damage, stats, None)

    with BagWriter(out, compression=compression) as writer:
        for scan, message in iter_messages(bag.scans, on_damage=on_chunk_damage, on_channels=bag.add):
            key = (scan.path, message.channel_id)
            channel = bag.channels.get(key)
            if channel is None:
                stats.lost[f"channel {message.channel_id}"] += 1
                _note(stats, f"{scan.path.name}: messages on channel {message.channel_id}, whose definition is lost")
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
    store = typestore()
    try:
        return str(store.hash_rihs01(msgtype)) if msgtype in store.types else ""
    except Exception:  # a type the store holds but cannot hash (a foreign definition)
        return ""
