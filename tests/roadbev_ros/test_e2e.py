"""End to end over real DDS, with processes: replay -> node -> record, online vs offline metrics."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from msg_bridge import bag
from msg_bridge.tf import TransformTree, transforms_from_tf
from roadbev_core.backends import create
from roadbev_core.config import DEFAULT_BACKEND, FarFieldConfig, GridSpec, RoadbevConfig, StereoCamera
from roadbev_lab.evaluation.evalbag import read_eval_bag, write_eval_bag
from roadbev_lab.evaluation.frames import evaluate
from roadbev_lab.evaluation.offline import prepare_bag, run_prepared
from roadbev_lab.evaluation.online import evaluate_online, format_online
from roadbev_lab.synth import DriveConfig, SyntheticDrive
from roadbev_ros.dds import child_env
from roadbev_ros.diagnostics import DROP_KINDS

ROOT = Path(__file__).resolve().parents[2]

FRAMES = 6
METRIC_KEYS = ("frames", "cells", "abs_err_cm", "rmse_cm", "gt_0p5cm_pct", "coverage_pct",
               # the sigma, scored from the recorded maps' uncertainty layer as eval scores Estimate.uncertainty
               "sigma_cells", "within_2sigma_pct", "confident_wrong_pct", "mean_sigma_cm")


@pytest.fixture(scope="session")
def drive_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small evaluation bag: 6 frames at 5 Hz, quarter-resolution images, 100 Hz IMU."""
    path = tmp_path_factory.mktemp("bags") / "drive.mcap"
    camera = StereoCamera.rsrd_half().scaled(0.25)
    write_eval_bag(path, SyntheticDrive(DriveConfig(frames=FRAMES, camera=camera, seed=3)))
    return path


def start(args: list[str], log: Path) -> subprocess.Popen[bytes]:
    with log.open("wb") as out:
        return subprocess.Popen([sys.executable, "-m", "roadbev_cli.cli", *args], stdout=out,
                                stderr=subprocess.STDOUT, env=child_env())


@pytest.fixture
def processes() -> Iterator[list[subprocess.Popen[bytes]]]:
    """Processes started by a test; always ended in teardown."""
    procs: list[subprocess.Popen[bytes]] = []
    yield procs
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.wait(10)


@pytest.mark.parametrize("backend", ["bev_sweep", "bm", DEFAULT_BACKEND])
def test_online_metrics_match_offline(ros: object, drive_bag: Path, tmp_path: Path, backend: str) -> None:
    eval_bag = read_eval_bag(drive_bag)
    offline = evaluate(create(backend, eval_bag.grid), eval_bag, imu=eval_bag.imu).metrics
    result = evaluate_online(drive_bag, tmp_path, backend=backend)
    online = result.metrics
    assert online["online"]["frames_without_output"] == 0, result.node_log
    for key in METRIC_KEYS:
        assert online[key] == pytest.approx(offline[key], rel=1e-6, abs=1e-9), key
    np.testing.assert_allclose(online["band_abs_err_cm"], offline["band_abs_err_cm"], rtol=1e-6)
    assert online["sigma_cells"] > 0
    assert online["reliability"] == offline["reliability"]
    # the recording holds every output: a map and a preview per frame, and diagnostics
    topics = bag.bag_topics(result.recorded)
    assert topics["/roadbev/elevation"].count == FRAMES
    assert topics["/roadbev/preview"].count == FRAMES
    assert topics["/diagnostics"].count >= 1
    assert result.diagnostics["backend"] == backend
    assert format_online(online).startswith(f"{backend} (lockstep): frames {FRAMES}")
    assert int(result.diagnostics["outputs"]) == FRAMES


def test_timed_replay_every_frame_is_an_output_or_a_counted_drop(ros: object, drive_bag: Path,
                                                                  tmp_path: Path) -> None:
    # a params file for the node: node section + wildcard, as on a vehicle
    params = tmp_path / "params.yaml"
    params.write_text("/**:\n  ros__parameters:\n    sync_slop_s: 0.01\nroadbev:\n  ros__parameters:\n"
                      "    diagnostics_period_s: 0.5\n")
    result = evaluate_online(drive_bag, tmp_path / "out", backend="bm", rate=2.0, params_file=params)
    node = result.diagnostics
    drops = sum(int(node[k]) for k in DROP_KINDS)
    assert int(node["frames_in"]) == FRAMES
    assert int(node["outputs"]) + drops == FRAMES
    assert result.metrics["online"]["outputs_matched"] == int(node["outputs"])
    assert result.metrics["online"]["frames_without_output"] == drops


