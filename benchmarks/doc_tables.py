"""Tables of the docs, generated from the committed benchmark results.

A page quotes a table between two markers, ``<!-- table: NAME -->`` and ``<!-- /table -->``;
:func:`render` makes the table NAME from its result file and :func:`check_page` says which marked
tables on a page differ from what the results give now (the tests run it on the README, so a
figure there cannot drift from the JSON it came from).

Run: ``.venv/bin/python -m benchmarks.doc_tables [--write README.md] [NAME ...]`` prints the tables
(or rewrites the marked blocks of a page in place).
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import re
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from benchmarks.common import RESULTS
from benchmarks.preview_budget import STAGE_SEPARATOR, STAGES
from roadbev_core.config import DEFAULT_BACKEND

__all__ = ["TABLES", "check_page", "marked_tables", "render", "rewrite_page"]

_BLOCK = re.compile(r"(<!-- table: (?P<name>[a-z0-9_]+) -->\n)(?P<body>.*?)(<!-- /table -->)", re.S)
_STAGE_TITLES = {
    "shipped": "as shipped",
    "true_answered": "true heights on the answered cells",
    "true_all": "true heights on every cell",
    "true_odometry": "true odometry",
    "true_datum": "true datum (map z)",
    "true_plane": "true contact plane",
    "no_latency": "no latency (every frame, at its stamp)",
}


def _load(name: str) -> dict[str, Any]:
    return dict(json.loads((RESULTS / name).read_text()))


def _fmt(value: float | None, digits: int = 2) -> str:
    return "–" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _arrival(a: Mapping[str, Any] | None, error: str = "abs_err_cm") -> str:
    """All / feature points (cm) and coverage (%) of one preview-at-arrival summary."""
    if not a:
        return "–"
    return f"{_fmt(a[error], 3)} / {_fmt(a['features_abs_err_cm'], 3)} ({_fmt(a['coverage_pct'], 1)})"


def _cells(table: Sequence[Mapping[str, Any]], rendered: bool) -> list[Mapping[str, Any]]:
    return sorted((t for t in table if t["rendered"] == rendered), key=lambda t: (t["speed_mps"], t["rate_hz"]))


def _header(cells: Sequence[Mapping[str, Any]], first: str) -> list[str]:
    head = [first] + [f"{c['speed_mps']:g} m/s, {c['rate_hz']:g} Hz" for c in cells]
    return ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]


def ride_shares(data: Mapping[str, Any]) -> str:
    """Share of the true road's gain per configuration on the rendered drives: mean ± std over the
    drives, and the worst drive."""
    cells = _cells(data["table"], rendered=True)
    names = ["window", "map_plane_attitude"] + [c["name"] for c in data["candidates"]]
    lines = _header(cells, "preview (mean ± std, worst drive)")
    for name in names:
        row = [f"`{name}`"]
        for cell in cells:
            r = cell["rows"].get(name, {})
            row.append(f"{_fmt(r.get('share_mean'))} ± {_fmt(r.get('share_std'))} ({_fmt(r.get('share_min'))})"
                       if "share_mean" in r else "–")
        lines.append("| " + " | ".join(row) + " |")
    drives = {c["drives"] for c in cells}
    lines.append("")
    streams = _streams(data)
    if streams:
        lines.append("Messages in one frame and reference (contact plane, `base_link`) with a vehicle speed and "
                     "times of arrival: " + ", ".join(
                         f"`{name}` {n_ok} of {n}" for name, (n_ok, n) in streams.items()) + ".")
        lines.append("")
    lines.append(f"{'/'.join(str(d) for d in sorted(drives))} rendered drives per cell; latency and frames fused "
                 f"per configuration: " + ", ".join(
                     f"`{c['name']}` {1e3 * c['latency_s']:.0f} ms / {1e3 * c['period_s']:.0f} ms a frame"
                     for c in data["candidates"]) + ".")
    return "\n".join(lines)


def _streams(data: Mapping[str, Any]) -> dict[str, tuple[int, int]]:
    """Per candidate over every rendered drive and rate: (messages in the contact-plane reference
    with a speed and times of arrival, messages)."""
    out: dict[str, tuple[int, int]] = {}
    for cell in data["cells"]:
        for rate in cell["rates"].values():
            for c in data["candidates"]:
                st = rate.get("stream", {}).get(c["name"])
                if st:
                    done, total = out.get(c["name"], (0, 0))
                    out[c["name"]] = (done + st["in_one_stream"], total + st["messages"])
    return out


def _share_cell(name: str, cell: Mapping[str, Any]) -> str:
    return f"{_fmt(cell['rows'][name]['share_mean'])} ± {_fmt(cell['rows'][name]['share_std'])}"


def ride_truth(data: Mapping[str, Any]) -> str:
    """The truth-only drives: the controller's Wk without and with the true road, and the share of
    its gain a perfect per-frame camera and a perfect fused map (without and with the contact
    plane's attitude undone) deliver: what the window and the reference allow."""
    cells = _cells(data["table"], rendered=False)
    lines = _header(cells, "truth-only drives")
    rows: list[tuple[str, Callable[[Mapping[str, Any]], str]]] = [
        ("drives", lambda c: str(c["drives"])),
        ("Wk passive / no preview / true road (m/s²)", lambda c: " / ".join(
            _fmt(c["rows"][r]["wk_rms_mps2"]) for r in ("passive", "no_preview", "true_road"))),
    ]
    for name in ("window", "map_plane", "map_plane_attitude"):
        rows.append((f"share `{name}`", functools.partial(_share_cell, name)))
    for title, value in rows:
        lines.append("| " + " | ".join([title] + [value(c) for c in cells]) + " |")
    return "\n".join(lines)


def default_candidate(data: Mapping[str, Any]) -> str:
    """The name of the run's candidate that is the node's default configuration (its backend with
    no option changed)."""
    for c in data["candidates"]:
        if c["backend"] == DEFAULT_BACKEND and not c["params"]:
            return str(c["name"])
    raise KeyError(f"the results hold no candidate of the default configuration ({DEFAULT_BACKEND})")


def ride_budget(data: Mapping[str, Any], candidate: str | None = None) -> str:
    """The error budget of one configuration (the default): its share with one stage at a time
    taken from the truth, per speed and camera rate (mean over the drives)."""
    name = candidate or default_candidate(data)
    cells = _cells(data["table"], rendered=True)
    lines = _header(cells, f"`{name}`, the truth in one stage")
    for stage in STAGES:
        row_name = name if stage == "shipped" else f"{name}{STAGE_SEPARATOR}{stage}"
        row = [_STAGE_TITLES[stage]]
        for cell in cells:
            r = cell["rows"].get(row_name, {})
            row.append(_fmt(r.get("share_mean")))
        lines.append("| " + " | ".join(row) + " |")
    row = ["a perfect fused map (`map_plane_attitude`)"]
    for cell in cells:
        row.append(_fmt(cell["rows"].get("map_plane_attitude", {}).get("share_mean")))
    lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def ride_arrival(data: Mapping[str, Any]) -> str:
    """The preview at arrival on the same rendered drives, against the true contact plane: overall /
    feature points, coverage, per configuration."""
    cells = _cells(data["table"], rendered=True)
    lines = _header(cells, "preview at arrival, cm: all / features (coverage %)")
    for c in data["candidates"]:
        row = [f"`{c['name']}`"]
        for cell in cells:
            row.append(_arrival(cell["rows"].get(c["name"], {}).get("arrival"), "contact_plane_abs_err_cm"))
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def arrival_rows(data: Mapping[str, Any], rows: Sequence[str] | None = None) -> str:
    """bench_arrival: the preview at arrival per configuration (fused map, and per frame for the
    first), per speed and camera rate: all / feature points against the reference each message
    declares, and coverage."""
    cells = sorted(data["table"], key=lambda t: (t["speed_mps"], t["rate_hz"]))
    names = list(rows) if rows is not None else (
        [c["name"] for c in data["candidates"]] + [f"{default_candidate(data)}{STAGE_SEPARATOR}per_frame"])
    lines = _header(cells, "cm: all / features (coverage %)")
    for name in names:
        row = [f"`{name}`"]
        for cell in cells:
            row.append(_arrival(cell["rows"].get(name)))
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def arrival_budget(data: Mapping[str, Any]) -> str:
    """bench_arrival: the error budget of the default configuration at arrival (all / features, cm)."""
    name = default_candidate(data)
    return arrival_rows(data, [name if s == "shipped" else f"{name}{STAGE_SEPARATOR}{s}" for s in STAGES])


def node_candidates(data: Mapping[str, Any]) -> str:
    """bench_node --drive: each configuration in the node with the map on, fed a camera's timing:
    frames fused, latency, inference and the node's own time per frame."""
    lines = ["| configuration | frames fused | latency p50 / p95 (ms) | inference p50 (ms) | node overhead mean (ms) |",
             "|---|---|---|---|---|"]
    for r in data["rows"]:
        lines.append(f"| `{r['backend']}` | {r['outputs']}/{r['frames']} | {_fmt(r['latency_ms']['p50'], 0)} / "
                     f"{_fmt(r['latency_ms']['p95'], 0)} | {_fmt(r['inference_p50_ms'], 0)} | "
                     f"{_fmt(r['overhead_mean_ms'], 1)} |")
    bag = data["bag"]
    lines.append("")
    lines.append(f"A {bag['frames']}-frame drive at {bag['frame_rate_hz']:g} Hz, the map on; "
                 f"`{data['machine'].get('cpu', 'this machine')}`, commit {data['machine'].get('git_commit', '?')}.")
    return "\n".join(lines)


TABLES: dict[str, tuple[str, Callable[[Mapping[str, Any]], str]]] = {
    "node_candidates": ("node_candidates.json", node_candidates),
    "arrival": ("arrival.json", arrival_rows),
    "arrival_budget": ("arrival.json", arrival_budget),
    "ride_shares": ("ride.json", ride_shares),
    "ride_truth": ("ride.json", ride_truth),
    "ride_budget": ("ride.json", ride_budget),
    "ride_arrival": ("ride.json", ride_arrival),
}


def render(name: str) -> str:
    """The table ``name`` from its committed result file.

    Raises:
        KeyError: an unknown table.
    """
    source, make = TABLES[name]
    return make(_load(source))


def _replace(page: str, fix: bool) -> tuple[str, list[str]]:
    stale: list[str] = []

    def sub(match: re.Match[str]) -> str:
        name = match.group("name")
        want = render(name) + "\n"
        if match.group("body") != want:
            stale.append(name)
        return match.group(1) + (want if fix else match.group("body")) + match.group(4)

    return _BLOCK.sub(sub, page), stale


def marked_tables(page: str) -> list[str]:
    """The names of the tables marked on a page's text, in order."""
    return [m.group("name") for m in _BLOCK.finditer(page)]


def check_page(path: Path) -> list[str]:
    """The names of the marked tables on the page at ``path`` that differ from their results."""
    return _replace(path.read_text(), fix=False)[1]


def rewrite_page(path: Path) -> list[str]:
    """Rewrite the marked tables of the page at ``path`` from the results; returns those that changed."""
    page, stale = _replace(path.read_text(), fix=True)
    path.write_text(page)
    return stale


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("names", nargs="*", help=f"tables to print (default all: {', '.join(TABLES)})")
    parser.add_argument("--write", type=Path, metavar="PAGE", help="rewrite the marked tables of PAGE in place")
    args = parser.parse_args(argv)
    if args.write:
        changed = rewrite_page(args.write)
        print(f"{args.write}: {len(changed)} table(s) rewritten {changed}", file=sys.stderr)
        return 0
    for name in args.names or TABLES:
        if name not in TABLES:
            parser.error(f"unknown table {name!r} (one of {', '.join(TABLES)})")
        print(f"<!-- table: {name} -->\n{render(name)}\n<!-- /table -->\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
