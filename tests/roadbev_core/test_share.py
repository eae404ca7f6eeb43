"""Where shared files are found: the source tree first, then the prefixes an install puts them in."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from roadbev_core.share import PACKAGE, find_shared, shared_candidates

ROOT = Path(__file__).resolve().parents[2]


def test_the_source_tree_comes_first() -> None:
    assert find_shared("config/fastdds.xml") == ROOT / "config" / "fastdds.xml"
    assert find_shared("checkpoints") == ROOT / "checkpoints"


def test_an_ament_prefix_is_searched_after_the_venv(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    installed = tmp_path / "install" / "share" / PACKAGE / "checkpoints"
    installed.mkdir(parents=True)
    monkeypatch.setenv("AMENT_PREFIX_PATH", f"{tmp_path / 'other'}:{tmp_path / 'install'}")
    candidates = shared_candidates("checkpoints")
    assert candidates == [ROOT / "checkpoints", Path(sys.prefix) / "share" / PACKAGE / "checkpoints",
                          tmp_path / "other" / "share" / PACKAGE / "checkpoints", installed]
    assert find_shared("checkpoints/nothing_like_it.pt") is None
    (installed / "only_installed.pt").write_bytes(b"")
    assert find_shared("checkpoints/only_installed.pt") == installed / "only_installed.pt"
