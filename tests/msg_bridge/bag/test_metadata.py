"""rosbag2 metadata: metadata.yaml read (a bad one is a one-line BagError), the channels' QoS
profiles, the marker's place."""

from __future__ import annotations

from pathlib import Path

import pytest

from msg_bridge import BagError, bag_topics
from msg_bridge.bag.metadata import MARKER_SUFFIX, marker_path, qos_list, qos_text, read_metadata, to_yaml


@pytest.mark.parametrize("content, reason", [
    (b"rosbag2_bagfile_information:\n  version: \xff\xfe\n", "not UTF-8 text"),
    (b"rosbag2_bagfile_information: [unclosed\n", "not a rosbag2 metadata file"),
])
def test_a_bad_metadata_file_is_a_one_line_bag_error(tmp_path: Path, content: bytes, reason: str) -> None:
    folder = tmp_path / "bag"
    folder.mkdir()
    (folder / "metadata.yaml").write_bytes(content)
    with pytest.raises(BagError, match=reason) as exc:
        bag_topics(folder)
    assert "\n" not in str(exc.value)


def test_the_marker_lies_next_to_the_bag(tmp_path: Path) -> None:
    assert marker_path(tmp_path / "drive.mcap") == tmp_path / "drive.mcap.recording"
    assert marker_path(tmp_path / "drive") == tmp_path / f"drive{MARKER_SUFFIX}"


@pytest.mark.parametrize(("latched", "depth", "durability"), [(True, 1, "transient_local"), (False, 10, "volatile")])
def test_qos_profiles_as_rosbag2_stores_them(latched: bool, depth: int, durability: str) -> None:
    (profile,) = qos_list(qos_text(latched))
    assert (profile["history"], profile["depth"], profile["durability"]) == ("keep_last", depth, durability)
    assert profile["reliability"] == "reliable"
    assert qos_list("") == [] and qos_list("[unclosed") == []


def test_a_directory_without_metadata_has_none(tmp_path: Path) -> None:
    assert read_metadata(tmp_path) is None
    (tmp_path / "metadata.yaml").write_text(to_yaml({"rosbag2_bagfile_information": {"version": 9}}))
    assert read_metadata(tmp_path) == {"version": 9}
