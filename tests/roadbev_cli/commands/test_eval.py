"""``roadbev eval``: a real (tiny) bag end to end, and a one-line reason for every bad input."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from roadbev_cli.cli import main
from roadbev_core.config import DEFAULT_BACKEND, GridSpec, StereoCamera
from roadbev_lab.evaluation.frames import CONTRACT_KEYS

CAMERA = StereoCamera.rsrd_half().scaled(0.5)
GRID = GridSpec().scaled(2)


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A two-frame half-resolution evaluation bag (single .mcap file)."""
    from roadbev_lab.evaluation.evalbag import write_eval_bag
    from roadbev_lab.synth import DriveConfig, RoadConfig, SyntheticDrive

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
    assert "preview_at_arrival" not in data  # not a drive bag
    assert "far_field" not in data  # no far-field truth in the bag


def test_frames_limit_and_default_backend(bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "m.json"
    assert main(["eval", str(bag), "--frames", "1", "--backend", "bev_sweep", "--json", str(out),
                 "--no-progress"]) == 0
    data = json.loads(out.read_text())
    assert data["frames"] == 1 and data["backend"] == "bev_sweep"
    assert main(["eval", str(bag), "--frames", "1", "--json", str(out), "--no-progress"]) == 0
    assert json.loads(out.read_text())["backend"] == DEFAULT_BACKEND  # no --backend, no params: the default
    # the learned stereo model refuses this bag's 6 cm grid by name
    assert main(["eval", str(bag), "--frames", "1", "--backend", "stereo", "--no-progress"]) == 2
    error = _one_line_error(capsys)
    assert "backend 'stereo' cannot run" in error and "trained 0.03 m" in error


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
    assert ("backend must be one of adabins, bev_sweep, bm, ensemble, gwcnet, mono, sgbm, stereo; got 'magic'"
            in _one_line_error(capsys))


def test_bad_params(bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    params = tmp_path / "bad.yaml"
    params.write_text("roadbev: [not, a, section\n")
    assert main(["eval", str(bag), "--params", str(params)]) == 2
    _one_line_error(capsys)
    params.write_text("roadbev:\n  ros__parameters:\n    backend: bev_sweep\n    bev_sweep.patch_cells: 4\n")
    assert main(["eval", str(bag), "--params", str(params), "--no-progress"]) == 2
    assert "odd" in _one_line_error(capsys)


@pytest.mark.parametrize(
    "section, reason",
    [
        ("base_hieght: 1.2", "unknown parameter 'base_hieght' (did you mean 'base_height'?)"),
        ("base_height: high", "base_height must be a number"),
        ("bev_swep.patch_cells: 5", "unknown parameter 'bev_swep.patch_cells'"),
        ("resolution: 0.001", "voxels, more than the limit"),
    ],
)
def test_a_typo_or_a_wrong_type_in_the_params_file_is_refused_by_name(
    bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], section: str, reason: str
) -> None:
    params = tmp_path / "typo.yaml"
    params.write_text(f"roadbev:\n  ros__parameters:\n    {section}\n")
    assert main(["eval", str(bag), "--params", str(params), "--no-progress"]) == 2
    assert reason in _one_line_error(capsys)


def test_a_params_file_for_another_node_is_reported(
    bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    params = tmp_path / "other.yaml"
    params.write_text("camera_driver:\n  ros__parameters:\n    exposure: 3\n")
    assert main(["eval", str(bag), "--params", str(params), "--no-progress"]) == 2
    assert "no section for node 'roadbev'" in _one_line_error(capsys)
    params.write_text("camera_driver:\n  ros__parameters: {exposure: 3}\nroadbev:\n  ros__parameters: {}\n")
    assert main(["eval", str(bag), "--params", str(params), "--no-progress", "--backend", "bm"]) == 0
    assert "sections for other nodes not applied: camera_driver" in capsys.readouterr().err


def test_bad_frames_and_checkpoint(bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", str(bag), "--frames", "0"]) == 2
    assert "--frames" in _one_line_error(capsys)
    assert main(["eval", str(bag), "--backend", "bm", "--checkpoint", "x.pt"]) == 2
    assert "learned" in _one_line_error(capsys)


# ------------------------------------------------------------------------------------------------
# partial results: truncated bags, broken images, bags without ground truth
# ------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def jpeg_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Five small JPEG frames (240 x 132), rewritten with small chunks (several per frame)."""
    from roadbev_lab.evaluation.evalbag import write_eval_bag
    from roadbev_lab.synth import DriveConfig, RoadConfig, SyntheticDrive
    from tests.roadbev_ros._damaged_bags import rewrite

    root = tmp_path_factory.mktemp("jpegbag")
    road = RoadConfig(road_class="B", features=("speed_bump",), noise_sigma=1.0)
    drive = SyntheticDrive(DriveConfig(frames=5, seed=6, road=road, camera=CAMERA.scaled(0.5), grid=GRID))
    write_eval_bag(root / "big.mcap", drive, compressed=True)
    rewrite(root / "big.mcap", root / "drive.mcap", chunk_size=8 * 1024)
    return root / "drive.mcap"


def _eval(bag: Path, tmp_path: Path, *extra: str) -> tuple[int, dict[str, Any]]:
    out = tmp_path / f"{bag.stem}.json"
    rc = main(["eval", str(bag), "--backend", "bm", "--json", str(out), "--no-progress", *extra])
    return rc, (json.loads(out.read_text()) if out.exists() else {})


def test_truncated_bags_give_their_readable_frames_and_say_what_was_lost(
    jpeg_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from tests.roadbev_ros._damaged_bags import truncate

    frames = []
    for fraction in (0.45, 0.7, 0.9):
        cut = truncate(jpeg_bag, tmp_path / f"cut{int(fraction * 100)}.mcap", fraction)
        rc, data = _eval(cut, tmp_path)
        err = capsys.readouterr().err
        assert rc == 0 and "breaks off" in err and "chunk" in err
        assert data["losses"] and 0 < data["frames"] < 5
        # The readable frames are the bag's first frames, evaluated as in the whole bag (all
        # but the last: the IMU samples after its stamp may lie beyond the cut).
        if data["frames"] > 1:
            head = str(data["frames"] - 1)
            _rc, part = _eval(cut, tmp_path, "--frames", head)
            _rc, whole = _eval(jpeg_bag, tmp_path, "--frames", head)
            assert part["cells"] == whole["cells"] and part["abs_err_cm"] == whole["abs_err_cm"]
        frames.append(data["frames"])
    assert frames == sorted(frames) and frames[0] < frames[-1]
    capsys.readouterr()
    nothing = truncate(jpeg_bag, tmp_path / "cut2.mcap", 0.02)
    assert main(["eval", str(nothing), "--backend", "bm", "--no-progress"]) == 2  # nothing to evaluate
    line = _one_line_error(capsys)
    assert "no left images" in line or "no usable frames" in line


def test_an_undecodable_jpeg_is_a_counted_lost_frame(jpeg_bag: Path, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    from tests.roadbev_ros._damaged_bags import rewrite

    def break_second_left(topic: str, index: int, msg: object) -> object:
        if topic.startswith("/stereo/left/image_rect") and index == 1:
            msg.data = np.frombuffer(b"\xff\xd8 this is no jpeg", np.uint8)  # type: ignore[attr-defined]
        return msg

    broken = tmp_path / "broken.mcap"
    rewrite(jpeg_bag, broken, change=break_second_left)
    rc, data = _eval(broken, tmp_path)
    assert rc == 0 and data["frames"] == 4 and data["lost_frames"] == 1
    assert "1 frame(s) lost: an image does not decode" in capsys.readouterr().err


def test_a_bag_without_ground_truth_writes_every_output_and_says_there_is_nothing_to_score(
    jpeg_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from msg_bridge.grid_map import grid_map_to_arrays
    from msg_bridge.preview import preview_from_message
    from roadbev_core.backends import create
    from roadbev_lab.evaluation.evalbag import bag_frames, read_eval_bag
    from tests.roadbev_ros._damaged_bags import rewrite

    drive = tmp_path / "nogt.mcap"
    rewrite(jpeg_bag, drive, drop=["/ground_truth/elevation"])
    out = tmp_path / "outputs.mcap"
    rc, data = _eval(drive, tmp_path, "--out", str(out))
    printed = capsys.readouterr().out
    assert rc == 0 and "nothing to score" in printed and data["frames"] == 5 and data["cells"] == 0
    with out.open("rb") as stream:  # the independent reader, message for message
        decoded = [(c.topic, d) for _s, c, _m, d in make_reader(stream, decoder_factories=[DecoderFactory()])
                   .iter_decoded_messages()]
    # docs/interface/bags.md: the outputs stamped and framed as the node publishes them, /tf to roadbev_road included
    assert Counter(t for t, _ in decoded) == {"/roadbev/elevation": 5, "/roadbev/elevation_far": 5,
                                              "/roadbev/preview": 5, "/tf": 5}
    eval_bag = read_eval_bag(drive)
    first = bag_frames(drive)[1][0]  # with the attitude from the bag's IMU, as the pipeline computes it
    expected = create("bm", eval_bag.grid).estimate(first.frame)
    maps = [grid_map_to_arrays(d) for t, d in decoded if t == "/roadbev/elevation"]
    assert maps[0].stamp_ns == first.frame.stamp_ns and maps[0].frame_id == "roadbev_road"
    np.testing.assert_array_equal(maps[0].layers["elevation"], expected.elevation)
    previews = [preview_from_message(d) for t, d in decoded if t == "/roadbev/preview"]
    assert [p.stamp_ns for p in previews] == [m.stamp_ns for m in maps] == eval_bag.stamps


def test_a_wrong_base_height_gets_a_self_check_hint_and_fails(
    bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    params = tmp_path / "wrong.yaml"
    params.write_text("roadbev:\n  ros__parameters:\n    base_height: 1.60\n")  # the road at z = -0.5 m
    out = tmp_path / "m.json"
    # every frame comes out empty: the metrics are printed and written, and the command fails with the cause
    assert main(["eval", str(bag), "--backend", "bev_sweep", "--params", str(params), "--json", str(out),
                 "--no-progress"]) == 2
    captured = capsys.readouterr()
    printed = captured.out
    error = captured.err.strip().splitlines()[-1]
    assert error.startswith("roadbev eval: error: every frame came out empty (coverage 0 %): ")
    assert "base_height" in error
    assert "uncertainty: error within 1 / 2 / 3 sigma" in printed
    hint = next(line for line in printed.splitlines() if line.startswith("self-check:"))
    assert "(low)" in hint and "base_height" in hint
    assert "base_height" in json.loads(out.read_text())["self_check"]


def test_a_cut_drive_bag_scores_every_readable_frame_as_the_whole_bag_does(tmp_path: Path) -> None:
    from msg_bridge.bag import read_messages
    from msg_bridge.grid_map import grid_map_to_arrays
    from tests.roadbev_ros._damaged_bags import truncate

    whole = tmp_path / "drive.mcap"
    assert main(["synth", str(whole), "--drive", "--frames", "6", "--image-scale", "0.25", "--quiet"]) == 0
    cut = truncate(whole, tmp_path / "cut.mcap", 0.9)
    maps = {}
    for name, path in (("whole", whole), ("cut", cut)):
        out = tmp_path / f"{name}_out.mcap"
        assert main(["eval", str(path), "--backend", "bm", "--json", str(tmp_path / f"{name}.json"), "--out", str(out),
                     "--no-progress"]) == 0
        maps[name] = {item.log_time_ns: grid_map_to_arrays(item.msg).layers["elevation"]
                      for item in read_messages(out, ["/roadbev/elevation"])}
    cut_json = json.loads((tmp_path / "cut.json").read_text())
    assert cut_json["losses"] and cut_json["preview_at_arrival"]["points"] > 0  # scored, with what was lost
    assert 0 < len(maps["cut"]) < len(maps["whole"])
    same = [np.array_equal(e, maps["whole"][s], equal_nan=True) for s, e in sorted(maps["cut"].items())]
    assert all(same), same


# ------------------------------------------------------------------------------------------------
# many bags: a folder, a glob, --workers / --ray; one summary, the bags' JSONs pooled
# ------------------------------------------------------------------------------------------------
def test_many_bags_give_each_bags_json_and_the_pooled_metrics(
    bag: Path, jpeg_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from roadbev_lab.evaluation.frames import without_timing

    archive = tmp_path / "archive"
    (archive / "day1").mkdir(parents=True)
    for source, name in ((bag, "day1/a.mcap"), (jpeg_bag, "b.mcap")):
        (archive / name).write_bytes(source.read_bytes())
    summary_path, store = tmp_path / "summary.json", tmp_path / "store"
    args = ["eval", str(archive), "--backend", "bm", "--no-progress", "--store", str(store), "--workers", "1"]
    assert main([*args, "--json", str(summary_path), "--report", str(tmp_path / "report.md")]) == 0
    printed = capsys.readouterr().out
    summary = json.loads(summary_path.read_text())
    assert summary["counts"] == {"bags": 2, "done": 2, "stored": 0, "failed": 0, "duplicate": 0}
    assert [b["bag"] for b in summary["bags"]] == [str(archive / "b.mcap"), str(archive / "day1" / "a.mcap")]
    for entry in summary["bags"]:  # each bag's entry is the JSON `roadbev eval BAG --json` writes
        _rc, alone = _eval(Path(entry["bag"]), tmp_path)
        assert without_timing(entry["result"]) == without_timing(alone)
    pooled = summary["pooled"]
    assert pooled["frames"] == 7 and set(CONTRACT_KEYS) <= set(pooled)
    assert "| **pooled, 2 bag(s)** | 7 |" in printed and (tmp_path / "report.md").read_text() in printed
    # again: both from the store; a glob names the same bags
    assert main(["eval", str(archive / "**" / "*.mcap"), *args[2:], "--json", str(summary_path)]) == 0
    assert json.loads(summary_path.read_text())["counts"]["stored"] == 2


def test_many_bags_with_a_corrupt_one_keep_the_others_and_fail(
    bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(b"\x89MCAP0\r\n" + b"\x00garbage" * 50)
    out = tmp_path / "summary.json"
    assert main(["eval", str(bag), str(broken), "--backend", "bm", "--no-progress", "--workers", "1", "--store",
                 str(tmp_path / "store"), "--json", str(out)]) == 2
    error = _one_line_error(capsys)
    assert "1 of 2 bag(s) failed" in error and "broken.mcap" in error
    summary = json.loads(out.read_text())
    assert [b["status"] for b in summary["bags"]] == ["done", "failed"] and summary["pooled"]["bags"] == 1


def test_many_bags_refuse_options_for_one(bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", str(bag), str(bag), "--out", str(tmp_path / "o.mcap")]) == 2
    assert "--out writes one bag's outputs" in _one_line_error(capsys)
    assert main(["eval", str(tmp_path / "*.db3")]) == 2
    assert "no bags match" in _one_line_error(capsys)
    assert main(["eval", str(bag), "--report", str(tmp_path / "r.md")]) == 2
    assert "--report is for many bags" in _one_line_error(capsys)


def test_many_bags_on_a_local_ray_cluster(bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("ray", reason="Ray is not installed (the fleet extra: pip install .[fleet])")
    out = tmp_path / "summary.json"
    assert main(["eval", str(bag), "--backend", "bm", "--no-progress", "--ray", "local", "--workers", "2",
                 "--store", str(tmp_path / "store"), "--json", str(out)]) == 0
    summary = json.loads(out.read_text())
    assert summary["run"]["executor"]["kind"] == "ray" and summary["counts"]["done"] == 1
    assert summary["pooled"]["frames"] == 2
