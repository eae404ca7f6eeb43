"""A shortened ``roadbev demo`` over real ROS 2: files, figures and numbers of the report."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib import image as mpimg

from msg_bridge import bag
from msg_bridge.grid_map import grid_map_to_arrays
from roadbev_core.config import GridSpec
from roadbev_lab.demo import run as demo_module
from roadbev_lab.demo.drive import DRIVE_SEED, drive_config, features_path
from roadbev_lab.demo.run import (
    DemoError,
    DemoOptions,
    DemoResult,
    _node_failure,
    _truth_profiles,
    demo_drive_config,
    ensure_demo_bag,
    pick_frames,
    run_demo,
    summary_lines,
)
from roadbev_lab.evaluation.arrival import ARRIVAL_KEYS
from roadbev_lab.evaluation.metrics import MetricAccumulator
from roadbev_ros.dds import child_env

FRAMES = 4
SCALE = 0.25  # 240 x 132 images: the whole demo in seconds
FIGURES = ("frames.png", "surface.png", "preview.png", "band_error.png", "reliability.png", "timing.png")
DRIVE_FRAMES = 12  # 1.1 s at 10 Hz: the ride scores 0.7 s after a 0.5 s warm-up
DRIVE_FIGURES = ("drive_map.png", "drive_hazards.png", "drive_arrival.png", "drive_ride.png")


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> tuple[DemoResult, DemoOptions]:
    root = tmp_path_factory.mktemp("demo")
    options = DemoOptions(frames=FRAMES, out_dir=root / "out", cache_dir=root / "cache", image_scale=SCALE,
                          report_frames=2, progress=False, drive_frames=DRIVE_FRAMES)
    return run_demo(options), options


def _recorded_metrics(recorded: Path, bag_path: Path, grid: GridSpec) -> dict[str, Any]:
    """The offline evaluation of the recorded outputs, written out here independently."""
    truths = {}
    for item in bag.read_messages(bag_path, ["/ground_truth/elevation"]):
        d = grid_map_to_arrays(item.msg, base=grid)
        truths[d.stamp_ns] = d.layers["elevation"]
    estimates = {}
    for item in bag.read_messages(recorded, ["/roadbev/elevation"]):
        d = grid_map_to_arrays(item.msg, base=grid)
        estimates[d.stamp_ns] = d.layers["elevation"]
    acc = MetricAccumulator(grid)
    for stamp, truth in sorted(truths.items()):
        estimate = estimates.get(stamp, np.full(grid.shape, np.nan))
        acc.add(np.asarray(estimate, np.float32), np.asarray(truth, np.float32))
    return acc.result().to_dict()


def test_demo_writes_the_report_with_every_figure(demo: tuple[DemoResult, DemoOptions]) -> None:
    _result, options = demo
    out = options.out_dir
    for name in (*FIGURES, "index.html", "report.json", "online.mcap", "node.log"):
        assert (out / name).is_file(), name
    for name in FIGURES:
        img = mpimg.imread(out / name)
        assert img.shape[0] > 200 and img.shape[1] > 300, name
        assert float(img[..., :3].std()) > 0.05, f"{name} looks blank"
    page = (out / "index.html").read_text()
    for name in FIGURES:
        assert f'src="{name}"' in page


def test_report_numbers_equal_the_offline_evaluation_of_the_recorded_outputs(
    demo: tuple[DemoResult, DemoOptions],
) -> None:
    result, options = demo
    payload = json.loads((options.out_dir / "report.json").read_text())
    online = next(r for r in payload["runs"] if r["mode"] == "online")["metrics"]
    offline = next(r for r in payload["runs"] if r["mode"] == "offline")["metrics"]
    from roadbev_lab.evaluation.evalbag import read_eval_bag

    grid = read_eval_bag(result.bag).grid
    recomputed = _recorded_metrics(options.out_dir / "online.mcap", result.bag, grid)
    assert online["frames"] == offline["frames"] == recomputed["frames"] == FRAMES
    assert online["cells"] == recomputed["cells"] > 0
    for key in ("abs_err_cm", "rmse_cm", "gt_0p5cm_pct", "coverage_pct"):
        assert online[key] == pytest.approx(recomputed[key], abs=1e-9), key
        # every frame is processed in lockstep: ROS 2 and `roadbev eval` agree
        assert online[key] == pytest.approx(offline[key], abs=1e-6), key
    assert payload["agreement"]["abs_err_cm"] < 1e-6
    # the sigma columns and the reliability plot: the recorded uncertainty layer scores as eval's sigma
    assert online["sigma_cells"] == offline["sigma_cells"] > 0
    for key in ("within_2sigma_pct", "confident_wrong_pct", "mean_sigma_cm"):
        assert online[key] == pytest.approx(offline[key], abs=1e-6), key
    assert online["reliability"] == offline["reliability"]
    # the 15 distance bands, as in the paper
    assert len(online["band_abs_err_cm"]) == 15
    assert 0.0 < online["abs_err_cm"] < 20.0  # real estimates, not a constant
    lines = summary_lines(result)
    assert any(f"{online['abs_err_cm']:.3f}" in line for line in lines)
    node_row = next(line for line in lines if line.startswith("ROS 2 node"))
    assert node_row.split()[-2:] == [f"{online['within_2sigma_pct']:.1f}", f"{online['confident_wrong_pct']:.2f}"]
    assert str((options.out_dir / "index.html").resolve()) in lines[-1]
    timing = payload["timing"]
    assert len(timing["latency_ms"]) == FRAMES and all(v > 0 for v in timing["latency_ms"])


def test_the_bag_is_cached_by_options(demo: tuple[DemoResult, DemoOptions], tmp_path: Path) -> None:
    result, options = demo
    config = demo_drive_config(FRAMES, 0, SCALE)
    assert options.cache_dir is not None
    path, reused = ensure_demo_bag(config, options.cache_dir)
    assert reused and path == result.bag
    assert not list(options.cache_dir.glob(".partial-*"))  # no half-written bag left behind
    # another seed is another cache entry (checked without rendering it)
    from roadbev_lab.demo.run import _cache_key

    assert _cache_key(demo_drive_config(FRAMES, 1, SCALE)) != _cache_key(config)
    # the drive section's drive, with its true features beside it
    assert result.drive is not None
    drive_path, reused = ensure_demo_bag(drive_config(DRIVE_FRAMES, DRIVE_SEED, SCALE), options.cache_dir)
    assert reused and drive_path == result.drive.bag and features_path(drive_path).is_file()


def test_the_drive_section_shows_the_fused_map_previews_at_arrival_hazards_and_the_ride(
    demo: tuple[DemoResult, DemoOptions],
) -> None:
    result, options = demo
    drive = result.drive
    assert drive is not None and drive.seed == DRIVE_SEED
    out = options.out_dir
    page = (out / "index.html").read_text()
    for name in DRIVE_FIGURES:
        img = mpimg.imread(out / name)
        assert img.shape[0] > 200 and img.shape[1] > 300, name
        assert float(img[..., :3].std()) > 0.05, f"{name} looks blank"
        assert f'src="{name}"' in page
    for heading in ("Preview at arrival", "Hazards on the fused map", "The ride"):
        assert heading in page
    payload = json.loads((out / "report.json").read_text())["drive"]
    on, off = payload["map_on"], payload["map_off"]
    assert set(ARRIVAL_KEYS) <= set(on["preview_at_arrival"]) and set(ARRIVAL_KEYS) <= set(off["preview_at_arrival"])
    assert on["map_enabled"] is True and "map" in on and "map" not in off and "map_enabled" not in off
    assert on["frames"] == off["frames"] == DRIVE_FRAMES
    # the fused map over the drive holds cells along the car's path, with sigma and counts where it holds them
    # (bev_sweep declines much of the real-road range's weak texture at this test's image scale: 16 % held)
    fused = drive.fused
    held = np.isfinite(fused.elevation)
    assert held.mean() > 0.1 and np.all(np.isfinite(fused.uncertainty[held])) and np.all(fused.observations[held] >= 1)
    x0, x1, _, _ = fused.extent()
    assert x0 < float(drive.path_xy[:, 0].max()) and x1 > drive.points_on[0].path.xy[-1, 0]
    # hazards: every scored feature is one of the road's (>= 3 cm), matched or reported missed
    assert payload["hazards"]["reference"] == "placed by the synthesiser"
    assert all(abs(f["height_m"]) >= 0.03 for f in payload["hazards"]["features"])
    # the ride: every source, the ceiling beats the controller without preview, and is the whole gain
    rows = payload["ride"]["rows"]
    assert set(rows) == {"passive", "no_preview", "per_frame", "fused", "true_road"}
    assert rows["true_road"]["mean"]["wk_rms_mps2"] < rows["no_preview"]["mean"]["wk_rms_mps2"]
    assert payload["ride"]["share"]["true_road"] == pytest.approx(1.0)
    assert payload["ride_scored_s"] > 0.3
    lines = summary_lines(result)
    assert any(line.startswith("drive (seed") for line in lines) and any("drive ride" in line for line in lines)


def test_the_drive_numbers_are_those_of_roadbev_eval_map_on_and_off(
    demo: tuple[DemoResult, DemoOptions], tmp_path: Path
) -> None:
    from roadbev_cli.cli import main

    result, _options = demo
    assert result.drive is not None
    for flag, shown in (("--map", result.drive.map_on), ("--no-map", result.drive.map_off)):
        out = tmp_path / f"eval{flag}.json"
        assert main(["eval", str(result.drive.bag), flag, "--json", str(out), "--no-progress"]) == 0
        cli = json.loads(out.read_text())
        for key in ("frames", "cells", "abs_err_cm", "coverage_pct", "band_abs_err_cm", "preview_at_arrival"):
            assert shown[key] == cli[key], (flag, key)
        assert shown.get("map") == cli.get("map"), flag


def test_the_arrival_figure_draws_the_points_the_metric_scores(demo: tuple[DemoResult, DemoOptions]) -> None:
    from roadbev_lab.evaluation.arrival import summarise_points
    from roadbev_lab.evaluation.frames import json_safe

    result, _options = demo
    drive = result.drive
    assert drive is not None
    for points, shown in ((drive.points_on, drive.map_on), (drive.points_off, drive.map_off)):
        assert [p.path.name for p in points] == ["front_left", "front_right"]
        summary = json_safe(summarise_points(points, shown["preview_at_arrival"]["lead_time_s"]))
        for key in ARRIVAL_KEYS:
            assert summary[key] == pytest.approx(shown["preview_at_arrival"][key], nan_ok=True), key
        for p in points:  # the plotted height minus the truth is the scored error
            ok = p.covered
            assert ok.any()
            assert p.preview_z[ok] - p.path.height[ok] == pytest.approx(p.error[ok], abs=1e-9)
            assert np.all(np.isnan(p.preview_z[~np.isfinite(p.error) & p.known]))


def test_the_demo_on_a_drive_bag_shows_the_nodes_previews_at_arrival_next_to_eval_map(
    demo: tuple[DemoResult, DemoOptions], tmp_path: Path
) -> None:
    """``roadbev demo --bag DRIVE``: the ROS 2 stage runs on the drive (the node with its map on)
    and the drive section on the same bag; the node's recorded previews score as ``eval --map``."""
    result, _options = demo
    assert result.drive is not None
    options = DemoOptions(bag=result.drive.bag, out_dir=tmp_path / "out", backend="bm", report_frames=1,
                          progress=False)
    run = run_demo(options)
    drive = run.drive
    assert drive is not None and drive.bag == result.drive.bag and drive.seed is None and drive.online is not None
    assert run.online["online"]["frames_without_output"] == 0
    for section in ("preview_at_arrival", "map"):
        for key, value in drive.map_on[section].items():
            if isinstance(value, float):
                assert drive.online[section][key] == pytest.approx(value, rel=1e-5, abs=1e-6), (section, key)
    assert "ROS 2 node (recorded outputs of this bag)" in (options.out_dir / "index.html").read_text()


