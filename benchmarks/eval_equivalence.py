"""Whether a change kept behaviour: the eval JSON of every backend, before and after, timings aside.

Run (from the repository root)::

    .venv/bin/python -m benchmarks.eval_equivalence --before REV [--after REV] [--drive BAG]

For each revision (``--after`` defaults to the working tree) a git worktree is checked out in a
temporary folder and ``roadbev eval`` runs every backend on ``bags/sample_drive.mcap`` and, with
``--map``, on a drive bag (``--drive``; by default the one the demo caches). The JSONs are
compared key by key without the keys that time the run (``fps``, ``*_ms``, ``timed_frames``) and
the bag's path. Exit 0 when every pair is equal; the differing keys are printed otherwise. Writes
``--out`` (JSON) when given.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
BACKENDS = ("bev_sweep", "bm", "sgbm", "stereo", "mono", "ensemble")
TIMING_KEYS = frozenset({"fps", "timed_frames", "bag"})
# Runs the command line of the checked-out revision (before the layout of roadbev_cli it lived in
# roadbev_ros.cli); the tree's folder decides, as the installed package may have the other layout.
_MAIN = "import importlib, sys; sys.exit(importlib.import_module(sys.argv.pop(1)).main())"


def without_timings(value: Any) -> Any:
    """``value`` (a JSON document) without the keys that time the run."""
    if isinstance(value, dict):
        return {k: without_timings(v) for k, v in value.items() if k not in TIMING_KEYS and not k.endswith("_ms")}
    if isinstance(value, list):
        return [without_timings(v) for v in value]
    return value


def differing_keys(before: dict[str, Any], after: dict[str, Any]) -> list[str]:
    """Top-level keys whose values differ (timings aside)."""
    a, b = without_timings(before), without_timings(after)
    return sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))


@contextmanager
def checkout(rev: str | None) -> Iterator[Path]:
    """The tree at ``rev`` (a temporary git worktree), or the working tree for None."""
    if rev is None:
        yield REPO
        return
    with tempfile.TemporaryDirectory() as tmp:
        tree = Path(tmp) / "tree"
        subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", "-q", str(tree), rev], check=True)
        try:
            yield tree
        finally:
            subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(tree)], check=False)


def evaluate_all(tree: Path, bags: list[tuple[str, Path, list[str]]], out: Path) -> dict[str, dict[str, Any]]:
    """``roadbev eval`` of every backend on every bag with ``tree``'s code."""
    results: dict[str, dict[str, Any]] = {}
    env = {**os.environ, "PYTHONPATH": str(tree)}
    cli = "roadbev_cli.cli" if (tree / "roadbev_cli").is_dir() else "roadbev_ros.cli"
    for label, bag, flags in bags:
        for backend in BACKENDS:
            name = f"{label}_{backend}"
            target = out / f"{name}.json"
            proc = subprocess.run([sys.executable, "-c", _MAIN, cli, "eval", str(bag), "--backend", backend,
                                   "--json", str(target), *flags], cwd=tree, env=env, capture_output=True, text=True)
            if proc.returncode != 0:
                raise RuntimeError(f"{name} at {tree}: exit {proc.returncode}: {proc.stderr.strip()[-400:]}")
            results[name] = json.loads(target.read_text())
    return results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", required=True, help="the revision before the change")
    parser.add_argument("--after", default=None, help="the revision after it (default: the working tree)")
    parser.add_argument("--drive", type=Path, default=None,
                        help="a drive bag evaluated with --map (default: the demo's cached drive under .cache/roadbev)")
    parser.add_argument("--out", type=Path, default=None, help="write the comparison here (JSON)")
    args = parser.parse_args(argv)
    drive = args.drive or next(iter(sorted((REPO / ".cache" / "roadbev").glob("drive_*.mcap"))), None)
    if drive is None or not drive.exists():
        parser.error("no drive bag: give --drive (roadbev synth --drive makes one)")
    bags = [("sample", REPO / "bags" / "sample_drive.mcap", []), ("drive", drive.resolve(), ["--map"])]
    with tempfile.TemporaryDirectory() as tmp:
        runs = []
        for side, rev in (("before", args.before), ("after", args.after)):
            folder = Path(tmp) / side
            folder.mkdir()
            with checkout(rev) as tree:
                runs.append(evaluate_all(tree, bags, folder))
    before, after = runs
    rows = {name: differing_keys(before[name], after[name]) for name in before}
    for name, keys in rows.items():
        print(f"{name}: {'same' if not keys else 'differs in ' + ', '.join(keys)}")
    if args.out is not None:
        args.out.write_text(json.dumps({"before": args.before, "after": args.after or "working tree",
                                        "drive": str(drive), "differing_keys": rows}, indent=2) + "\n")
    return 0 if not any(rows.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
