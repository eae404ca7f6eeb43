"""The docs' tables come from the committed results: every marked table on the README and on the
pages under docs/ is what its result files give now, every result file is quoted somewhere, and
the renderers read the results' structure."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from benchmarks import doc_tables
from benchmarks.common import RESULTS

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
PAGES = doc_tables.doc_pages(ROOT)


def _marked() -> dict[Path, list[str]]:
    return {page: doc_tables.marked_tables(page.read_text()) for page in PAGES}


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_marked_table_of_a_page_equals_its_results(page: Path) -> None:
    assert doc_tables.check_page(page) == [], "run: python -m benchmarks.doc_tables --write"


def test_the_results_pages_quote_every_table_and_every_result_file() -> None:
    marked = _marked()
    results = {n for page, names in marked.items() if "results" in page.parts for n in names}
    assert set(doc_tables.TABLES) <= results, "tables no results page quotes"
    committed = {str(p.relative_to(RESULTS)) for p in RESULTS.rglob("*.json")}
    assert committed <= doc_tables.sources(sorted(results)), "result files no table quotes"


def test_the_readme_quotes_the_demo_from_its_result_file() -> None:
    assert "demo" in doc_tables.marked_tables(README.read_text())


def test_a_table_ends_with_the_command_machine_and_commit_its_file_records() -> None:
    text = doc_tables.render("table1")
    assert text.splitlines()[-1].startswith("Command: `python -m benchmarks.run_all")
    assert "Machine: AMD EPYC" in text and "Commit `" in text
    # a file without a command of its own gets the table's documented one
    assert "Command: `.venv/bin/python -m benchmarks.bench_labels`." in doc_tables.render("labels")


def test_provenance_says_only_what_the_file_records() -> None:
    full = {"command": "python -m x --y", "machine": {"cpu": "CPU", "cores": 4, "torch": "2.0", "torch_threads": 1,
                                                      "git_commit": "abc1234", "time_utc": "2026-01-02T03:04:05Z"}}
    assert doc_tables.provenance(full) == ("Command: `python -m x --y`. Machine: CPU, 4 cores, torch 2.0 "
                                           "(torch threads: 1). Commit `abc1234`, 2026-01-02.")
    assert doc_tables.provenance({"machine": "x86_64, 2 cores"}, "make demo") == (
        "Command: `make demo`. Machine: x86_64, 2 cores.")
    assert doc_tables.provenance({}) == ""


def test_a_stale_table_is_found_and_rewritten(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text("intro\n<!-- table: ride_budget -->\n| old | table |\n<!-- /table -->\nend\n")
    assert doc_tables.check_page(page) == ["ride_budget"]
    assert doc_tables.rewrite_page(page) == ["ride_budget"]
    assert doc_tables.check_page(page) == []
    text = page.read_text()
    assert text.startswith("intro\n<!-- table: ride_budget -->\n|") and text.endswith("<!-- /table -->\nend\n")
    with pytest.raises(KeyError):
        doc_tables.render("no_such_table")


def test_the_command_checks_and_rewrites_pages(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    page = tmp_path / "page.md"
    page.write_text("<!-- table: labels -->\nstale\n<!-- /table -->\n")
    assert doc_tables.main(["--check", str(page)]) == 1
    assert f"{page}: 1 stale table(s) ['labels']" in capsys.readouterr().err
    assert "stale" in page.read_text()  # a check writes nothing
    assert doc_tables.main(["--write", str(page)]) == 0
    assert doc_tables.main(["--check", str(page)]) == 0


def _ride_cell(road: str, shares: dict[str, float], no_preview: float = 2.0,
              true_road: float = 1.0) -> dict[str, Any]:
    rows = {"no_preview": {"mean": {"wk_rms_mps2": no_preview}}, "true_road": {"mean": {"wk_rms_mps2": true_road}}}
    arrival = {name: {"points": 100, "coverage_pct": 100.0, "features_abs_err_cm": 1.0, "features_points": 10}
               for name in shares if name != "ceiling"}
    return {"road": road, "speed_mps": 20.0, "rendered": True,
            "rates": {"10": {"share": shares, "rows": rows, "arrival": arrival}}}


def _ride_run(*cells: dict[str, Any]) -> dict[str, Any]:
    return {"candidates": [{"name": "cand"}], "cells": [*cells, {**cells[0], "rendered": False}]}


def test_road_by_road_tables_take_the_mean_and_worst_drive_of_each_road() -> None:
    run = _ride_run(_ride_cell("bumps", {"ceiling": 0.9, "cand": 0.8, "cand:true_surface": 0.9}),
                    _ride_cell("bumps", {"ceiling": 0.9, "cand": 0.6, "cand:true_surface": 0.7}, 3.0, 2.0),
                    _ride_cell("potholes", {"ceiling": 0.8, "cand": -0.1, "cand:true_surface": 0.5}))
    roads = doc_tables.ride_roads(run, rows=("ceiling",))
    assert "| Wk no preview / true road (m/s²), bumps | 2.50 / 1.50 |" in roads
    assert "| `ceiling`, bumps | 0.90 (0.90) |" in roads  # perfect rows carry no arrival figure
    assert "| `cand`, bumps | 0.70 (0.60) · 1.00 |" in roads
    assert "| `cand`, potholes | -0.10 (-0.10) · 1.00 |" in roads
    assert roads.endswith("1/2 rendered drives per road kind and cell.")  # the truth-only drive is left out
    budget = doc_tables.ride_budget_roads(run, "cand", stages=("shipped", "true_surface", "true_far"))
    assert "| bumps: as shipped | 0.70 |" in budget
    assert "| potholes: true heights on the other answered cells | 0.50 |" in budget
    assert "true heights on the far field" not in budget  # a stage the run did not take has no row
    applied = _ride_run(_ride_cell("bumps", {"cand": 0.5}), _ride_cell("potholes", {"cand": -1.5}))
    gain = doc_tables.ride_gain_roads(applied, run)
    assert "| `cand`, potholes, the measured gain | -0.10 (-0.10) |" in gain
    assert "| `cand`, potholes, all of it applied | -1.50 (-1.50) |" in gain


def test_the_sigma_at_arrival_table_reads_each_configurations_pooled_arrival() -> None:
    arrival = {"within_1sigma_pct": 96.04, "within_2sigma_pct": 99.2, "confident_wrong_pct": 0.178,
               "mean_sigma_cm": 1.488, "abs_err_cm": 0.315}
    run = {"candidates": [{"name": "cand"}, {"name": "older"}],
           "table": [{"rendered": True, "speed_mps": 20.0, "rate_hz": 10.0,
                      "rows": {"cand": {"arrival": arrival}, "older": {"arrival": {"abs_err_cm": 0.3}}}},
                     {"rendered": False, "speed_mps": 20.0, "rate_hz": 10.0, "rows": {}}]}
    text = doc_tables.ride_arrival_sigma(run)
    assert "| `cand` | 96.0 / 99.2 · 0.18 · 1.49 / 0.32 |" in text
    assert "| `older` | – / – · – · – / 0.30 |" in text  # a run from before the sigma was scored
    assert len(text.splitlines()) == 4  # the truth-only drives carry no candidate


def test_the_baseline_table_names_each_checkpoint_of_a_kind_that_has_several() -> None:
    phase = {"frames": 760, "epochs": 1, "batch_size": 2, "lr": 1e-4, "steps": 380, "seconds": 60.0,
             "command": "roadbev train", "history": [{"epoch": 1, "loss": 0.3, "abs_err": 0.07}]}
    held = {"frames": 2, "training": {"abs_err": 0.1, "relative_err": 0.02},
            "tuning": {"abs_err": 0.2, "relative_err": 0.05}}

    def record(kind: str, path: str) -> dict[str, object]:
        return {"kind": kind, "checkpoint": path, "parameters": 5e5, "error_unit": "m of depth",
                "phases": [phase], "held_out": held}

    alone = doc_tables.baseline_training({"baselines": [record("adabins", "a.pt"), record("gwcnet", "g.pt")]})
    assert "| adabins | 0.50 |" in alone and "a.pt" not in alone
    both = doc_tables.baseline_training({"baselines": [record("adabins", "a.pt"), record("adabins", "b.pt")]})
    assert "| adabins (`a.pt`) | 0.50 |" in both and "| adabins (`b.pt`) | abs. error (m of depth) |" in both


def test_the_demos_drive_table_lists_the_fused_maps_bands_when_its_report_has_them() -> None:
    data = json.loads((RESULTS / "demo.json").read_text())
    fused = data["report"]["drive"]["map_on"]["map"]
    fused["bands"] = [{"x_from_m": 14.0, "x_to_m": 15.0, "abs_err_cm": 1.81, "mean_sigma_cm": 5.35,
                       "within_1sigma_pct": 95.7, "confident_wrong_pct": 0.0, "cells": 1649.0, "windows": 59}]
    assert "| 14 to 15 | 1.81 | 5.35 | 95.7 | 0.00 |" in doc_tables.demo_drive(data)
    fused["bands"] = []
    assert "metres ahead of `base_link`" not in doc_tables.demo_drive(data)
