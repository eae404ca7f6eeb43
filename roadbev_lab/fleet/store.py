"""Each bag's finished result, kept under a key of the bag's content and the configuration.

A key is the SHA-256 of the bag's content digest (:func:`content_digest`: every file of the bag,
byte for byte) and the configuration's digest (:func:`config_digest`: everything that changes
the result, the package version included). The same bag under another name, path or time stamp
has the same key; one changed byte, parameter or release gives another. A result is one file,
``<root>/<key[:2]>/<key>.npz`` (the record as JSON text and the arrays it pools from), written
to a temporary name and renamed: it is complete or absent, never half there, whenever the run
stops. Re-running a command skips every bag whose key is in the store.

Hashing a large bag reads all of it, so each bag's content digest is remembered by its files'
names, sizes and modification times (``<root>/fingerprints/``): an unchanged bag is not read
again to find its key.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from roadbev_lab.evaluation.frames import to_json

__all__ = ["ResultStore", "bag_files", "config_digest", "content_digest", "fingerprint", "result_key"]

_CHUNK = 1 << 20  # bytes read at a time while hashing


def bag_files(bag: Path) -> list[Path]:
    """The files whose bytes make a bag: the ``.mcap`` file itself, or every file of a rosbag2
    directory (``metadata.yaml`` and its ``.mcap`` files), sorted."""
    if bag.is_file():
        return [bag]
    return sorted(p for p in bag.rglob("*") if p.is_file())


def fingerprint(bag: Path) -> str:
    """A digest of the bag's file names, sizes and modification times (not its content): what
    says, without reading it, that a bag is the one hashed before."""
    h = hashlib.sha256(str(bag.resolve()).encode())
    for path in bag_files(bag):
        stat = path.stat()
        name = path.name if path == bag else str(path.relative_to(bag))
        h.update(f"\0{name}\0{stat.st_size}\0{stat.st_mtime_ns}".encode())
    return h.hexdigest()


def content_digest(bag: Path) -> str:
    """SHA-256 of the bag's content: each file's name within the bag (not the bag's own name)
    and bytes, in order.

    Raises:
        OSError: a file cannot be read.
    """
    h = hashlib.sha256()
    for path in bag_files(bag):
        name = "" if path == bag else str(path.relative_to(bag))
        h.update(f"\0{name}\0".encode())
        with path.open("rb") as stream:
            while chunk := stream.read(_CHUNK):
                h.update(chunk)
    return h.hexdigest()


def config_digest(config: Mapping[str, Any]) -> str:
    """SHA-256 of a configuration (JSON with sorted keys: the same settings, the same digest)."""
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()


def result_key(content: str, config: str) -> str:
    """The store's key of a bag's content digest under a configuration's digest."""
    return hashlib.sha256(f"{content}\0{config}".encode()).hexdigest()


class ResultStore:
    """Finished results by key, in a folder (created on the first write).

    Args:
        root: the store's folder.
    """

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    def _path(self, key: str) -> Path:
        return self.root / key[:2] / f"{key}.npz"

    def has(self, key: str) -> bool:
        """Whether the result of ``key`` is complete in the store."""
        return self._path(key).is_file()

    def put(self, key: str, record: Mapping[str, Any], arrays: Mapping[str, np.ndarray] | None = None) -> None:
        """Keep a result (its JSON record and arrays), replacing one of the same key, atomically."""
        path = self._path(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        payload = {f"array.{k}": np.asarray(v) for k, v in (arrays or {}).items()}
        payload["record"] = np.array(to_json(record))
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{key}.", suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as stream:
                np.savez_compressed(stream, **payload)  # type: ignore[arg-type]  # names are str
                stream.flush()
                os.fsync(stream.fileno())
            Path(tmp).replace(path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    def get(self, key: str) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """The record and arrays of ``key``.

        Raises:
            KeyError: no result under ``key``.
            ValueError: the file is not a result (damaged outside this store's writes).
        """
        path = self._path(key)
        if not path.is_file():
            raise KeyError(key)
        with np.load(path, allow_pickle=False) as data:
            record = json.loads(str(data["record"]))
            arrays = {k[len("array."):]: data[k] for k in data.files if k.startswith("array.")}
        return record, arrays

    def cached_digest(self, bag: Path) -> str | None:
        """The content digest remembered for the bag as it is now (same files, sizes, times); None if none."""
        path = self.root / "fingerprints" / fingerprint(bag)
        try:
            return path.read_text().strip() or None
        except OSError:
            return None

    def remember_digest(self, bag: Path, digest: str) -> None:
        """Remember the bag's content digest for its current files (:meth:`cached_digest`)."""
        folder = self.root / "fingerprints"
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=".", suffix=".tmp")
        with os.fdopen(fd, "w") as stream:
            stream.write(digest)
        Path(tmp).replace(folder / fingerprint(bag))
