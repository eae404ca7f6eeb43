"""bench_kitti's rectification-residual rows: every offset asked, 0 included, once each, in order."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from benchmarks import bench_kitti


def test_row_offset_sensitivity_runs_each_backend_at_each_offset_and_the_recorded_frame(
        monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[tuple[str, float]] = []

    def fake_run(name: str, bag_path: Path, row_offset_px: float = 0.0) -> dict[str, Any]:
        calls.append((name, row_offset_px))
        return {"backend": name, "coverage_pct": 50.0 - 10.0 * abs(row_offset_px), "abs_err_cm": 1.0,
                "confident_wrong_pct": 2.0, "rmse_cm": 9.9}

    monkeypatch.setattr(bench_kitti, "run_backend", fake_run)
    rows = bench_kitti.row_offset_sensitivity(["bm", "sgbm"], Path("unused.mcap"), [0.5, -0.25, 0.5])
    assert calls == [(n, o) for n in ("bm", "sgbm") for o in (-0.25, 0.0, 0.5)]
    assert [r["row_offset_px"] for r in rows["bm"]] == [-0.25, 0.0, 0.5]
    assert rows["sgbm"][1] == {"row_offset_px": 0.0, "coverage_pct": 50.0, "abs_err_cm": 1.0,
                               "confident_wrong_pct": 2.0}
