"""A bag opened: the MCAP files a BAG path names, each scanned, and the schemas and channels they
define (:func:`open_bag`).

A BAG path is either a rosbag2 directory (with ``metadata.yaml``) or a single ``.mcap`` file
(contract, "Command line"); both open the same way. Schemas and channels come from wherever the
writer left them: outside chunks, in the summary, in a ``.recording`` marker, or (for a bag
whose writer did not finish) inside the chunks (:meth:`Bag.ensure_channels`).
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

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


def _mcap_files(path: Path) -> list[Path]:
    if path.is_file():
        return [path]
    meta = read_metadata(path)
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
class Bag:
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


def open_bag(path: Path) -> Bag:
    """Scan the files of the bag at ``path`` and collect the schemas and channels they define.

    Raises:
        BagError: no bag at ``path``, a file that is no MCAP or unreadable, or nothing readable.
    """
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
    bag = Bag(path, scans, {}, {}, False)
    for scan in scans:
        bag.add(scan, scan.schemas.values(), scan.channels.values())
    bag.marker = _marker_channels(path, bag)
    return bag
