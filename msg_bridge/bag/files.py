"""A bag opened: the MCAP files a BAG path names, each scanned, and the schemas and channels they
define (:func:`open_bag`).

A BAG path is either a rosbag2 directory (with ``metadata.yaml``) or a single ``.mcap`` file
(contract, "Command line"); both open the same way. Schemas and channels come from wherever the
writer left them: outside chunks, in the summary, in a ``.recording`` marker, or (for a bag
whose writer did not finish) inside the chunks (:meth:`Bag.ensure_channels`). A split bag (a
rosbag2 directory of several files) with a file missing or unreadable opens with the files that
can be read; the others are named in :attr:`Bag.lost_files`.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from msg_bridge.bag.errors import BagError
from msg_bridge.bag.mcap_file import Channel, FileScan, McapFormatError, Schema, load_chunk, scan_file
from msg_bridge.bag.metadata import marker_path, read_metadata

__all__ = ["Bag", "open_bag"]


def _check_path(path: Path) -> None:
    if not path.exists():
        raise BagError(f"{path}: no such bag (file or rosbag2 directory)")
    if path.is_dir() and not (path / "metadata.yaml").exists() and not any(path.glob("*.mcap")):
        raise BagError(f"{path}: a directory without metadata.yaml or .mcap files is not a rosbag2 bag")
    if path.is_file() and path.suffix != ".mcap":
        raise BagError(f"{path}: not an .mcap file or a rosbag2 directory")


def _listed_counts(meta: dict[str, Any]) -> dict[str, int]:
    """File name -> message count, as metadata.yaml's ``files`` entries give them."""
    counts: dict[str, int] = {}
    entries = meta.get("files")
    for entry in entries if isinstance(entries, list) else []:
        if isinstance(entry, dict) and isinstance(entry.get("message_count"), int):
            counts[Path(str(entry.get("path", ""))).name] = entry["message_count"]
    return counts


def _mcap_files(path: Path) -> tuple[list[Path], dict[Path, int]]:
    """The MCAP files of the bag at ``path`` (those metadata.yaml lists, some of which may be
    missing), and the message count of each file where metadata.yaml gives it."""
    if path.is_file():
        return [path], {}
    meta = read_metadata(path)
    if meta is not None:
        storage = str(meta.get("storage_identifier", "mcap"))
        if storage != "mcap":
            raise BagError(f"{path}: storage {storage!r} is not supported (only MCAP bags)")
        listed = meta.get("relative_file_paths") or []
        names = [Path(str(p)).name for p in (listed if isinstance(listed, list) else [listed])]
        missing = [n for n in names if not (path / n).is_file()]
        if names and len(missing) == len(names):
            raise BagError(f"{path}: files listed in metadata.yaml are missing: {', '.join(missing)}")
        if names:
            return [path / n for n in names], {path / n: c for n, c in _listed_counts(meta).items()}
    return sorted(path.glob("*.mcap")), {}


@dataclass
class Bag:
    """The scanned files of a bag and every channel known so far.

    Attributes:
        lost_files: files of a split bag that are missing or cannot be read -> why, and what
            that costs where metadata.yaml says (the other files are read).
    """

    path: Path
    scans: list[FileScan]
    schemas: dict[tuple[Path, int], Schema]
    channels: dict[tuple[Path, int], Channel]
    marker: bool
    lost_files: dict[Path, str] = field(default_factory=dict)

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


def _marker_channels(path: Path, bag: Bag) -> bool:
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


def _scan(file: Path, check_data_crc: bool) -> FileScan:
    try:
        scan = scan_file(file, check_data_crc=check_data_crc)
    except McapFormatError as exc:
        raise BagError(f"{file}: {exc}") from None
    except OSError as exc:
        raise BagError(f"{file}: cannot read: {exc}") from None
    if not scan.profile and not scan.chunks and not scan.loose:
        reason = "; ".join(d.reason for d in scan.damage) or "no records"
        raise BagError(f"{file}: truncated or corrupt bag, nothing readable ({reason})")
    return scan


def open_bag(path: Path, *, check_data_crc: bool = True) -> Bag:
    """Scan the files of the bag at ``path`` and collect the schemas and channels they define.

    Args:
        path: a rosbag2 directory or an ``.mcap`` file.
        check_data_crc: check each file's data section CRC (reads every byte; a look at the
            indexes only can skip it).

    Raises:
        BagError: no bag at ``path``, a file that is no MCAP or unreadable, or nothing readable
            (a split bag with some of its files missing or unreadable opens with the others:
            :attr:`Bag.lost_files`).
    """
    _check_path(path)
    scans: list[FileScan] = []
    files, counts = _mcap_files(path)
    lost_files: dict[Path, str] = {}
    for file in files:
        if not file.is_file():
            lost_files[file] = "listed in metadata.yaml but missing"
            continue
        try:
            scans.append(_scan(file, check_data_crc))
        except BagError as exc:
            if len(files) == 1:  # a bag of one file: its error is the bag's
                raise
            lost_files[file] = f"cannot be read ({str(exc).removeprefix(f'{file}: ')})"
    for file, why in lost_files.items():
        n = counts.get(file)
        lost_files[file] = why + (f"; its {n} message(s) are lost" if n is not None else "; its messages are lost")
    if not scans:
        if not lost_files:
            raise BagError(f"{path}: no .mcap files")
        raise BagError(f"{path}: no file of the bag can be read: "
                       + "; ".join(f"{file.name}: {why}" for file, why in lost_files.items()))
    # Schemas and channels, as the writer left them: outside chunks or in the summary; by index
    # ids, so that the summary's copies serve when the chunk that held them is damaged.
    bag = Bag(path, scans, {}, {}, False, lost_files)
    for scan in scans:
        bag.add(scan, scan.schemas.values(), scan.channels.values())
    bag.marker = _marker_channels(path, bag)
    return bag