def test_replay_and_record_commands_round_trip_raw_bytes(drive_bag: Path, tmp_path: Path,
                                                         processes: list[subprocess.Popen[bytes]]) -> None:
    out = tmp_path / "rec.mcap"
    topics = ["/stereo/left/image_rect", "/imu/data", "/roadbev/grid_config"]
    processes.append(start(["record", str(out), "--topics", *topics], tmp_path / "record.log"))
    replay = start(["replay", str(drive_bag), "--topics", *topics, "--wait-for-subscribers", "20",
                    "--json", str(tmp_path / "replay.json")], tmp_path / "replay.log")
    processes.append(replay)
    assert replay.wait(60) == 0, (tmp_path / "replay.log").read_text()
    time.sleep(0.5)
    processes[0].send_signal(signal.SIGTERM)  # the recorder closes its file cleanly
    assert processes[0].wait(20) == 0, (tmp_path / "record.log").read_text()
    original = {t: [m for m in bag.read_messages(drive_bag, [t], raw=True)] for t in topics}
    recorded = {t: [m for m in bag.read_messages(out, [t], raw=True)] for t in topics}
    for topic in topics:
        assert len(recorded[topic]) == len(original[topic]), topic
        for rec, orig in zip(recorded[topic], original[topic], strict=True):
            data, expected = bytes(rec.msg), bytes(orig.msg)
            # identical bytes; DDS may add the payload's trailing alignment padding (< 4 zeros)
            assert data[: len(expected)] == expected, topic
            assert len(data) - len(expected) < 4 and not any(data[len(expected):]), topic
    # published with the bag's timing: receive times keep the log-time spacing
    sent = np.array([m.log_time_ns for m in original["/imu/data"]], dtype=np.float64) * 1e-9
    got = np.array([m.log_time_ns for m in recorded["/imu/data"]], dtype=np.float64) * 1e-9
    error = np.abs((got - got[0]) - (sent - sent[0]))
    assert np.median(error) < 0.01 and np.percentile(error, 90) < 0.05, error


def test_node_command_rejects_a_nonsense_params_file(tmp_path: Path) -> None:
    params = tmp_path / "bad.yaml"
    params.write_text("roadbev:\n  ros__parameters:\n    resolution: 0.07\n")
    proc = subprocess.run([sys.executable, "-m", "roadbev_cli.cli", "node", "--params", str(params),
                           "--backend", "bm"], capture_output=True, text=True, timeout=60, env=child_env())
    assert proc.returncode == 2
    assert "whole number" in proc.stderr


def test_replay_command_refuses_a_missing_bag(tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "roadbev_cli.cli", "replay", str(tmp_path / "nope.mcap")],
                          capture_output=True, text=True, timeout=60, env={**os.environ})
    assert proc.returncode == 2 and "not found" in proc.stderr


def test_sample_bag_compressed_images_online_match_offline(ros: object, tmp_path: Path) -> None:
    """The shipped sample bag (JPEG images, 960x528): image_transport:=compressed end to end."""
    sample = Path(__file__).resolve().parents[2] / "bags" / "sample_drive.mcap"
    if not sample.exists():
        pytest.skip("bags/sample_drive.mcap is not in this checkout")
    eval_bag = read_eval_bag(sample)
    assert eval_bag.compressed
    offline = evaluate(create("bm", eval_bag.grid), eval_bag, imu=eval_bag.imu).metrics
    result = evaluate_online(sample, tmp_path, backend="bm")
    assert result.metrics["online"]["frames_without_output"] == 0, result.node_log
    for key in METRIC_KEYS:
        assert result.metrics[key] == pytest.approx(offline[key], rel=1e-6, abs=1e-9), key


def test_a_looped_replay_resets_with_one_warning_a_pass(drive_bag: Path, tmp_path: Path,
                                                         processes: list[subprocess.Popen[bytes]]) -> None:
    """`roadbev replay --loop --clock` into a node on use_sim_time: each pass (the bag's 1 s of
    stamps jumps back and stays back) is one reset with one WARN, counted, never a problem."""
    node_log, recorded = tmp_path / "node.log", tmp_path / "diag.mcap"
    processes.append(start(["node", "--backend", "bm", "--ros-args", "-p", "use_sim_time:=true",
                            "-p", "diagnostics_period_s:=0.25"], node_log))
    processes.append(start(["record", str(recorded), "--topics", "/diagnostics"], tmp_path / "record.log"))
    replay = start(["replay", str(drive_bag), "--loop", "--clock", "--json", str(tmp_path / "replay.json")],
                   tmp_path / "replay.log")
    processes.append(replay)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and node_log.read_text().count("stamps went back") < 2:
        time.sleep(0.2)
    time.sleep(0.5)
    replay.send_signal(signal.SIGINT)
    assert replay.wait(20) == 0, (tmp_path / "replay.log").read_text()
    time.sleep(1.0)
    for proc in (processes[1], processes[0]):  # the recorder, then the node
        proc.send_signal(signal.SIGINT)
        assert proc.wait(20) == 0
    log = node_log.read_text()
    jumps = log.count("stamps went back")
    assert jumps >= 2, log
    warnings = [line for line in log.splitlines() if "[WARN]" in line]
    assert len(warnings) == jumps and all("stamps went back" in w for w in warnings), log
    assert "[ERROR]" not in log, log
    statuses = [m.msg.status[0] for m in bag.read_messages(recorded, ["/diagnostics"])]
    values = [{kv.key: kv.value for kv in s.values} for s in statuses]
    assert int(values[-1]["time_jumps"]) == jumps
    assert not any(k.startswith("problem.") for k in values[-1]), values[-1]
    for status, v in zip(statuses, values, strict=True):
        if float(v["input_rate_hz"]) > 0:  # while the bag plays
            assert status.level != bytes([1]) or "coverage" in status.message, status.message


