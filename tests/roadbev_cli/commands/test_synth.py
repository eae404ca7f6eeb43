"""``roadbev synth``: a small synthetic evaluation bag, deterministic, with clear refusals."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from msg_bridge import bag_topics, read_messages
from msg_bridge.grid_map import grid_map_to_arrays
from roadbev_cli.cli import main
from roadbev_lab.evaluation.evalbag import read_eval_bag

SMALL = ["--frames", "2", "--image-scale", "0.25", "--quiet"]


def test_synth_writes_a_readable_eval_bag_deterministically(tmp_path: Path) -> None:
    digests = []
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        out = tmp_path / folder / "drive.mcap"
        assert main(["synth", str(out), *SMALL, "--compressed", "--seed", "3", "--features", "pothole"]) == 0
        digests.append(hashlib.sha256(out.read_bytes()).hexdigest())
    assert digests[0] == digests[1]
    topics = {t: i.count for t, i in bag_topics(out).items()}
    assert topics["/stereo/left/image_rect/compressed"] == 2 == topics["/ground_truth/elevation"]
    assert topics["/roadbev/grid_config"] == 1 and topics["/imu/data"] >= 21  # 100 Hz over 0.2 s
    bag = read_eval_bag(out)
    assert len(bag) == 2 and bag.camera.size == (240, 132)
    assert all(sample.truth is not None for sample in bag)


def test_synth_far_field_adds_its_truth_and_eval_scores_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "far.mcap"
    assert main(["synth", str(out), *SMALL, "--seed", "3", "--far-field"]) == 0
    topics = {t: i.count for t, i in bag_topics(out).items()}
    assert topics["/ground_truth/elevation_far"] == 2 == topics["/ground_truth/elevation"]
    bag = read_eval_bag(out)
    assert bag.far_grid is not None and bag.far_grid.shape == (66, 16) and bag.far_grid.x_min == bag.grid.x_max
    assert all(sample.far_truth is not None and np.isfinite(sample.far_truth).all() for sample in bag)
    report = tmp_path / "far.json"
    capsys.readouterr()
    outputs = tmp_path / "outputs.mcap"
    assert main(["eval", str(out), "--backend", "bm", "--json", str(report), "--out", str(outputs)]) == 0
    assert "far field 7.08-15 m (12 cm cells): abs. error" in capsys.readouterr().out
    far = json.loads(report.read_text())["far_field"]
    assert far["estimated"] and far["frames_with_truth"] == 2 and len(far["bands"]) == 8
    # --out writes what the node publishes: the far-field map on its own topic, on its grid
    maps = [grid_map_to_arrays(m.msg) for m in read_messages(outputs, ["/roadbev/elevation_far"])]
    assert len(maps) == 2 and maps[0].grid.shape == (66, 16) and maps[0].grid.x_min == bag.grid.x_max
    assert [m.stamp_ns for m in maps] == bag.stamps


def test_synth_raw_directory_bag(tmp_path: Path) -> None:
    out = tmp_path / "raw_bag"
    args = ["--frames", "1", "--image-scale", "0.25", "--quiet", "--compression", "none", "--features"]
    assert main(["synth", str(out), *args]) == 0
    assert (out / "metadata.yaml").is_file()
    assert bag_topics(out)["/stereo/right/image_rect"].count == 1


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--frames", "0"], "--frames must be >= 1"),
        (["--image-scale", "0"], "--image-scale"),
        (["--speed", "-1"], "speed"),
        (["--jpeg-quality", "0"], "--jpeg-quality"),
    ],
)
def test_bad_arguments_exit_with_a_reason(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], message: str
) -> None:
    assert main(["synth", str(tmp_path / "x.mcap"), "--quiet", *extra]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "x.mcap").exists()


def test_existing_output_is_not_overwritten(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "exists.mcap"
    out.write_bytes(b"keep")
    assert main(["synth", str(out), "--quiet"]) == 2
    assert "exists already" in capsys.readouterr().err
    assert out.read_bytes() == b"keep"


def test_synth_drive_writes_a_drive_bag_that_eval_scores_at_arrival(tmp_path: Path) -> None:
    import json

    from roadbev_lab.evaluation.arrival import ARRIVAL_KEYS

    out = tmp_path / "drive.mcap"
    args = ["--duration", "0.6", "--rate", "5", "--image-scale", "0.25", "--quiet", "--speed", "8", "--features",
            "speed_bump", "--odom-rate", "25", "--road-map-resolution", "0.04"]
    assert main(["synth", str(out), "--drive", *args]) == 0
    topics = {t: i.count for t, i in bag_topics(out).items()}
    assert topics["/ground_truth/elevation"] == 3  # 0.6 s at 5 Hz
    assert topics["/tf_static"] == 1 == topics["/ground_truth/road_map"]
    assert topics["/ground_truth/odom"] == topics["/imu/data"] and topics["/odom"] >= 0.24 * topics["/imu/data"]
    metrics = tmp_path / "m.json"
    assert main(["eval", str(out), "--backend", "bm", "--json", str(metrics), "--no-progress"]) == 0
    data = json.loads(metrics.read_text())["preview_at_arrival"]
    assert set(ARRIVAL_KEYS) <= set(data)
    assert data["lead_time_s"] == 0.1 and data["points"] > 2 * 0.4 * 8 / 0.03 * 0.9
    assert 0.0 <= data["coverage_pct"] <= 100.0


def test_synth_frames_and_duration_exclude_each_other(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    assert main(["synth", str(tmp_path / "x.mcap"), "--frames", "2", "--duration", "1"]) != 0
    assert "--frames or --duration" in capsys.readouterr().err


def test_eval_map_on_a_drive_fuses_publishes_and_scores_the_map(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    import json

    from msg_bridge.bag import read_messages
    from msg_bridge.preview import preview_from_message

    bag = tmp_path / "drive.mcap"
    args = ["--duration", "1.0", "--rate", "10", "--image-scale", "0.25", "--quiet", "--speed", "8", "--features",
            "speed_bump", "--road-map-resolution", "0.04"]
    assert main(["synth", str(bag), "--drive", *args]) == 0
    runs = {}
    for flag in ("--map", "--no-map"):
        metrics, out = tmp_path / f"m{flag}.json", tmp_path / f"out{flag}.mcap"
        assert main(["eval", str(bag), flag, "--backend", "bm", "--json", str(metrics), "--out", str(out),
                     "--no-progress"]) == 0
        runs[flag] = (json.loads(metrics.read_text()), out)
    fused, per_frame = runs["--map"][0], runs["--no-map"][0]
    assert fused["map_enabled"] is True and "map" not in per_frame and "map_enabled" not in per_frame
    assert {"abs_err_cm", "coverage_pct", "confident_wrong_pct"} <= set(fused["map"])
    assert 0.0 < fused["map"]["coverage_pct"] <= 100.0 and fused["map"]["windows"] == 10
    assert fused["abs_err_cm"] == per_frame["abs_err_cm"]  # the per-frame estimates do not change
    topics = {t: i.count for t, i in bag_topics(runs["--map"][1]).items()}
    assert topics["/roadbev/map"] == topics["/tf"] == topics["/roadbev/preview"] == 10
    assert "/roadbev/map" not in {t for t in bag_topics(runs["--no-map"][1])}
    references = [preview_from_message(item.msg) for item in read_messages(runs["--map"][1], ["/roadbev/preview"])]
    # one stream: every preview in base_link against a contact plane, the body's until the map holds the contacts
    assert {r.frame_id for r in references} == {"base_link"}
    first, last = references[0].profiles.contact_plane, references[-1].profiles.contact_plane
    assert first is not None and first.source in ("road", "body")
    assert last is not None and last.source == "map"
    assert all(r.time_of_arrival is not None for r in references)
    again = tmp_path / "again.json"
    assert main(["eval", str(bag), "--map", "--backend", "bm", "--json", str(again), "--no-progress"]) == 0
    second = json.loads(again.read_text())
    assert second["map"] == fused["map"] and second["preview_at_arrival"] == fused["preview_at_arrival"]


def test_eval_map_needs_odometry(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = tmp_path / "plain.mcap"
    assert main(["synth", str(bag), "--frames", "1", "--image-scale", "0.25", "--quiet"]) == 0
    capsys.readouterr()
    assert main(["eval", str(bag), "--map", "--no-progress"]) == 2
    assert "--map needs odometry" in capsys.readouterr().err
