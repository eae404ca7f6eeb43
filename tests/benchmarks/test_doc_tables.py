"""The docs' tables come from the committed results: every marked table on the README is what its
result file gives now, and the renderers read the results' structure."""

from __future__ import annotations

from pathlib import Path

import pytest

from benchmarks import doc_tables

README = Path(__file__).resolve().parents[2] / "README.md"


def test_every_marked_table_of_the_readme_equals_its_results() -> None:
    marked = set(doc_tables.marked_tables(README.read_text()))
    assert {"ride_shares", "ride_budget", "arrival"} <= marked  # the preview's tables are generated
    assert doc_tables.check_page(README) == [], "run: python -m benchmarks.doc_tables --write README.md"


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
