"""bench_map: the map stage timed over repeated passes of one drive, each frame's best pass kept."""

from __future__ import annotations

import json
from pathlib import Path

from benchmarks import bench_map


def test_each_frame_keeps_its_best_pass(tmp_path: Path) -> None:
    out = tmp_path / "map_stage.json"
    assert bench_map.main(["--frames", "12", "--repeats", "2", "--out", str(out)]) == 0
    record = json.loads(out.read_text())
    assert record["repeats"] == 2 and record["frames"] == 12
    for key in ("map_stage_ms", "fusion_ms"):
        best, first = record[key], record["first_pass"][key]
        assert 0.0 < best["p50"] <= first["p50"] and best["mean"] <= first["mean"], (key, best, first)
        assert best["p50"] <= best["p95"]
    # the fusion is part of the map stage
    assert record["fusion_ms"]["mean"] < record["map_stage_ms"]["mean"]
    assert record["fusion_target_met"] == (record["fusion_ms"]["p50"] < record["target_fusion_ms"])