def test_a_drive_replayed_into_the_node_gives_the_fused_map_and_previews_of_eval_map(ros: object,
                                                                                     tmp_path: Path) -> None:
    """Online == offline for the map: the node fed over DDS (/odom, /tf_static, images, IMU)
    publishes the previews and maps that ``roadbev eval --map`` computes, scored the same."""
    import json

    from roadbev_cli.cli import main

    drive = tmp_path / "drive.mcap"
    assert main(["synth", str(drive), "--drive", "--duration", "0.8", "--rate", "10", "--speed", "8",
                 "--image-scale", "0.25", "--features", "speed_bump", "--road-map-resolution", "0.04",
                 "--quiet"]) == 0
    offline_json = tmp_path / "offline.json"
    # the default configuration, as the node and `roadbev eval` run it without being told one
    assert main(["eval", str(drive), "--map", "--json", str(offline_json), "--no-progress"]) == 0
    offline = json.loads(offline_json.read_text())
    assert offline["backend"] == DEFAULT_BACKEND
    result = evaluate_online(drive, tmp_path / "online", node_params={"publish_odom_tf": True})
    online = result.metrics
    assert online["online"]["frames_without_output"] == 0, result.node_log
    recorded = bag.bag_topics(result.recorded)
    assert recorded["/roadbev/map"].count == 8
    # what a viewer needs to place the outputs: the node's TF (per frame, and odom -> base_link
    # from the odometry) and the replayed mount join every frame the outputs and the shipped
    # viewer configs name to RViz's fixed frame
    assert recorded["/tf"].count > 8 and recorded["/tf_static"].count == 1
    tree = TransformTree(tf for item in bag.read_messages(result.recorded, ["/tf", "/tf_static"])
                         for tf in transforms_from_tf(item.msg))
    outputs = {item.msg.header.frame_id for item in bag.read_messages(
        result.recorded, ["/roadbev/elevation", "/roadbev/preview", "/roadbev/map"])}
    configs = (ROOT / "config" / "roadbev.rviz").read_text() + (ROOT / "config" / "roadbev.foxglove.json").read_text()
    named = set(re.findall(r'(?:Fixed Frame: |"followTf": "|"frameId": ")(\w+)', configs))
    assert {"odom", "base_link"} <= named and {"roadbev_road", "base_link", "odom"} <= outputs
    for frame in sorted(named | outputs):
        tree.lookup("odom", frame)  # raises when a frame is not joined to the fixed frame
    for section in ("preview_at_arrival", "map"):
        for key, value in offline[section].items():
            if isinstance(value, float):
                assert online[section][key] == pytest.approx(value, rel=1e-5, abs=1e-6), (section, key)


def test_the_far_field_online_matches_offline(ros: object, tmp_path: Path) -> None:
    path = tmp_path / "far.mcap"
    camera = StereoCamera.rsrd_half().scaled(0.25)  # the images of the other end-to-end tests
    far_grid = FarFieldConfig().grid(GridSpec())
    write_eval_bag(path, SyntheticDrive(DriveConfig(frames=3, camera=camera, seed=5, far_grid=far_grid)))
    offline = run_prepared(prepare_bag(path, RoadbevConfig.from_params({"backend": "bm"}))).metrics["far_field"]
    result = evaluate_online(path, tmp_path / "online", backend="bm", node_params={"far_field.enabled": True})
    online = result.metrics["far_field"]
    assert result.metrics["online"]["frames_without_output"] == 0, result.node_log
    assert offline["estimated"] and offline["cells"] > 0 and offline["frames_with_truth"] == 3
    for key in ("frames_with_truth", "labelled_cells", "cells", "abs_err_cm", "coverage_pct", "sigma_cells",
                "within_2sigma_pct", "confident_wrong_pct"):
        assert online[key] == pytest.approx(offline[key], rel=1e-6, abs=1e-9), key
    assert [b["cells"] for b in online["bands"]] == [b["cells"] for b in offline["bands"]]
    assert bag.bag_topics(result.recorded)["/roadbev/elevation_far"].count == 3
