"""bench_far_field: per band of 1 m to the far edge, the physics beside each backend's scores."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import pytest

from benchmarks import doc_tables
from benchmarks.bench_far_field import main


def test_one_frame_gives_every_band_from_the_grid_to_the_far_edge(tmp_path: Path) -> None:
    out = tmp_path / "far_field.json"
    assert main(["--frames", "1", "--backends", "bm", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    bands = data["bands"]
    assert [b["grid"] for b in bands] == ["near"] * 6 + ["far"] * 8
    assert bands[0]["x_from_m"] == 2.16 and bands[-1]["x_to_m"] == 15.0
    assert [b["x_from_m"] for b in bands[6:]] == [7.08, *range(8, 15)]
    # the limit grows with range, the ground sampling coarsens
    assert all(a["limit_sigma_cm"] < b["limit_sigma_cm"] for a, b in itertools.pairwise(bands))
    assert bands[-1]["row_length_cm"] > 15.0 > 1.0 > bands[0]["row_length_cm"]
    assert data["rig"]["far_cell_m"] == pytest.approx(0.12) and data["rig"]["farthest_in_view_m"] < 15.0
    scored = data["backends"]["bm"]
    assert len(scored["bands"]) == len(bands) and scored["far_ms"] > 0
    for band, limit in zip(scored["bands"], bands, strict=True):
        if band["cells"]:
            assert band["ratio_to_limit"] == pytest.approx(band["abs_err_cm"] / limit["limit_abs_err_cm"])
        else:
            assert band["ratio_to_limit"] is None or math.isnan(band["ratio_to_limit"])
    # the docs' table renders from such a file, one row per band
    table = doc_tables.far_field(data)
    assert table.startswith("| band (m) |") and table.count("\n| ") == len(bands) and "`bm`: error" in table


def test_a_backend_with_options_is_scored_under_its_spec(tmp_path: Path) -> None:
    out = tmp_path / "far_field.json"
    assert main(["--frames", "1", "--backends", "bm", "bm:block_size=15", "--out", str(out)]) == 0
    scored = json.loads(out.read_text())["backends"]
    assert list(scored) == ["bm", "bm:block_size=15"]
    # another block size answers other cells: the option reached the backend
    assert scored["bm"]["near"]["coverage_pct"] != scored["bm:block_size=15"]["near"]["coverage_pct"]
    # and it is compared with the plain backend on the cells both answered, band by band
    assert "against" not in scored["bm"]
    against = scored["bm:block_size=15"]["against"]
    assert against["backend"] == "bm" and len(against["bands"]) == len(scored["bm"]["bands"])
    for common, mine, plain in zip(against["bands"], scored["bm:block_size=15"]["bands"], scored["bm"]["bands"],
                                   strict=True):
        assert common["cells"] <= min(mine["cells"], plain["cells"])
        assert common["x_from_m"] == mine["x_from_m"]
    assert sum(b["cells"] for b in against["bands"]) > 0
    table = doc_tables.far_field_against(json.loads(out.read_text()))
    assert table.count("\n| ") == len(against["bands"]) and "`bm:block_size=15`" in table
