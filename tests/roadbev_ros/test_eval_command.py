"""``roadbev eval``: a real (tiny) bag end to end, and a one-line reason for every bad input."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.evaluation import CONTRACT_KEYS
from roadbev_ros.cli import main

CAMERA = StereoCamera.rsrd_half().scaled(0.5)
GRID = GridSpec().scaled(2)


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A two-frame half-resolution evaluation bag (single .mcap file)."""
    from msg_bridge.evalbag import write_eval_bag
    from roadbev_core.synth import DriveConfig, RoadConfig, SyntheticDrive

    path = tmp_path_factory.mktemp("evalbag") / "drive.mcap"
    road = RoadConfig(road_class="B", features=("speed_bump",), noise_sigma=1.0)
    write_eval_bag(path, SyntheticDrive(DriveConfig(frames=2, seed=5, road=road, camera=CAMERA, grid=GRID)))
    return path


def _one_line_error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("roadbev eval: ")
    return err[0]


def test_eval_writes_metrics(bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    params = tmp_path / "p.yaml"
    params.write_text("roadbev:\n  ros__parameters:\n    base_height: 1.10\n    bm.block_size: 7\n")
    out = tmp_path / "out" / "metrics.json"
    rc = main(["eval", str(bag), "--backend", "bm", "--params", str(params), "--json", str(out), "--no-progress"])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "abs.err cm" in printed and "bm" in printed
    data = json.loads(out.read_text())
    assert set(CONTRACT_KEYS) <= set(data)
    assert data["backend"] == "bm" and data["frames"] == 2
    assert data["backend_options"] == {"block_size": 7}
    assert len(data["band_abs_err_cm"]) == 15
    assert data["grid"]["resolution"] == pytest.approx(GRID.resolution)
    assert 0.0 < data["abs_err_cm"] < 3.0 and data["coverage_pct"] > 50.0
    assert data["fps"] > 0


def test_frames_limit_and_default_backend(bag: Path, tmp_path: Path) -> None:
    out = tmp_path / "m.json"
    assert main(["eval", str(bag), "--frames", "1", "--json", str(out), "--no-progress"]) == 0
    data = json.loads(out.read_text())
    assert data["frames"] == 1 and data["backend"] == "bev_sweep"


def test_missing_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", str(tmp_path / "nope.mcap")]) == 2
    assert "bag not found" in _one_line_error(capsys)


def test_not_a_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", str(tmp_path)]) == 2
    assert "not a rosbag2 bag" in _one_line_error(capsys)


def test_corrupt_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(b"\x89MCAP0\r\n" + b"\x00garbage" * 50)
    assert main(["eval", str(broken), "--backend", "bm", "--no-progress"]) == 2
    _one_line_error(capsys)


def test_unknown_backend(bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", str(bag), "--backend", "magic"]) == 2
    assert "unknown backend 'magic'" in _one_line_error(capsys)


def test_bad_params(bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    params = tmp_path / "bad.yaml"
    params.write_text("roadbev: [not, a, section\n")
    assert main(["eval", str(bag), "--params", str(params)]) == 2
    _one_line_error(capsys)
    params.write_text("roadbev:\n  ros__parameters:\n    bev_sweep.patch_cells: 4\n")
    assert main(["eval", str(bag), "--params", str(params), "--no-progress"]) == 2
    assert "odd" in _one_line_error(capsys)


def test_bad_frames_and_checkpoint(bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", str(bag), "--frames", "0"]) == 2
    assert "--frames" in _one_line_error(capsys)
    assert main(["eval", str(bag), "--backend", "bm", "--checkpoint", "x.pt"]) == 2
    assert "learned" in _one_line_error(capsys)


def test_a_wrong_base_height_gets_a_self_check_hint(
    bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    params = tmp_path / "wrong.yaml"
    params.write_text("roadbev:\n  ros__parameters:\n    base_height: 1.60\n")  # the road at z = -0.5 m
    out = tmp_path / "m.json"
    assert main(["eval", str(bag), "--backend", "bev_sweep", "--params", str(params), "--json", str(out),
                 "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "uncertainty: error within 1 / 2 / 3 sigma" in printed
    hint = next(line for line in printed.splitlines() if line.startswith("self-check:"))
    assert "(low)" in hint and "base_height" in hint
    assert "base_height" in json.loads(out.read_text())["self_check"]
