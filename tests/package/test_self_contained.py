"""No tracked file points outside the repository: the interface is documented under
docs/interface/, so code, tests and docs name pages there, never the design notes the project
started from (only docs/interface/index.md may say where the interface came from)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
# Split so that this file does not name them itself.
OUTSIDE = ("../" "shared", "shared/" "design", "contract" ".md")
MAY_NAME_THE_SOURCE = {"docs/interface/index.md"}
# git's own test for binary content: a NUL byte in the first 8000 bytes.
_SNIFF_BYTES = 8000


def outside_pointers(root: Path, paths: list[str]) -> list[str]:
    """``path:line: text`` for every line of a text file among ``paths`` (relative to ``root``)
    that names a place outside the repository; binary files are skipped."""
    found = []
    for rel in paths:
        path = root / rel
        if rel in MAY_NAME_THE_SOURCE or not path.is_file():
            continue
        with path.open("rb") as fh:
            if b"\0" in fh.read(_SNIFF_BYTES):
                continue
        text = path.read_bytes().decode("utf-8", errors="replace")
        for number, line in enumerate(text.splitlines(), 1):
            if any(name in line for name in OUTSIDE):
                found.append(f"{rel}:{number}: {line.strip()}")
    return found


def _tracked_files() -> list[str]:
    if shutil.which("git") is None or not (REPO / ".git").exists():
        pytest.skip("not a git checkout")
    out = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, check=True).stdout
    return [name for name in out.decode().split("\0") if name]


def test_no_tracked_file_points_outside_the_repository() -> None:
    tracked = _tracked_files()
    assert "README.md" in tracked and len(tracked) > 100
    assert outside_pointers(REPO, tracked) == []


# A pointer outside, built so that this file does not hold one.
_POINTER = "/".join(["..", "shared", "design", "contract" ".md"])


def test_a_pointer_outside_is_found_and_binary_files_are_skipped(tmp_path: Path) -> None:
    (tmp_path / "a.py").write_text(f'"""Frames (see {_POINTER})."""\nx = 1\n')
    (tmp_path / "b.md").write_text("the interface: docs/interface/bags.md\n")
    (tmp_path / "c.bin").write_bytes(b"\0\1../" b"shared")
    (tmp_path / "docs" / "interface").mkdir(parents=True)
    (tmp_path / "docs" / "interface" / "index.md").write_text("from " "contract" ".md upstream\n")
    found = outside_pointers(tmp_path, ["a.py", "b.md", "c.bin", "docs/interface/index.md", "gone.txt"])
    assert found == [f'a.py:1: """Frames (see {_POINTER})."""']