def test_a_given_drive_bag_that_cannot_be_scored_leaves_the_section_out_with_the_reason(
    demo: tuple[DemoResult, DemoOptions], tmp_path: Path
) -> None:
    from roadbev_lab.demo.run import _drive_stage
    from tests.roadbev_ros._damaged_bags import rewrite

    result, _options = demo
    assert result.drive is not None
    no_odom = tmp_path / "no_odom.mcap"
    rewrite(result.drive.bag, no_odom, drop=["/odom"])
    stages: dict[str, float] = {}
    section, note = _drive_stage(DemoOptions(bag=no_odom, progress=False), no_odom, stages)
    assert section is None and note.startswith("No drive section") and "odometry" in note
    assert _drive_stage(DemoOptions(drive=False), no_odom, stages) == (None, "")


def test_pick_frames_prefers_relief_and_spreads() -> None:
    flat = np.zeros((4, 4), np.float32)
    bumpy = flat.copy()
    bumpy[0, 0] = 0.1
    truths = [flat, bumpy, bumpy, flat, flat, flat, bumpy, None]
    chosen = pick_frames(truths, 2)
    assert len(chosen) == 2 and 6 in chosen and (1 in chosen or 2 in chosen)
    assert pick_frames([], 3) == []


def test_node_without_output_is_a_one_line_reason() -> None:
    metrics = {"online": {"outputs_matched": 0, "frames_published": 4}}
    reason = _node_failure(metrics, "starting\nTraceback...\nBackendError: no checkpoint\n")
    assert reason is not None and "no output" in reason and "no checkpoint" in reason and "\n" not in reason
    assert _node_failure({"online": {"outputs_matched": 3}}, "") is None


