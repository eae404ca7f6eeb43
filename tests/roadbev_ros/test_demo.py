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
from roadbev_core.metrics import MetricAccumulator
from roadbev_ros.dds import child_env
from roadbev_ros.demo import (
    DemoError,
    DemoOptions,
    DemoResult,
    _node_failure,
    demo_drive_config,
    ensure_demo_bag,
    pick_frames,
    run_demo,
    summary_lines,
)

FRAMES = 4
SCALE = 0.25  # 240 x 132 images: the whole demo in seconds
FIGURES = ("frames.png", "surface.png", "preview.png", "band_error.png", "timing.png")


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> tuple[DemoResult, DemoOptions]:
    root = tmp_path_factory.mktemp("demo")
    options = DemoOptions(frames=FRAMES, out_dir=root / "out", cache_dir=root / "cache", image_scale=SCALE,
                          report_frames=2, progress=False)
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
    from msg_bridge.evalbag import read_eval_bag

    grid = read_eval_bag(result.bag).grid
    recomputed = _recorded_metrics(options.out_dir / "online.mcap", result.bag, grid)
    assert online["frames"] == offline["frames"] == recomputed["frames"] == FRAMES
    assert online["cells"] == recomputed["cells"] > 0
    for key in ("abs_err_cm", "rmse_cm", "gt_0p5cm_pct", "coverage_pct"):
        assert online[key] == pytest.approx(recomputed[key], abs=1e-9), key
        # every frame is processed in lockstep: ROS 2 and `roadbev eval` agree
        assert online[key] == pytest.approx(offline[key], abs=1e-6), key
    assert payload["agreement"]["abs_err_cm"] < 1e-6
    # the 15 distance bands, as in the paper
    assert len(online["band_abs_err_cm"]) == 15
    assert 0.0 < online["abs_err_cm"] < 20.0  # real estimates, not a constant
    lines = summary_lines(result)
    assert any(f"{online['abs_err_cm']:.3f}" in line for line in lines)
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
    from roadbev_ros.demo import _cache_key

    assert _cache_key(demo_drive_config(FRAMES, 1, SCALE)) != _cache_key(config)


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


def test_cli_missing_bag_exits_with_one_line(tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "roadbev_ros.cli", "demo", "--bag", str(tmp_path / "nope.mcap"),
                           "--out", str(tmp_path / "o"), "--no-progress"],
                          capture_output=True, text=True, env=child_env(), timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "bag not found" in proc.stderr


def test_demo_on_a_truncated_bag_without_ground_truth_writes_the_report(demo, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """The readable frames of a cut bag of the user's own drive: maps, previews and timing, no
    error figures, and the report says what was lost."""
    from ._damaged_bags import rewrite, truncate

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
    assert "nothing to score" in (options.out_dir / "index.html").read_text()
