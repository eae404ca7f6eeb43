"""``roadbev bag info`` and ``roadbev bag recover`` on whole, unfinished, damaged and garbage bags."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from msg_bridge import BagWriter, bag_factory, bag_info, marker_path, read_messages
from msg_bridge.imu import imu_message
from roadbev_cli.cli import main

N = 400


def _write(path: Path, *, close: bool = True) -> BagWriter:
    writer = BagWriter(path, chunk_size=4096)
    writer.open()
    writer.add_topic("/imu/data", "sensor_msgs/msg/Imu")
    writer.add_topic("/note", "std_msgs/msg/String", latched=True)
    factory = bag_factory()
    writer.write("/note", factory.new("std_msgs/msg/String", data="hello"), 1)
    for k in range(N):
        writer.write("/imu/data", imu_message(factory, stamp_ns=10 + k, orientation_xyzw=(0, 0, 0, 1)), 10 + k)
    if close:
        writer.close()
    else:
        writer.flush()
    return writer


def test_info_of_a_whole_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "whole.mcap"
    _write(path)
    assert main(["bag", "info", str(path), "--json", str(tmp_path / "info.json")]) == 0
    out = capsys.readouterr().out
    assert "closed cleanly" in out and f"/imu/data  {N:>8}  sensor_msgs/msg/Imu" in out and "damage" not in out
    data = json.loads((tmp_path / "info.json").read_text())
    assert data["closed"] and data["topics"]["/note"] == {"type": "std_msgs/msg/String", "count": 1}
    assert data["chunks"] > 3 and data["chunks_without_crc"] == 0 and data["verified"]


def test_info_and_recover_of_a_bag_whose_writer_was_killed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "live.mcap"
    writer = _write(path, close=False)  # what SIGKILL leaves: chunks, no summary, the marker
    assert main(["bag", "info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "NOT closed cleanly" in out and ".recording marker" in out and f"{N:>8}" in out
    fixed = tmp_path / "fixed"
    assert main(["bag", "recover", str(path), str(fixed), "--no-progress"]) == 0
    assert f"recovered {N + 1} message(s)" in capsys.readouterr().out
    assert (fixed / "metadata.yaml").is_file() and bag_info(fixed).closed
    assert [m.log_time_ns for m in read_messages(fixed, ["/imu/data"])] == [10 + k for k in range(N)]
    writer.abort()
    assert not marker_path(path).exists()


def test_info_and_recover_of_a_damaged_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from msg_bridge.bag.mcap_file import scan_file

    path = tmp_path / "damaged.mcap"
    _write(path)
    chunk = scan_file(path).chunks[3]
    data = bytearray(path.read_bytes())
    data[chunk.data_start + chunk.data_length // 2] ^= 0x10
    path.write_bytes(bytes(data))
    assert main(["bag", "info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "closed cleanly" in out and "damage:   1 part(s)" in out and "chunk 3 at byte" in out and "lost)" in out
    lost = sum(bag_info(path).lost.values())
    assert main(["bag", "recover", str(path), str(tmp_path / "copy.mcap"), "--no-progress"]) == 0
    assert f"recovered {N + 1 - lost} message(s)" in capsys.readouterr().out and lost > 0
    assert bag_info(tmp_path / "copy.mcap").damage == []


def test_nothing_readable_or_an_existing_output_is_a_one_line_error(tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"\x89MCAP0\r\n" + bytes(64))
    assert main(["bag", "recover", str(garbage), str(tmp_path / "out.mcap"), "--no-progress"]) == 2
    assert main(["bag", "info", str(garbage)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("roadbev bag: ") and "garbage.mcap" in line for line in err)
    assert not (tmp_path / "out.mcap").exists() and not marker_path(tmp_path / "out.mcap").exists()
    whole = tmp_path / "whole.mcap"
    _write(whole)
    assert main(["bag", "recover", str(whole), str(whole)]) == 2
    assert "exists already" in capsys.readouterr().err
