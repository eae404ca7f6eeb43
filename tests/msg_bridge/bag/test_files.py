"""Opening a BAG path: files that are no MCAP, paths that are no bag, a metadata.yaml that names
missing files or another storage, a split bag with a file missing or unreadable, and the channels
of a bag whose writer is still open."""

from __future__ import annotations

from pathlib import Path

import pytest

from msg_bridge import BagError, BagWriter, bag_topics, read_messages
from msg_bridge.bag.files import open_bag
from msg_bridge.bag.metadata import to_yaml
from tests.msg_bridge.bag._bags import split_bag


@pytest.mark.parametrize("content", [b"", b"not an mcap file at all", b"\x89MCAP0\r\n" + bytes(100)])
def test_garbage_files_raise_bag_error(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "garbage.mcap"
    path.write_bytes(content)
    with pytest.raises(BagError, match=r"garbage\.mcap"):
        bag_topics(path)


def test_bad_paths_raise_bag_error(tmp_path: Path) -> None:
    with pytest.raises(BagError, match="no such bag"):
        list(read_messages(tmp_path / "missing.mcap"))
    (tmp_path / "empty_dir").mkdir()
    with pytest.raises(BagError, match=r"without metadata\.yaml"):
        bag_topics(tmp_path / "empty_dir")
    (tmp_path / "bag.db3").write_bytes(b"")
    with pytest.raises(BagError, match=r"not an \.mcap file"):
        bag_topics(tmp_path / "bag.db3")


def _directory_bag(path: Path) -> None:
    with BagWriter(path) as writer:
        writer.add_topic("/s", "std_msgs/msg/String")


def test_a_metadata_file_naming_missing_files_or_another_storage_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "bag"
    _directory_bag(path)
    (path / "bag.mcap").rename(path / "renamed.mcap")
    with pytest.raises(BagError, match=r"files listed in metadata\.yaml are missing: bag\.mcap"):
        open_bag(path)
    info = {"storage_identifier": "sqlite3", "relative_file_paths": ["bag.db3"]}
    (path / "metadata.yaml").write_text(to_yaml({"rosbag2_bagfile_information": info}))
    with pytest.raises(BagError, match="storage 'sqlite3' is not supported"):
        open_bag(path)


def test_an_open_writers_marker_defines_its_channels(tmp_path: Path) -> None:
    path = tmp_path / "live.mcap"
    writer = BagWriter(path)
    writer.open()
    writer.add_topic("/s", "std_msgs/msg/String", latched=True)
    bag = open_bag(path)  # nothing but the header is in the file yet
    assert bag.marker and not bag.closed
    channels = [(c.topic, bag.msgtype(bag.scans[0], c.id)) for c in bag.channels.values()]
    assert channels == [("/s", "std_msgs/msg/String")]
    writer.close()
    assert open_bag(path).closed


def test_a_split_bag_with_a_file_missing_or_unreadable_opens_with_the_others(tmp_path: Path) -> None:
    path = tmp_path / "split"
    first, second, third = split_bag(path, parts=3)
    second.unlink()
    third.write_bytes(b"not an mcap file")
    bag = open_bag(path)
    assert [s.path for s in bag.scans] == [first]
    assert bag.lost_files == {
        second: "listed in metadata.yaml but missing; its 20 message(s) are lost",
        third: "cannot be read (no MCAP magic at the start: not an MCAP file); its 20 message(s) are lost",
    }
    first.unlink()
    with pytest.raises(BagError, match=r"no file of the bag can be read: split_0\.mcap: listed in metadata\.yaml "
                       r"but missing.*; split_1\.mcap: listed.*; split_2\.mcap: cannot be read"):
        open_bag(path)