def test_options_refuse_bad_values() -> None:
    with pytest.raises(DemoError):
        DemoOptions(frames=0)
    with pytest.raises(DemoError):
        DemoOptions(image_scale=0.0)
    with pytest.raises(DemoError, match="drive-frames"):
        DemoOptions(drive_frames=2)


def test_cli_missing_bag_exits_with_one_line(tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "roadbev_cli.cli", "demo", "--bag", str(tmp_path / "nope.mcap"),
                           "--out", str(tmp_path / "o"), "--no-progress"],
                          capture_output=True, text=True, env=child_env(), timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "bag not found" in proc.stderr
    assert not any(tmp_path.glob("o*"))  # it failed before writing anything: no folder left


def test_a_failed_demo_keeps_the_last_report_and_names_what_it_wrote(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    from roadbev_cli import cli
    from roadbev_cli.commands import demo as demo_command

    out = tmp_path / "report"
    out.mkdir()
    (out / "index.html").write_text("the last good report")

    def failing(options: DemoOptions, **_kwargs: object) -> DemoResult:
        options.out_dir.mkdir(parents=True)
        (options.out_dir / "node.log").write_text("what the node said")
        raise DemoError("ROS 2 stage failed: the node exited")

    monkeypatch.setattr(demo_command, "run_demo", failing)
    assert cli.main(["demo", "--out", str(out), "--no-progress", "--no-drive"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"roadbev demo: error: ROS 2 stage failed: the node exited; what it wrote is in "
                   f"{tmp_path / 'report.failed'} (node.log); {out} is as it was")
    assert (out / "index.html").read_text() == "the last good report"
    assert (tmp_path / "report.failed" / "node.log").is_file() and not (tmp_path / "report.partial").exists()


def test_demo_on_a_truncated_bag_without_ground_truth_writes_the_report(demo, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """The readable frames of a cut bag of the user's own drive: maps, previews and timing, no
    error figures, and the report says what was lost."""
    from tests.roadbev_ros._damaged_bags import rewrite, truncate

    result, _options = demo
    drive = tmp_path / "drive.mcap"
    rewrite(result.bag, drive, drop=["/ground_truth/elevation"])
    cut = truncate(drive, tmp_path / "cut.mcap", 0.8)
    options = DemoOptions(bag=cut, out_dir=tmp_path / "out", backend="bm", report_frames=1, progress=False)
    lines: list[str] = []
    partial = run_demo(options, log=lines.append)
    files = {p.name for p in options.out_dir.iterdir()}
    assert {"index.html", "report.json", "frames.png", "preview.png", "timing.png"} <= files
    assert "band_error.png" not in files
    payload = json.loads((options.out_dir / "report.json").read_text())
    assert payload["losses"] and any("breaks off" in line for line in payload["losses"])
    assert any("breaks off" in line for line in lines)
    # every whole frame the node got was answered (a frame cut in half is not waited for)
    assert 0 < partial.online["frames"] < FRAMES and partial.online["online"]["frames_without_output"] == 0
    assert partial.online["frames"] <= partial.offline["frames"] < FRAMES and partial.offline["cells"] == 0
    page = (options.out_dir / "index.html").read_text()
    assert "nothing to score" in page
    # not a drive bag: no drive section, and the page says why
    assert partial.drive is None and "No drive section" in page and "drive_map.png" not in files


def test_truth_profiles_mark_the_samples_whose_tyre_footprint_is_hidden() -> None:
    from roadbev_core.preview import wheel_track_profiles

    grid = GridSpec()
    truth = np.zeros(grid.shape)
    like = wheel_track_profiles(truth, None, grid, track_offsets_m=[0.8, -0.8], tyre_width_m=0.2, spacing_m=0.1)
    hidden = np.zeros(grid.shape, bool)
    x = grid.x_centres()
    hidden[(x > 5.0) & (x < 5.5), :] = True  # a strip across both tracks
    col = int(np.argmin(np.abs(grid.y_centres() - 0.8)))
    hidden[(x > 3.0) & (x < 3.3), col] = True  # one column under the left tyre only
    left, right = _truth_profiles(truth, grid, like, hidden)
    assert left.hidden is not None and right.hidden is not None
    d = left.distance_m
    strip = (d > 5.0 + 0.05) & (d < 5.5 - 0.05)  # samples whose footprint lies inside the strip
    assert left.hidden[strip].all() and right.hidden[strip].all()
    assert left.hidden[(d > 3.05) & (d < 3.25)].all() and not right.hidden[(d > 2.9) & (d < 3.4)].any()
    assert not left.hidden[(d < 2.9) | ((d > 3.4) & (d < 4.9)) | (d > 5.6)].any()
    (no_mask, _) = _truth_profiles(truth, grid, like)
    assert no_mask.hidden is None and no_mask.sigma_m is None


def test_the_demo_report_bar_counts_files(monkeypatch: pytest.MonkeyPatch) -> None:
    units: list[str] = []
    monkeypatch.setattr(demo_module, "progress_bar", lambda **kw: units.append(kw["unit"]))
    demo_module._bar(None, "report", True, unit="file")
    demo_module._bar(3, "offline", True)
    assert units == ["file", "frame"]
