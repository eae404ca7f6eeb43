"""Writing rosbag2 MCAP bags: :class:`BagWriter`.

The writer writes rosbag2 MCAP (version 9 metadata) through the ``mcap`` writer, with zstd *chunk*
compression or none, a CRC-32 on every chunk, on the data section (which covers what no chunk CRC
does: the message indexes and the metadata record) and on the summary. A path ending in ``.mcap``
becomes a single MCAP file (no ``metadata.yaml``; ``ros2 bag`` and rosbags read it directly); any
other path becomes a rosbag2 directory. The file is written in place from the start: every
finished chunk is in the file (and, with ``flush(fsync=True)``, on the disk), so a writer killed
mid-way leaves a bag that is readable up to its last complete chunk. While the writer is open a
marker ``<bag>.recording`` lies next to the bag (it also keeps the channel definitions);
:meth:`BagWriter.close` removes it. Bags carry no wall-clock time: writing the same messages with
the same log times gives byte-identical files.
"""

from __future__ import annotations

import json
import os
import shutil
from collections import Counter
from collections.abc import Mapping
from contextlib import suppress
from pathlib import Path
from types import TracebackType
from typing import Any, NamedTuple

from msg_bridge.bag.errors import BagError
from msg_bridge.bag.metadata import marker_path, qos_list, qos_text, to_yaml
from msg_bridge.bag.typestore import serialize, typestore

__all__ = ["COMPRESSIONS", "DEFAULT_CHUNK_SIZE", "BagWriter"]

COMPRESSIONS = ("zstd", "none")
DEFAULT_CHUNK_SIZE = 1 << 20


def _schema_of(msgtype: str) -> tuple[str, bytes]:
    """(encoding, data) of the MCAP schema for ``msgtype``, as ``ros2 bag`` writes it."""
    text, _digest = typestore().generate_msgdef(msgtype, ros_version=2)
    encoding = "ros2idl" if text.startswith("=" * 80 + "\nIDL: ") else "ros2msg"
    return encoding, text.encode()


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
    """Writes a rosbag2 MCAP bag with real chunk, data section and summary CRCs; use as a context manager.

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
        """Create the bag and its marker and start the MCAP file; :meth:`__enter__` calls it."""
        # Imported on use: mcap is slow to import and ``import msg_bridge`` writes no bag.
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
        self._writer = Writer(stream, chunk_size=self.chunk_size, compression=compression, enable_crcs=True,
                              enable_data_crcs=True)
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
        channel_id = self.add_channel(topic, msgtype, encoding, data, {"offered_qos_profiles": qos_text(latched)},
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
            writer.add_metadata("rosbag2", {"serialized_metadata": to_yaml(info)})
            writer.finish()
            stream.fsync()
        finally:
            stream.close()
        if not self.single_file:
            tmp = self.path / "metadata.yaml.tmp"
            tmp.write_text(to_yaml({"rosbag2_bagfile_information": info}))
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
                    "offered_qos_profiles": qos_list(qos),
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
    """The writer's name in the MCAP header (``library``; :func:`~msg_bridge.bag.bag_info` shows it)."""
    from mcap.writer import LIBRARY_IDENTIFIER  # imported on use, as in BagWriter.open

    return f"roadbev msg_bridge.bag ({LIBRARY_IDENTIFIER})"
