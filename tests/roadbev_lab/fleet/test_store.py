"""The result store and the keys: content, not names or times; complete or absent; bags found."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from roadbev_lab.fleet.runner import find_bags, output_names
from roadbev_lab.fleet.store import ResultStore, config_digest, content_digest, fingerprint, result_key


def test_a_result_comes_back_as_it_was_put_and_nothing_half_written_stays(tmp_path: Path) -> None:
    store = ResultStore(tmp_path / "store")
    key = "ab" + "0" * 62
    assert not store.has(key)
    arrays = {"hist": np.arange(5, dtype=np.int64), "sums": np.array([0.1, 1e-17])}
    store.put(key, {"bag": "x.mcap", "abs_err_cm": float("nan"), "n": 3}, arrays)
    assert store.has(key)
    record, back = store.get(key)
    assert record == {"bag": "x.mcap", "abs_err_cm": None, "n": 3}  # strict JSON, as the one-bag command writes
    assert set(back) == set(arrays) and all(np.array_equal(back[k], v) for k, v in arrays.items())
    assert [p.name for p in (tmp_path / "store" / "ab").iterdir()] == [f"{key}.npz"]  # no temporary left
    with pytest.raises(KeyError):
        store.get("cd" + "0" * 62)


def test_the_key_is_the_content_and_the_settings(tmp_path: Path) -> None:
    a, b = tmp_path / "a.mcap", tmp_path / "sub" / "b.mcap"
    b.parent.mkdir()
    a.write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 10)
    b.write_bytes(a.read_bytes())
    assert content_digest(a) == content_digest(b)  # another name, folder and time: the same bag
    os.utime(a, ns=(1, 1))
    assert content_digest(a) == content_digest(b) and fingerprint(a) != fingerprint(b)
    data = bytearray(b.read_bytes())
    data[100] ^= 1
    b.write_bytes(bytes(data))
    assert content_digest(a) != content_digest(b)
    folder = tmp_path / "bag"
    folder.mkdir()
    (folder / "metadata.yaml").write_text("x")
    (folder / "bag_0.mcap").write_bytes(b"1")
    first = content_digest(folder)
    (folder / "metadata.yaml").write_text("y")
    assert content_digest(folder) != first  # every file of a rosbag2 directory counts
    one, other = config_digest({"backend": "bm", "x": [1, 2]}), config_digest({"x": [1, 2], "backend": "bm"})
    assert one == other != config_digest({"backend": "sgbm", "x": [1, 2]})
    assert result_key(first, one) != result_key(first, config_digest({"backend": "sgbm"}))


def test_a_digest_is_remembered_until_the_files_change(tmp_path: Path) -> None:
    store = ResultStore(tmp_path / "store")
    bag = tmp_path / "a.mcap"
    bag.write_bytes(b"one")
    assert store.cached_digest(bag) is None
    store.remember_digest(bag, content_digest(bag))
    assert store.cached_digest(bag) == content_digest(bag)
    bag.write_bytes(b"two!")  # another size (and time): read again
    assert store.cached_digest(bag) is None


def test_bags_from_lists_folders_and_patterns(tmp_path: Path) -> None:
    archive = tmp_path / "archive"
    (archive / "day1").mkdir(parents=True)
    (archive / "day2" / "rosbag").mkdir(parents=True)
    for name in ("day1/a.mcap", "day1/b.mcap", "day2/rosbag/metadata.yaml", "day2/rosbag/rosbag_0.mcap",
                 "day2/notes.txt"):
        (archive / name).write_text("x")
    a, b, rosbag = archive / "day1" / "a.mcap", archive / "day1" / "b.mcap", archive / "day2" / "rosbag"
    assert find_bags([archive]) == [a, b, rosbag]  # a rosbag2 directory is one bag, its .mcap inside no other
    assert find_bags([str(archive / "day1" / "*.mcap"), a]) == [a, b]  # each bag once
    assert find_bags([str(archive / "**" / "b.mcap")]) == [b]
    with pytest.raises(FileNotFoundError, match="no bags match"):
        find_bags([str(archive / "*.db3")])
    with pytest.raises(FileNotFoundError, match="bag not found"):
        find_bags([archive / "missing.mcap"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="no bags in"):
        find_bags([tmp_path / "empty"])
    names = output_names([a, archive / "day2" / "a.mcap", rosbag])
    assert names[rosbag] == "rosbag.mcap" and names[a] != names[archive / "day2" / "a.mcap"]
    assert names[a].startswith("a-") and names[a].endswith(".mcap")
