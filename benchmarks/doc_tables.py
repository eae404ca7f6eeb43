"""Tables of the docs, generated from the committed benchmark results.

A page quotes a table between two markers, ``<!-- table: NAME -->`` and ``<!-- /table -->``;
:func:`render` makes the table NAME from its result files (each table ends with the command that
made them, the machine and the commit, as far as the files record them) and :func:`check_page`
says which marked tables on a page differ from what the results give now. The tests run it on
the README and on every page under ``docs/``, so a figure there cannot drift from the JSON it came
from, and check that every result file under ``benchmarks/results/`` is quoted somewhere.

Run: ``.venv/bin/python -m benchmarks.doc_tables [NAME ...]`` prints the tables;
``--write [PAGE ...]`` rewrites the marked blocks of the pages in place and ``--check [PAGE ...]``
names the pages with a stale table and exits 1 when there is one (default pages: the README and
every page under ``docs/``).
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import re
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.bench_ride import pooled_arrival
from benchmarks.bench_runtimes import markdown as runtimes_markdown
from benchmarks.common import RESULTS
from benchmarks.preview_budget import STAGE_SEPARATOR, STAGES
from benchmarks.run_all import common_cell_markdown, flat_reference_line
from benchmarks.run_all import markdown_table as table1_markdown
from roadbev_core.config import DEFAULT_BACKEND

__all__ = ["ROOT", "TABLES", "Table", "check_page", "doc_pages", "marked_tables", "provenance", "render",
           "rewrite_page", "sources"]

ROOT = RESULTS.parents[1]  # the repository
_BLOCK = re.compile(r"(<!-- table: (?P<name>[a-z0-9_]+) -->\n)(?P<body>.*?)(<!-- /table -->)", re.S)
_STAGE_TITLES = {
    "shipped": "as shipped",
    "true_answered": "true heights on the answered cells",
    "true_features": "true heights on the answered cells of the road's features",
    "true_surface": "true heights on the other answered cells",
    "true_short": "the true relief shorter than 1 m on the answered cells",
    "true_all": "true heights on every cell",
    "true_far": "true heights on the far field's answered cells",
    "far_error_halved": "the far field's error halved",
    "true_odometry": "true odometry",
    "true_datum": "true datum (map z)",
    "true_plane": "true contact plane",
    "no_latency": "no latency (every frame, at its stamp)",
}
# The backends of the sample drive's committed evaluations (benchmarks/results/sample_drive_<name>.json).
SAMPLE_DRIVE_BACKENDS = ("bev_sweep", "bm", "sgbm", "stereo", "mono", "ensemble")


def _load(name: str) -> dict[str, Any]:
    """A result file: a path under ``benchmarks/results/``, or from the repository root when it
    names a folder outside it (``roadbev_core/data/...``)."""
    path = ROOT / name if name.startswith("roadbev_core/") else RESULTS / name
    return dict(json.loads(path.read_text()))


def _fmt(value: float | None, digits: int = 2) -> str:
    return "–" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _row(cells: Sequence[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _head(*titles: str) -> list[str]:
    return [_row(titles), "|" + "---|" * len(titles)]


def provenance(data: Mapping[str, Any], command: str | None = None) -> str:
    """One line: the command that made a result file (its own record, else ``command``), the
    machine and the commit it ran at, as far as the file records them."""
    parts: list[str] = []
    cmd = data.get("command") or command
    if cmd:
        parts.append(f"Command: `{str(cmd).strip()}`.")
    machine = data.get("machine")
    if isinstance(machine, Mapping):
        name = machine.get("cpu") or machine.get("processor")
        cores = machine.get("cores") or machine.get("threads")
        where = ", ".join(p for p in (str(name) if name else "", f"{cores} cores" if cores else "") if p)
        if machine.get("torch"):
            where += f", torch {machine['torch']}"
            if machine.get("torch_threads") not in (None, cores):
                where += f" (torch threads: {machine['torch_threads']})"
        if where:
            parts.append(f"Machine: {where}.")
        if machine.get("git_commit"):
            when = f", {str(machine['time_utc'])[:10]}" if machine.get("time_utc") else ""
            parts.append(f"Commit `{machine['git_commit']}`{when}.")
    elif machine:
        parts.append(f"Machine: {machine}.")
    return " ".join(parts)


# --- the preview: ride and arrival benchmarks ----------------------------------------------------

def _arrival(a: Mapping[str, Any] | None, error: str = "abs_err_cm") -> str:
    """All / feature points (cm) and coverage (%) of one preview-at-arrival summary."""
    if not a:
        return "–"
    return f"{_fmt(a[error], 3)} / {_fmt(a['features_abs_err_cm'], 3)} ({_fmt(a['coverage_pct'], 1)})"


def _cells(table: Sequence[Mapping[str, Any]], rendered: bool) -> list[Mapping[str, Any]]:
    return sorted((t for t in table if t["rendered"] == rendered), key=lambda t: (t["speed_mps"], t["rate_hz"]))


def _header(cells: Sequence[Mapping[str, Any]], first: str) -> list[str]:
    return _head(first, *(f"{c['speed_mps']:g} m/s, {c['rate_hz']:g} Hz" for c in cells))


def ride_shares(data: Mapping[str, Any]) -> str:
    """Share of the true road's gain per configuration on the rendered drives: mean ± std over the
    drives, and the worst drive."""
    cells = _cells(data["table"], rendered=True)
    names = [*_perfect_rows(cells, ("window", "map_plane_attitude")), *(c["name"] for c in data["candidates"])]
    lines = _header(cells, "preview (mean ± std, worst drive)")
    for name in names:
        row = [f"`{name}`"]
        for cell in cells:
            r = cell["rows"].get(name, {})
            row.append(f"{_fmt(r.get('share_mean'))} ± {_fmt(r.get('share_std'))} ({_fmt(r.get('share_min'))})"
                       if "share_mean" in r else "–")
        lines.append(_row(row))
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
                     + (f" (its pace backend {1e3 * c['pace_latency_s']:.0f} ms / {1e3 * c['pace_period_s']:.0f} ms)"
                        if "pace_latency_s" in c else "")
                     for c in data["candidates"]) + ".")
    return "\n".join(lines)


def _road_items(data: Mapping[str, Any]) -> dict[tuple[str, float, float], list[Mapping[str, Any]]]:
    """The rendered drives' per-rate results by (road kind, speed, camera rate)."""
    out: dict[tuple[str, float, float], list[Mapping[str, Any]]] = {}
    for cell in data["cells"]:
        if cell["rendered"]:
            for rate, item in cell["rates"].items():
                out.setdefault((cell["road"], float(cell["speed_mps"]), float(rate)), []).append(item)
    return out


def _road_axes(items: Mapping[tuple[str, float, float], Any]) -> tuple[list[str], list[tuple[float, float]]]:
    """The road kinds and the (speed, camera rate) columns of :func:`_road_items`."""
    return sorted({road for road, _, _ in items}), sorted({(speed, rate) for _, speed, rate in items})


def _road_head(first: str, columns: Sequence[tuple[float, float]]) -> list[str]:
    return _head(first, *(f"{speed:g} m/s, {rate:g} Hz" for speed, rate in columns))


def _road_shares(items: Sequence[Mapping[str, Any]], name: str) -> list[float]:
    """The finite shares of row ``name`` over ``items``."""
    return [i["share"][name] for i in items if math.isfinite(i["share"].get(name, math.nan))]


def _road_share(items: Sequence[Mapping[str, Any]], name: str) -> str:
    """Mean share of ``name`` over ``items`` and the worst drive's, or a dash where none has it."""
    shares = _road_shares(items, name)
    return f"{_fmt(float(np.mean(shares)))} ({_fmt(min(shares))})" if shares else "–"


def _road_wk(items: Sequence[Mapping[str, Any]]) -> str:
    """Mean Wk-weighted RMS body acceleration of the controller without preview and with the true
    road over ``items`` (m/s²)."""
    if not items:
        return "–"
    return " / ".join(_fmt(float(np.mean([i["rows"][r]["mean"]["wk_rms_mps2"] for i in items])))
                      for r in ("no_preview", "true_road"))


def ride_budget_roads(data: Mapping[str, Any], candidate: str,
                      stages: Sequence[str] = ("shipped", "true_answered", "true_features", "true_surface",
                                               "true_far", "no_latency")) -> str:
    """Road by road, the error budget of ``candidate``: its mean share with one stage at a time
    taken from the truth, per speed and camera rate (the stages the run took)."""
    items = _road_items(data)
    roads, columns = _road_axes(items)
    lines = _road_head(f"`{candidate}`, the truth in one stage", columns)
    for road in roads:
        for stage in stages:
            row_name = candidate if stage == "shipped" else f"{candidate}{STAGE_SEPARATOR}{stage}"
            shares = [_road_shares(items.get((road, speed, rate), []), row_name) for speed, rate in columns]
            if any(shares):
                lines.append(_row([f"{road}: {_STAGE_TITLES[stage]}",
                                   *(_fmt(float(np.mean(s))) if s else "–" for s in shares)]))
    return "\n".join(lines)


def ride_roads(data: Mapping[str, Any], rows: Sequence[str] = ("window_far_visible",)) -> str:
    """Road by road: the share of the true road's gain per configuration on each road kind's
    rendered drives (mean and worst drive), and its preview at arrival on the road's features,
    against the true contact plane (pooled as the benchmark pools it:
    :func:`benchmarks.bench_ride.pooled_arrival`); ``rows`` are perfect rows shown first where
    the run has them."""
    items = _road_items(data)
    roads, columns = _road_axes(items)
    names = [r for r in rows if any(r in i["share"] for group in items.values() for i in group)]
    names += [c["name"] for c in data["candidates"]]
    lines = _road_head("share (mean, worst drive) · features at arrival (cm)", columns)
    for road in roads:  # what there is to gain on each road: the controller without and with the true road
        lines.append(_row([f"Wk no preview / true road (m/s²), {road}",
                           *(_road_wk(items.get((road, speed, rate), [])) for speed, rate in columns)]))
    for name in names:
        for road in roads:
            row = [f"`{name}`, {road}"]
            for speed, rate in columns:
                group = items.get((road, speed, rate), [])
                text = _road_share(group, name)
                arrivals = [i["arrival"][name] for i in group if name in i.get("arrival", {})]
                if arrivals and name not in rows and text != "–":
                    text += f" · {_fmt(pooled_arrival(arrivals)['features_abs_err_cm'])}"
                row.append(text)
            lines.append(_row(row))
    drives = sorted({len(group) for group in items.values()})
    lines.append("")
    lines.append(f"{'/'.join(str(d) for d in drives)} rendered drives per road kind and cell.")
    return "\n".join(lines)


def ride_gain_roads(applied: Mapping[str, Any], measured: Mapping[str, Any]) -> str:
    """Road by road, each candidate of ``measured`` (a run with the controller's measured gain)
    against the same candidate of ``applied`` (the same drives with all of every preview applied,
    ``bench_ride --no-preview-gain``): mean share and the worst drive's."""
    with_gain, without = _road_items(measured), _road_items(applied)
    roads, columns = _road_axes(with_gain)
    names = [c["name"] for c in measured["candidates"] if c["name"] in {a["name"] for a in applied["candidates"]}]
    lines = _road_head("share (mean, worst drive)", columns)
    for name in names:
        for road in roads:
            for title, items in (("the measured gain", with_gain), ("all of it applied", without)):
                lines.append(_row([f"`{name}`, {road}, {title}"]
                                  + [_road_share(items.get((road, speed, rate), []), name) for speed, rate in columns]))
    return "\n".join(lines)


def _perfect_rows(cells: Sequence[Mapping[str, Any]], names: Sequence[str]) -> list[str]:
    """``names`` and, where the run has them (``bench_ride --far-field``), their rows reaching the
    far-field grid's far edge (``<name>_far``) and those of only the road the camera sees from
    where it is (``<name>_visible``, ``<name>_far_visible``)."""
    return [f"{n}{suffix}" for suffix in ("", "_visible", "_far", "_far_visible") for n in names
            if not suffix or any(f"{n}{suffix}" in c["rows"] for c in cells)]


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
    for name in _perfect_rows(cells, ("window", "map_plane", "map_plane_attitude")):
        rows.append((f"share `{name}`", functools.partial(_share_cell, name)))
    for title, value in rows:
        lines.append(_row([title] + [value(c) for c in cells]))
    return "\n".join(lines)


def default_candidate(data: Mapping[str, Any]) -> str:
    """The name of the run's candidate that is the node's default configuration (its backend with
    no option changed)."""
    for c in data["candidates"]:
        if c["backend"] == DEFAULT_BACKEND and not c["params"]:
            return str(c["name"])
    raise KeyError(f"the results hold no candidate of the default configuration ({DEFAULT_BACKEND})")


def _stage_rows(name: str, cells: Sequence[Mapping[str, Any]]) -> list[tuple[str, str]]:
    """(stage, row name) of the error budget's stages of candidate ``name`` that the run took
    (a run may lack some: a far-field candidate's label stages where its drives were rendered
    without the far field's labels, the newer stages in an older run)."""
    rows = [(stage, name if stage == "shipped" else f"{name}{STAGE_SEPARATOR}{stage}") for stage in STAGES]
    return [(stage, row) for stage, row in rows if any(row in cell["rows"] for cell in cells)]


def ride_budget(data: Mapping[str, Any], candidate: str | None = None) -> str:
    """The error budget of one configuration (the default): its share with one stage at a time
    taken from the truth, per speed and camera rate (mean over the drives)."""
    name = candidate or default_candidate(data)
    cells = _cells(data["table"], rendered=True)
    lines = _header(cells, f"`{name}`, the truth in one stage")
    for stage, row_name in _stage_rows(name, cells):
        row = [_STAGE_TITLES[stage]]
        for cell in cells:
            r = cell["rows"].get(row_name, {})
            row.append(_fmt(r.get("share_mean")))
        lines.append(_row(row))
    for perfect in _perfect_rows(cells, ("map_plane_attitude",)) + _perfect_rows(cells, ("window",))[1:]:
        what = "a perfect fused map" if perfect.startswith("map_plane") else (
            "a perfect camera, of the road it sees" if perfect.endswith("_visible") else "a perfect camera")
        row = [f"{what} (`{perfect}`)"]
        for cell in cells:
            row.append(_fmt(cell["rows"].get(perfect, {}).get("share_mean")))
        lines.append(_row(row))
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
        lines.append(_row(row))
    return "\n".join(lines)


def ride_arrival_sigma(data: Mapping[str, Any]) -> str:
    """The sigma each configuration's preview gave at arrival against its error there, on the
    rendered drives: within 1 / 2 sigma (%), the mean sigma and the mean absolute error (cm)."""
    cells = _cells(data["table"], rendered=True)
    lines = _header(cells, "within 1σ / 2σ · confidently wrong (%) · mean σ / abs. error (cm)")
    for c in data["candidates"]:
        row = [f"`{c['name']}`"]
        for cell in cells:
            a = cell["rows"].get(c["name"], {}).get("arrival") or {}
            row.append(f"{_fmt(a.get('within_1sigma_pct'), 1)} / {_fmt(a.get('within_2sigma_pct'), 1)} · "
                       f"{_fmt(a.get('confident_wrong_pct'))} · {_fmt(a.get('mean_sigma_cm'))} / "
                       f"{_fmt(a.get('abs_err_cm'))}" if a else "–")
        lines.append(_row(row))
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
        lines.append(_row(row))
    return "\n".join(lines)


def arrival_budget(data: Mapping[str, Any]) -> str:
    """bench_arrival: the error budget of the default configuration at arrival (all / features, cm)."""
    return arrival_rows(data, [row for _, row in _stage_rows(default_candidate(data), data["table"])])


# --- the node -----------------------------------------------------------------------------------

def node_candidates(data: Mapping[str, Any]) -> str:
    """bench_node --drive: each configuration in the node with the map on, fed a camera's timing:
    frames fused, latency, inference, the node's own time per frame and its wait for the motion
    samples after each image's stamp (IMU, odometry); with the latency on arrival where the run
    measured it (each frame's latency less its wait for the node), and the frames the pace backend
    answered where the run counted them."""
    on_arrival = all("latency_on_arrival_ms" in r for r in data["rows"])
    paced = all("paced_frames" in r for r in data["rows"])
    lines = _head("configuration", "frames fused", "latency p50 / p95 (ms)",
                  *(("latency on arrival p50 (ms)",) if on_arrival else ()), "inference p50 (ms)",
                  "node overhead mean (ms)", "IMU / odometry wait mean (ms)",
                  *(("answered by the pace backend",) if paced else ()))
    for r in data["rows"]:
        arrival = [_fmt(r["latency_on_arrival_ms"]["p50"], 0)] if on_arrival else []
        lines.append(_row([f"`{r['backend']}`", f"{r['outputs']}/{r['frames']}",
                           f"{_fmt(r['latency_ms']['p50'], 0)} / {_fmt(r['latency_ms']['p95'], 0)}", *arrival,
                           _fmt(r["inference_p50_ms"], 0), _fmt(r["overhead_mean_ms"], 1),
                           _fmt(r["imu_wait_mean_ms"], 1), *([str(r["paced_frames"])] if paced else [])]))
    bag = data["bag"]
    lines.append("")
    lines.append(f"A {bag['frames']}-frame drive at {bag['frame_rate_hz']:g} Hz with odometry (the map on), "
                 "replayed with the bag's timing: each image leaves the replay at its stamp, so a node free "
                 "when it comes waits for the IMU and odometry samples after the stamp (a camera driver "
                 "delivers an image some tens of milliseconds after its stamp, by when they have come; a "
                 "configuration still busy with the previous frame finds them there)."
                 + (" The latency on arrival leaves out each frame's wait for the node to finish the previous "
                    "one: what a frame costs when the node takes it at once, the latency the ride benchmark "
                    "charges (its model of the node adds the waits)." if on_arrival else ""))
    return "\n".join(lines)


def node_rows(data: Mapping[str, Any]) -> str:
    """bench_node: per backend and replay mode, frames answered, throughput, latency, inference and
    the node's own time per frame."""
    rate = data["bag"]["frame_rate_hz"]
    modes = {"5hz": f"bag's timing ({rate:g} Hz)", "max": "as fast as possible"}
    lines = _head("backend", "replay", "frames answered", "throughput (Hz)", "latency p50 / p95 (ms)",
                  "p95 after the first frame (ms)", "inference p50 (ms)", "node overhead mean / p95 (ms)")
    for r in data["rows"]:
        lines.append(_row([
            f"`{r['backend']}`", modes.get(r["mode"], r["mode"]), f"{r['outputs']}/{r['frames']}",
            _fmt(r["throughput_hz"]), f"{_fmt(r['latency_ms']['p50'], 0)} / {_fmt(r['latency_ms']['p95'], 0)}",
            _fmt(r["latency_after_first_ms"]["p95"], 0), _fmt(r["inference_p50_ms"], 0),
            f"{_fmt(r['overhead_mean_ms'], 1)} / {_fmt(r['overhead_p95_ms'], 1)}",
        ]))
    bag = data["bag"]
    params = ", ".join(f"`{k}` = {v}" for k, v in data.get("node_params", {}).items())
    lines.append("")
    lines.append(f"A {bag['frames']}-frame bag at {rate:g} Hz, "
                 + ("a drive with odometry (the map on)" if bag.get("drive_with_odometry") else "no odometry (map off)")
                 + (f"; node parameters {params}" if params else "")
                 + f"; the node's own work measured apart, single-threaded: "
                 f"{_fmt(data['pipeline_overhead_ms']['total_ms'])} ms a frame.")
    return "\n".join(lines)


def map_stage(data: Mapping[str, Any]) -> str:
    """bench_map: the map stage and the fusion alone per frame (best of the passes)."""
    lines = _head("per frame (ms)", "p50", "p95", "mean", "first pass p50")
    for key, title in (("map_stage_ms", "map stage (fusion, contact plane, preview, window)"),
                       ("fusion_ms", "fusion")):
        lines.append(_row([title, _fmt(data[key]["p50"]), _fmt(data[key]["p95"]), _fmt(data[key]["mean"]),
                           _fmt(data["first_pass"][key]["p50"])]))
    lines.append("")
    lines.append(f"{data['frames']} frames of a drive at {data['speed_mps']:g} m/s and {data['rate_hz']:g} Hz, "
                 f"best of {data['repeats']} passes per frame; fusion target {data['target_fusion_ms']:g} ms "
                 f"({'met' if data['fusion_target_met'] else 'not met'}).")
    return "\n".join(lines)


def dds_sizes(data: Mapping[str, Any]) -> str:
    """bench_dds_sizes: images delivered between two processes through the shipped profile, per
    size and QoS."""
    sizes = list(data["reliable"]["delivered_by_mib"])
    lines = _head("QoS \\ image size (MiB)", *sizes)
    for key, title in (("reliable", "reliable"), ("best_effort", "best effort (the node's sensor QoS)")):
        got = data[key]
        lines.append(_row([title] + [f"{got['delivered_by_mib'][s]} of {got['delivered_of']}" for s in sizes]))
    lines.append("")
    lines.append(f"Profile `{data['profile']}`, one square rgb8 image per size, {data['gap_s']:g} s apart.")
    return "\n".join(lines)


def msg_bridge(data: Mapping[str, Any]) -> str:
    """bench_msg_bridge: median time per conversion."""
    lines = _head("conversion", "median")
    for key, value in data.items():
        if key.endswith("_ms"):
            lines.append(_row([f"`{key[:-3]}`", f"{value:.3f} ms"]))
        elif key.endswith("_per_s"):
            lines.append(_row([f"`{key[:-6]}`", f"{value:.1f} per s"]))
        elif key.endswith("_s"):
            lines.append(_row([f"`{key[:-2]}`", f"{value:.3f} s"]))
    lines.append("")
    lines.append(f"Zero-copy image read: {'yes' if data['zero_copy_image_read'] else 'no'}.")
    return "\n".join(lines)


def flood(data: Mapping[str, Any]) -> str:
    """The node under an image and IMU flood (``bench_flood``): per replay speed, what came out,
    how late, what was dropped for its latency and what the diagnostics said."""
    lines = _head("replay", "images / IMU (Hz)", "outputs / frames", "outputs per s", "latency p50 / p95 (ms)",
                  "dropped for latency", "diagnostics ok / warn / error", "warnings naming the flood")
    for row in data["rows"]:
        reports = row["diagnostics"]["reports"]
        lines.append(_row([
            f"{row['rate_factor']:g}x", f"{row['image_hz']:g} / {row['imu_hz']:g}",
            f"{row['outputs']} / {row['frames_published']}", _fmt(row["outputs_per_s"], 1),
            f"{_fmt(row['latency_ms']['p50'], 0)} / {_fmt(row['latency_ms']['p95'], 0)}",
            str(row["dropped_stale"]), f"{reports['ok']} / {reports['warn']} / {reports['error']}",
            str(row["diagnostics"]["flood_reports"]),
        ]))
    return "\n".join(lines)


def fleet(data: Mapping[str, Any]) -> str:
    """``bench_fleet``: many bags, the serial loop against one task per bag on a local Ray cluster."""
    pooled = data["pooled"]
    lines = _head("bags x frames", "backend", "serial (s)", f"Ray, {data['workers']} workers (s)",
                  "cluster start (s, apart)", "speed-up", "per bag / pooled identical",
                  "pooled abs. err. (cm) / coverage (%)")
    lines.append(_row([
        f"{data['bags']} x {data['frames_per_bag']}", f"`{data['backend']}`", _fmt(data["serial_s"], 1),
        _fmt(data["ray_s"], 1), _fmt(data["ray_cluster_start_s"], 1), f"{_fmt(data['speedup'], 2)}x",
        f"{'yes' if data['identical_per_bag'] else 'no'} / {'yes' if data['identical_pooled'] else 'no'}",
        f"{_fmt(pooled['abs_err_cm'], 3)} / {_fmt(pooled['coverage_pct'], 1)}",
    ]))
    return "\n".join(lines)


def preview_stream(data: Mapping[str, Any]) -> str:
    """bench_preview_stream: what a subscriber received on a replayed drive (node defaults, map on),
    the reference controller's last diagnostics and the fused map's sigma."""
    c = data["controller"]
    medians, p95s = data["map_sigma_median_cm"], data["map_sigma_p95_cm"]
    rows = [
        ("previews received", f"{data['previews']}"),
        ("in `base_link` against the contact plane, with a speed and times of arrival",
         f"{data['in_one_stream_pct']:.1f} %"),
        ("contact plane from", ", ".join(f"{k} {v}" for k, v in data["contact_plane_sources"].items())),
        ("controller: messages received / refused", f"{c['received']} / {c['refused']}"),
        ("controller: force commands published", f"{data['force_commands']}"),
        ("controller: preview gain applied", c["preview_gain"]),
        ("fused maps received", f"{data['map_messages']}"),
        ("map `uncertainty` layer: median / p95 over a map (cm)",
         f"{min(medians):.2f}–{max(medians):.2f} / up to {max(p95s):.2f}"),
    ]
    lines = _head("on the recording", "value") + [_row(r) for r in rows]
    lines.append("")
    lines.append(f"Backend `{data['backend']}`, bag `{data['bag']}`.")
    return "\n".join(lines)


# --- backends: accuracy, uncertainty, robustness -------------------------------------------------

def table1(data: Mapping[str, Any]) -> str:
    """The paper's Table I protocol on the synthetic test frames, and bev_sweep against each
    image-view backend on the cells both estimated (the benchmark's own markdown)."""
    common = common_cell_markdown(data["targets"].get("common_cells", {}))
    flat = flat_reference_line(data["targets"].get("flat_reference"))
    text = table1_markdown(data["results"]) + (f"\n\n{common}" if common else "") + (f"\n\n{flat}" if flat else "")
    return (text + f"\n\n{data['frames']} frames, seeds {data['seeds'][0]}–{data['seeds'][1]}, "
            f"appearance `{data['appearance']}`.")


def uncertainty_targets(table: Mapping[str, Any], *drives: Mapping[str, Any]) -> str:
    """Each backend's sigma against the targets: confidently wrong on Table I and on the sample
    drive, within 2 sigma and mean sigma / RMSE on Table I."""
    by_drive = {d["backend"]: d for d in drives}
    lines = _head("backend", "confidently wrong, Table I / sample drive (%) (≤ 0.5)",
                  "within 2σ, Table I (%) (90–98)", "mean σ / RMSE, Table I (≤ 1.5)")
    for m in table["results"]:
        drive = by_drive.get(m["backend"], {})
        lines.append(_row([
            m["backend"], f"{_fmt(m['confident_wrong_pct'])} / {_fmt(drive.get('confident_wrong_pct'))}",
            _fmt(m["within_2sigma_pct"], 1), _fmt(m["mean_sigma_cm"] / m["rmse_cm"]),
        ]))
    return "\n".join(lines)


def sample_drive(*drives: Mapping[str, Any]) -> str:
    """`roadbev eval bags/sample_drive.mcap --backend B` for every backend."""
    lines = _head("backend", "abs. err. (cm)", "RMSE (cm)", "coverage (%)", "median / p95 abs. err. (cm)",
                  "within 2σ (%)", "confidently wrong (%)", "mean σ (cm)", "FPS")
    for d in drives:
        lines.append(_row([
            d["backend"], _fmt(d["abs_err_cm"], 3), _fmt(d["rmse_cm"], 3), _fmt(d["coverage_pct"], 1),
            f"{_fmt(d['median_abs_err_cm'], 3)} / {_fmt(d['p95_abs_err_cm'], 2)}", _fmt(d["within_2sigma_pct"], 1),
            _fmt(d["confident_wrong_pct"]), _fmt(d["mean_sigma_cm"], 3), _fmt(d["fps"], 1),
        ]))
    lines.append("")
    lines.append(f"{drives[0]['frames']} frames of `bags/sample_drive.mcap`.")
    return "\n".join(lines)


def sigma_calibration(data: Mapping[str, Any]) -> str:
    """calibrate_sigma: the common factor per backend and the calibrated sigma's scores on the
    pooled tuning set and on each of its two sets."""
    lines = _head("backend", "factor", "within 1σ / 2σ / 3σ, pooled (%)", "confidently wrong, pooled (%)",
                  "mean σ / RMSE, pooled", "within 2σ, scenes / drives (%)", "confidently wrong, scenes / drives (%)")
    for name, d in data["details"].items():
        s, per = d["tuning_scores"], d["tuning_scores_per_set"]
        lines.append(_row([
            name, _fmt(d["factor"]),
            " / ".join(_fmt(s[f"within_{k}sigma_pct"], 1) for k in (1, 2, 3)), _fmt(s["confident_wrong_pct"]),
            _fmt(s["mean_sigma_cm"] / s["rmse_cm"]),
            f"{_fmt(per['scenes']['within_2sigma_pct'], 1)} / {_fmt(per['drives']['within_2sigma_pct'], 1)}",
            f"{_fmt(per['scenes']['confident_wrong_pct'])} / {_fmt(per['drives']['confident_wrong_pct'])}",
        ]))
    lines.append("")
    drives = ", ".join(f"`{d}`" for d in data["drives"])
    lines.append(f"Tuning set: {data['frames']['scenes']} scenes (seeds {data['seeds'][0]}–{data['seeds'][1]}) and "
                 f"{data['frames']['drives']} frames of the drives {drives} (speed:rate:seed), "
                 "`roadbev_core/data/sigma_calibration.json`.")
    lines += _later_fits(data)
    return "\n".join(lines)


def _later_fits(data: Mapping[str, Any]) -> list[str]:
    """A line per later calibrate_sigma run that fitted some of a table's entries on its tuning set."""
    separate: dict[str, list[str]] = {}
    for name, d in data["details"].items():
        if d.get("command", data["command"]) != data["command"]:
            separate.setdefault(d["command"], []).append(name)
    return [f"{', '.join(names)} fitted on the same tuning set by a later run: `{command}`."
            for command, names in separate.items()]


def far_sigma_calibration(data: Mapping[str, Any]) -> str:
    """calibrate_sigma --far-field: the far-field tables per backend (factor, footprint term) and
    their scores on the tuning scenes, pooled and in the worst band of 1 m."""
    lines = _head("backend", "factor", "footprint term", "within 1σ / 2σ / 3σ (%)", "confidently wrong (%)",
                  "worst band: confidently wrong (%)", "mean σ / RMSE")
    for name, d in data["details"].items():
        s = d["tuning_scores"]
        lines.append(_row([
            name, _fmt(d["factor"]), _fmt(data["models"][name]["footprint"], 3),
            " / ".join(_fmt(s[f"within_{k}sigma_pct"], 1) for k in (1, 2, 3)), _fmt(s["confident_wrong_pct"]),
            _fmt(s["worst_band_confident_wrong_pct"]), _fmt(s["mean_sigma_cm"] / s["rmse_cm"]),
        ]))
    grid = data["grid"]
    lines.append("")
    lines.append(f"Tuning set: {data['frames']['scenes']} scenes (seeds {data['seeds'][0]}–{data['seeds'][1]}) with "
                 f"features in the far-field window, the far-field grid {grid['x_min']:g}–{grid['x_max']:g} m in "
                 f"{100 * grid['resolution']:g} cm cells, `roadbev_core/data/far_sigma_calibration.json`.")
    lines += _later_fits(data)
    return "\n".join(lines)


def far_field_physics(data: Mapping[str, Any]) -> str:
    """bench_far_field, the rig alone: per band of 1 m, the road one image row covers, the image
    rows a cell holds, the disparity, the height error of a tenth of a pixel of disparity, and the
    share of frames that see the band (docs/concepts/grid.md, "The far field")."""
    rig = data["rig"]
    lines = _head("band (m)", "grid, cell (cm)", "one image row covers (cm)", "image rows per cell", "disparity (px)",
                  f"height σ of {rig['subpixel_precision_px']:g} px (cm)", "frames that see it (%)")
    for band in data["bands"]:
        lines.append(_row([
            f"{band['x_from_m']:g}–{band['x_to_m']:g}", f"{band['grid']}, {_fmt(100 * band['cell_m'], 0)}",
            _fmt(band["row_length_cm"], 1), _fmt(100 * band["cell_m"] / band["row_length_cm"], 2),
            _fmt(band["disparity_px"], 1), _fmt(band["limit_sigma_cm"], 2), _fmt(band["in_view_pct"], 0),
        ]))
    lines.append("")
    lines.append(f"At the band's centre on the RSRD rig ({rig['image']}, fx {rig['fx_px']:.0f} px, baseline "
                 f"{rig['baseline_m']:.3f} m, {rig['base_height_m']:g} m high) at its mean pitch of "
                 f"{rig['pitch_deg']:.1f}°: the road is in view up to {rig['farthest_in_view_m']:.1f} m, and one image "
                 f"row at the far field's middle, rounded up to whole cells, makes its {100 * rig['far_cell_m']:g} cm "
                 f"cells. The frames that see a band: of the benchmark's {data['frames']} frames, their pitch drawn "
                 "from the RSRD distribution.")
    return "\n".join(lines)


def far_field(data: Mapping[str, Any]) -> str:
    """bench_far_field: per band of 1 m from the grid's near edge to the far field's far edge, the
    rig's ground sampling and physical limit, and each backend's error (and its ratio to the
    limit), coverage and σ honesty."""
    names = list(data["backends"])
    lines = _head("band (m)", "cell (cm)", "one image row (cm)", "in view (% of frames)", "limit σ (cm)",
                  *(f"`{n}`: error (× limit) · coverage · within 2σ · confidently wrong" for n in names))
    for i, band in enumerate(data["bands"]):
        row = [f"{band['x_from_m']:g}–{band['x_to_m']:g}", _fmt(100 * band["cell_m"], 0),
               _fmt(band["row_length_cm"], 1), _fmt(band["in_view_pct"], 0), _fmt(band["limit_sigma_cm"], 2)]
        for name in names:
            b = data["backends"][name]["bands"][i]
            row.append(f"{_fmt(b['abs_err_cm'])} cm ({_fmt(b['ratio_to_limit'], 1)}×) · "
                       f"{_fmt(b['coverage_pct'], 0)} % · {_fmt(b['within_2sigma_pct'], 0)} % · "
                       f"{_fmt(b['confident_wrong_pct'], 1)} %")
        lines.append(_row(row))
    lines.append("")
    rig = data["rig"]
    lines.append(f"{data['frames']} rendered frames (seeds {data['seeds'][0]}–{data['seeds'][1]}, appearance "
                 f"`{data['appearance']}`), the RSRD rig ({rig['image']}, fx {rig['fx_px']:.0f} px, baseline "
                 f"{rig['baseline_m']:.3f} m, {rig['base_height_m']:g} m high). The limit: the height error of a "
                 f"{rig['subpixel_precision_px']:g} px disparity error at the band's centre at the mean pitch of "
                 f"{rig['pitch_deg']:.1f}°, where the road is in view up to {rig['farthest_in_view_m']:.1f} m; the "
                 "ratio compares the mean abs. error with that limit's (√(2/π) σ). Far field, all bands: " + "; ".join(
                     f"`{n}` {_fmt(b['far']['abs_err_cm'])} cm, coverage {_fmt(b['far']['coverage_pct'], 1)} %, "
                     f"confidently wrong {_fmt(b['far']['confident_wrong_pct'])} %, "
                     f"{_fmt(b['far_ms'], 0)} ms added to a frame"
                     for n, b in data["backends"].items()) + " (the time a frame takes beyond the grid's estimate: "
                 "an ensemble's far-field matchers run beside the grid's).")
    return "\n".join(lines)


def far_field_against(data: Mapping[str, Any]) -> str:
    """bench_far_field, each backend run with options against the same backend without: per band of
    1 m its coverage and the plain one's, and on the cells both answered the two errors."""
    pairs = [(n, b) for n, b in data["backends"].items() if "against" in b]
    lines = _head("band (m)", *(f"`{b['against']['backend']}` → `{n}`: coverage (%) · error on the cells both "
                                "answered (cm)" for n, b in pairs))
    for i, band in enumerate(data["bands"]):
        row = [f"{band['x_from_m']:g}–{band['x_to_m']:g}"]
        for _, b in pairs:
            plain, mine, common = data["backends"][b["against"]["backend"]]["bands"][i], b["bands"][i], \
                b["against"]["bands"][i]
            row.append(f"{_fmt(plain['coverage_pct'], 0)} → {_fmt(mine['coverage_pct'], 0)} · "
                       f"{_fmt(common['against_abs_err_cm'])} → {_fmt(common['abs_err_cm'])}")
        lines.append(_row(row))
    lines.append("")
    lines.append(f"{data['frames']} rendered frames (seeds {data['seeds'][0]}–{data['seeds'][1]}, appearance "
                 f"`{data['appearance']}`), every backend through the pipeline with the far field on (the grid's "
                 "bands first, then the far field's).")
    return "\n".join(lines)


def datum_calibration(data: Mapping[str, Any]) -> str:
    """calibrate_datum: each backend's datum sigma and drift, and how the fit scores the drives."""
    lines = _head("backend", "datum σ (mm)", "drift (mm per m driven)", "steepest drive (mm/m)", "frames",
                  "RMS datum error (cm)", "within 3σ (%)")
    for name, d in data["backends"].items():
        lines.append(_row([
            name, _fmt(1e3 * d["datum_sigma_m"], 1), _fmt(1e3 * d["datum_drift"], 2),
            _fmt(1e3 * d["steepest_drift"], 2), str(d["frames"]), _fmt(d["rms_error_cm"], 2),
            _fmt(d["within_3sigma_pct"], 1),
        ]))
    lines.append("")
    drives = ", ".join(f"{d['speed_mps']:g} m/s {d['rate_hz']:g} Hz" for d in data["drives"][:2])
    lines.append(f"{len(data['drives'])} tuning drives of {data['duration_s']:g} s (seeds "
                 f"{data['drives'][0]['seed']}–{data['drives'][-1]['seed']}; {drives}, ...).")
    return "\n".join(lines)


def preview_sigma(data: Mapping[str, Any]) -> str:
    """bench_preview_sigma: preview samples off by more than 2 cm while their sigma is below 1 cm,
    behind the demo drive's speed bumps and over the whole drive, map off and on."""
    lines = _head("backend", "map", "behind the bumps: off > 2 cm at σ < 1 cm", "largest error at σ < 1 cm (cm)",
                  "beyond 3σ (%)", "whole drive: off > 2 cm at σ < 1 cm")
    for name, b in data["backends"].items():
        for mode, title in (("map_off", "off (per frame)"), ("map_on", "on (fused, contact plane)")):
            behind, whole = b[mode]["behind_bumps"], b[mode]["all"]
            lines.append(_row([
                name, title, f"{behind['confident_wrong']} of {behind['samples']}",
                _fmt(behind["max_err_cm_sigma_below_1cm"]), _fmt(behind["outside_3sigma_pct"], 1),
                f"{whole['confident_wrong']} of {whole['samples']}",
            ]))
    lines.append("")
    lines.append(f"The demo drive (seed {data['seed']}, {data['frames']} frames, {data['bumps']} speed bumps scored), "
                 f"the latest message stamped {data['lead_time_s']:g} s before each front wheel's arrival.")
    return "\n".join(lines)


def robustness(data: Mapping[str, Any]) -> str:
    """robustness: abs. error at coverage per backend, one perturbation at a time."""
    sweep = data["sweep"]
    first = next(iter(sweep.values()))
    backends = [k for k in first if k not in ("levels", "unit")]
    lines = _head("perturbation", *backends)
    zero = first["levels"].index(0.0)
    lines.append(_row(["none"] + [f"{_fmt(first[b]['abs_err_cm'][zero], 3)} at "
                                  f"{_fmt(first[b]['coverage_pct'][zero], 1)} %" for b in backends]))
    for s in sweep.values():
        for i, level in enumerate(s["levels"]):
            if level == 0.0:
                continue
            lines.append(_row([f"{s['unit']}: {level:g}"] + [
                f"{_fmt(s[b]['abs_err_cm'][i], 3)} at {_fmt(s[b]['coverage_pct'][i], 1)} %" for b in backends]))
    lines.append("")
    lines.append(f"{data['frames']} frames, seeds {data['seeds'][0]}–{data['seeds'][1]}, appearance "
                 f"`{data['appearance']}`; abs. err. (cm) at coverage.")
    return "\n".join(lines)


def bev_sweep_tuning(data: Mapping[str, Any]) -> str:
    """tune_bev_sweep: each variant of bev_sweep (and the image-view backends) on the tuning frames."""
    lines = _head("configuration", "abs. err. (cm)", "RMSE (cm)", ">0.5 cm (%)", "coverage (%)", "pipeline (ms)")
    for r in data["results"]:
        lines.append(_row([r["config"], _fmt(r["abs_err_cm"], 3), _fmt(r["rmse_cm"], 3), _fmt(r["gt_0p5cm_pct"], 1),
                           _fmt(r["coverage_pct"], 1), _fmt(r["pipeline_ms"], 0)]))
    lines.append("")
    lines.append(f"{data['frames']} tuning frames, seeds {data['seeds'][0]}–{data['seeds'][1]}.")
    return "\n".join(lines)


def bev_sweep_limits(data: Mapping[str, Any]) -> str:
    """bev_sweep_limits: bev_sweep and bm per band of local relief, and where bev_sweep's error lies."""
    lines = _head("relief within 5 × 5 cells (cm)", "bev_sweep: coverage (%) / abs. err. (cm) / share of its error (%)",
                  "bm: coverage (%) / abs. err. (cm) / share of its error (%)")
    for r in data["relief"]:
        lo, hi = r["relief_cm"]
        band = f"≥ {lo:g}" if hi is None else f"{lo:g}–{hi:g}"
        lines.append(_row([band] + [
            f"{_fmt(r[b]['coverage_pct'], 1)} / {_fmt(r[b]['abs_err_cm'], 3)} / {_fmt(r[b]['share_of_error_pct'], 1)}"
            for b in ("bev_sweep", "bm")]))
    lines.append("")
    lines.extend(_head("error", "bev_sweep", "bm"))
    tails = data["tail"]
    for key, title, digits in (("median_cm", "median (cm)", 3), ("p95_cm", "p95 (cm)", 2),
                               ("worst_5pct_share_of_error_pct", "share of the error in the worst 5 % of cells (%)", 1),
                               ("tail_cells_pct", "cells off by more than 1.5 cm (%)", 1),
                               ("tail_in_far_third_pct", "of those, in the far third (%)", 1),
                               ("tail_in_patches_pct", "of those, in patches of ≥ 20 cells (%)", 1)):
        lines.append(_row([title] + [_fmt(tails[b][key], digits) for b in ("bev_sweep", "bm")]))
    lines.append("")
    lines.append(f"Seeds {data['seeds'][0]}–{data['seeds'][1]}. The ground truth averaged over bev_sweep's "
                 f"aggregation windows leaves {_fmt(data['smoothing_floor_cm'], 3)} cm on the cells it answers "
                 f"(its own error there: {_fmt(data['bev_sweep_abs_err_cm'], 3)} cm).")
    return "\n".join(lines)


# --- real frames and texture ---------------------------------------------------------------------

def kitti(data: Mapping[str, Any]) -> str:
    """bench_kitti: every backend on each real KITTI frame, against the flat prior."""
    frames = data["frames"]
    lines = _head("backend", *(f"{f['frame']} ({f['labelled_cells']} cells)" for f in frames))
    lines.append(_row(["flat prior (0 everywhere)"] + [f"{_fmt(f['flat_prior_abs_err_cm'])} cm" for f in frames]))
    for i, first in enumerate(frames[0]["backends"]):
        row = [first["backend"]]
        for f in frames:
            b = f["backends"][i]
            if "refused" in b:  # the reason's first clause, after "<Error>: <backend>: " (all of it in the JSON)
                row.append("refused: " + b["refused"].split(": ", 2)[-1].split(":")[0])
            else:
                row.append(f"{_fmt(b['abs_err_cm'])} cm at {_fmt(b['coverage_pct'], 0)} % (prior there "
                           f"{_fmt(b['flat_prior_on_covered_cells_cm'])}), bias {b['bias_cm']:+.2f}, "
                           f"c.w. {_fmt(b['confident_wrong_pct'], 0)} %")
        lines.append(_row(row))
    lines.append("")
    fits = "; ".join(f"{f['frame']}: {f['gt_source']}, `base_height` {f['fitted_base_height_m']:.3f} m, "
                     f"pitch {f['fitted_pitch_deg']:.2f}°" for f in frames)
    lines.append(f"Fitted on each frame's ground-truth points: {fits}. {data['caveat']}")
    return "\n".join(lines)


def kitti_row_offsets(data: Mapping[str, Any]) -> str:
    """bench_kitti --row-offsets: coverage, abs. error and confidently wrong share as the right image
    moves by a sub-pixel amount."""
    frames = data["frames"]
    first = next(iter(frames[0]["row_offset_sensitivity"].values()))
    offsets = [r["row_offset_px"] for r in first]
    lines = _head("frame", "backend", *(f"{o:+g} px" if o else "as recorded" for o in offsets))
    for f in frames:
        for name, rows in f["row_offset_sensitivity"].items():
            lines.append(_row([f["frame"], name] + [
                f"{_fmt(r['coverage_pct'], 1)}, {_fmt(r['abs_err_cm'])}, {_fmt(r['confident_wrong_pct'], 0)}"
                for r in rows]))
    lines.append("")
    lines.append("Each cell: coverage (%), abs. err. (cm), confidently wrong (%); positive = the right image "
                 "moved down.")
    return "\n".join(lines)


def _medians(stats: Sequence[Mapping[str, Any]], digits: int) -> str:
    return " / ".join(_fmt(s["median"], digits) for s in stats)


def texture(data: Mapping[str, Any]) -> str:
    """bench_texture: texture statistics of the real frames and of every synthetic setting, per
    distance band, and the matchers' coverage (synthetic at the real frames' label mix)."""
    bands = " / ".join(f"{lo:g}–{hi:g}" for lo, hi in data["bands_m"])
    lines = _head("", f"gradient energy (DN²/px²), bands {bands} m", "inter-view ZNCC, fine band",
                  "inter-view ZNCC, mid band", "coverage bm / sgbm / bev_sweep (%)")
    for f in data["real"]["per_frame"]:
        cov = " / ".join(_fmt(f["coverage_pct"][b][0], 1) for b in ("bm", "sgbm", "bev_sweep"))
        lines.append(_row([f"real: {f['frame']}", _medians(f["gradient_energy"], 1), _medians(f["view_zncc_fine"], 2),
                           _medians(f["view_zncc_mid"], 2), cov]))
    for s in data["synthetic"]:
        mix = s["check"]["coverage_synth_at_real_mix_pct"]
        cov = " / ".join(_fmt(mix[b], 1) for b in ("bm", "sgbm", "bev_sweep"))
        lines.append(_row([f"synthetic: {s['name']}", _medians(s["gradient_energy"], 1),
                           _medians(s["view_zncc_fine"], 2), _medians(s["view_zncc_mid"], 2), cov]))
    pooled = data["real"]["coverage_pct"]
    lines.append("")
    lines.append("Medians per band. The three real frames pooled: coverage " + " / ".join(
        f"{b} {_fmt(sum(v) / len(v), 1)} %" for b, v in pooled.items()) + " (mean of the frames).")
    return "\n".join(lines)


def texture_closest(data: Mapping[str, Any]) -> str:
    """bench_texture: the synthetic setting closest to each real frame against the tolerances."""
    tol = data["tolerances"]
    lines = _head("real frame", "closest setting", "gradient energy, synthetic / real per band",
                  "coverage factor bm / sgbm / bev_sweep", "tolerances met")
    for frame, c in data["closest_per_real_frame"].items():
        factor = " / ".join(_fmt(c["coverage_factor"][b]) for b in ("bm", "sgbm", "bev_sweep"))
        lines.append(_row([frame, c["closest_setting"], " / ".join(_fmt(r) for r in c["energy_median_ratio_per_band"]),
                           factor, "yes" if c["tolerances_met"] else "no"]))
    lines.append("")
    lines.append(f"Tolerances: gradient energy per band {tol['energy_median_ratio']} of real; "
                 f"StereoBM coverage within a factor {tol['bm_coverage_factor']:g}.")
    return "\n".join(lines)


# --- learned models ------------------------------------------------------------------------------

def models(*runs: Mapping[str, Any]) -> str:
    """bench_models: the shipped checkpoints on the test scenes, per appearance; the error left once
    each frame's offset or plane is removed."""
    lines = _head("model", "test scenes", "abs. err. (cm)", "RMSE (cm)", "coverage (%)",
                  "without each frame's offset (cm)", "without each frame's plane (cm)", "FPS")
    for run in runs:
        t = run["test_set"]
        scenes = f"{t['frames']}, seeds {t['seeds'][0]}–{t['seeds'][1]}, `{t['appearance']}`"
        for r in run["results"]:
            lines.append(_row([r["backend"], scenes, _fmt(r["abs_err_cm"], 3), _fmt(r["rmse_cm"], 3),
                               _fmt(r["coverage_pct"], 1), _fmt(r["offset_removed_abs_err_cm"], 3),
                               _fmt(r["plane_removed_abs_err_cm"], 3), _fmt(r["fps"], 1)]))
    return "\n".join(lines)


def baseline_training(data: Mapping[str, Any]) -> str:
    """baseline_training: each shipped image-view baseline's training phases and their budget."""
    lines = _head("baseline", "parameters (M)", "phase", "frames", "epochs", "batch", "peak lr", "steps",
                  "minutes", "last epoch's loss", "last epoch's abs. error")
    kinds = [b["kind"] for b in data["baselines"]]

    def label(b: Mapping[str, Any]) -> str:  # a kind with several checkpoints: each named by its file
        return b["kind"] if kinds.count(b["kind"]) == 1 else f"{b['kind']} (`{b['checkpoint']}`)"

    for b in data["baselines"]:
        for number, p in enumerate(b["phases"], start=1):
            last = p["history"][-1] if p["history"] else {}
            lines.append(_row([label(b), _fmt(b["parameters"] / 1e6, 2), str(number), str(p["frames"]),
                               f"{len(p['history'])} of {p['epochs']}", str(p["batch_size"]), f"{p['lr']:g}",
                               str(p["steps"]), _fmt(p["seconds"] / 60.0, 1), _fmt(last.get("loss"), 3),
                               f"{_fmt(last.get('abs_err'), 3)} {b['error_unit']}"]))
    lines.append("")
    commands = dict.fromkeys(p["command"] for b in data["baselines"] for p in b["phases"])  # a shared phase once
    lines.append("Each phase's command: " + "; ".join(f"`{c}`" for c in commands) + ".")
    scored = [b for b in data["baselines"] if b.get("held_out")]
    if scored:
        lines.append("")
        lines += _head("baseline", "its own output against its labels", "training scenes", "tuning scenes")
        for b in scored:
            h = b["held_out"]
            for key, what in (("abs_err", f"abs. error ({b['error_unit']})"), ("relative_err", "relative error (%)")):
                scale, digits = (100.0, 2) if key == "relative_err" else (1.0, 3)
                lines.append(_row([label(b), what, _fmt(scale * h["training"][key], digits),
                                   _fmt(scale * h["tuning"][key], digits)]))
        frames = scored[0]["held_out"]["frames"]
        lines.append("")
        lines.append(f"Over every labelled pixel of {frames} training scenes (seeds 0–{frames - 1}) and {frames} "
                     "tuning scenes (never trained on), the network in evaluation mode.")
    return "\n".join(lines)


def tune_gwcnet(data: Mapping[str, Any]) -> str:
    """tune_gwcnet: GwcNet-lite's abs. error and coverage per max_sigma_px on the tuning scenes, the
    classical matchers beside it."""
    lines = _head("backend", "max_sigma_px", "abs. err. (cm)", "RMSE (cm)", "coverage (%)",
                  "on sgbm's cells: gwcnet / sgbm (cm)", "on bm's cells: gwcnet / bm (cm)")

    def against(row: Mapping[str, Any], other: str) -> str:
        pair = row.get(f"vs_{other}")
        return "–" if not pair else f"{_fmt(pair['abs_err_cm'], 3)} / {_fmt(pair[f'{other}_abs_err_cm'], 3)}"

    for r in data["rows"]:
        limit = r.get("max_sigma_px")
        lines.append(_row([r["backend"], "–" if limit is None else ("none" if limit == 0 else f"{limit:g}"),
                           _fmt(r["abs_err_cm"], 3), _fmt(r["rmse_cm"], 3), _fmt(r["coverage_pct"], 1),
                           against(r, "sgbm"), against(r, "bm")]))
    lines.append("")
    checkpoint = data.get("checkpoint", "shipped")
    lines.append(f"{data['frames']} tuning scenes, seeds {data['seeds'][0]}–{data['seeds'][1]}; checkpoint "
                 f"{'the shipped one' if checkpoint == 'shipped' else f'`{checkpoint}`'}.")
    return "\n".join(lines)


def drive_frames(data: Mapping[str, Any]) -> str:
    """bench_drive_frames: stereo checkpoints on held-out drive frames and on Table I."""
    drives = data["rows"][0]["drives"]
    lines = _head("checkpoint", *(f"{d['seed']} ({d['speed_mps']:g} m/s)" for d in drives), "all drive frames",
                  "Table I")
    for r in data["rows"]:
        lines.append(_row([f"`{r['checkpoint']}`"] + [_fmt(d["abs_err_cm"], 3) for d in r["drives"]]
                          + [_fmt(r["all_drive_frames"]["abs_err_cm"], 3), _fmt(r["table1"]["abs_err_cm"], 3)]))
    lines.append("")
    lines.append(f"Abs. err. (cm); {data['drives']['frames_each']} frames per drive.")
    return "\n".join(lines)


def runtimes(data: Mapping[str, Any]) -> str:
    """bench_runtimes: the learned models per inference runtime (the benchmark's own markdown)."""
    return (runtimes_markdown(dict(data))
            + f"\n\n{data['frames']} Table I frames, {data['threads']} thread(s) per runtime.")


# --- hazards -------------------------------------------------------------------------------------

def hazards(data: Mapping[str, Any]) -> str:
    """bench_hazards: the detector on true road maps, per drive and in all."""
    lines = _head("road", "seed", "length (km)", "features", "detected", "false alarms")
    for d in data["drives"]:
        lines.append(_row([d["road"], str(d["seed"]), _fmt(d["length_km"], 3), str(d["features"]), str(d["detected"]),
                           str(d["false_alarms"])]))
    s = data["summary"]
    lines.append("")
    lines.append(f"In all: {s['features']} features, {100 * s['detection_rate']:.0f} % detected; height error mean "
                 f"{100 * s['height_rel_err_mean']:.1f} %, max {100 * s['height_rel_err_max']:.1f} %, "
                 f"{100 * s['height_within_15pct']:.1f} % within 15 %; false alarms "
                 f"{s['false_alarms_per_km_smooth']:g} per km over {s['smooth_km']:.2f} km of smooth road, "
                 f"{s['false_alarms_per_km_feature_roads']:g} per km on the feature roads.")
    return "\n".join(lines)


def hazards_map(data: Mapping[str, Any]) -> str:
    """bench_hazards --map: the tracker on the fused map of rendered drives, per speed."""
    lines = _head("speed (m/s)", "features", "reported", "reported ≥ 1 s / ≥ 0.6 s before the front axle",
                  "window allows (s)", "lead median / min (s)", "first report ahead of the front axle, median (m)",
                  "height error mean: first report / in the grid's reach / last", "last within 15 %",
                  "false alarms per km: feature roads / smooth road")

    def pct(value: float | None) -> str:
        return "–" if value is None else f"{100 * value:.0f} %"

    for s in data["summary"]:
        smooth = "–" if s["false_alarms_smooth"] is None else (
            f"{s['false_alarms_smooth']} over {1e3 * s['smooth_km']:.0f} m")
        lines.append(_row([
            f"{s['speed_mps']:g}", str(s["features"]), f"{s['reported']} ({s['reported_pct']:.0f} %)",
            f"{s['reported_1s_ahead_pct']:.0f} % / "
            + ("–" if "reported_0.6s_ahead_pct" not in s else f"{s['reported_0.6s_ahead_pct']:.0f} %"),
            _fmt(s["window_lead_s"]),
            f"{_fmt(s['lead_s_median'])} / {_fmt(s['lead_s_min'])}", _fmt(s["first_reported_distance_m_median"], 1),
            f"{pct(s.get('first_height_rel_err_mean'))} / {pct(s.get('height_at_near_rel_err_mean'))} / "
            f"{pct(s['height_rel_err_mean'])}", pct(s["height_within_15pct"]),
            f"{s['false_alarms_per_km_feature_roads']:.0f} / {smooth}",
        ]))
    lines.append("")
    far = " with the far field (`far_field.enabled`)" if data.get("far_field") else ""
    latency = data.get("latency_s") or 0.0
    charged = (f"; every lead is charged the node's latency, {1e3 * latency:.0f} ms" if latency
               else "; the node's latency is not charged on the leads")
    lines.append(f"Backend `{data['backend']}`{far}, the map on with each drive's own odometry{charged}.")
    return "\n".join(lines)


# --- tools: labels, the renderer -----------------------------------------------------------------

def labels(data: Mapping[str, Any]) -> str:
    """bench_labels: the vectorised label code against a per-point loop."""
    lines = _head("points", "per-point loop (s)", "vectorised (s)", "speed-up", "largest difference (m)", "same mask")
    lines.append(_row([f"{data['points']:,}", _fmt(data["loop_s"]), _fmt(data["vectorized_s"], 3),
                       f"{data['speedup']:.0f}×", f"{data['max_abs_diff_m']:.0e}",
                       "yes" if data["same_mask"] else "no"]))
    return "\n".join(lines)


def synth(data: Mapping[str, Any]) -> str:
    """bench_synth: rendering time per stereo frame and per drive frame."""
    lines = _head("per frame", "wall median (min–max) (s)", "CPU median (s)")
    for key, title in (("stereo_render", "stereo frame"), ("drive_frame", "drive frame"),
                       ("make_sample", "independent sample (`make_sample`: scene, render, labels)")):
        wall, cpu = data[f"{key}_wall_s"], data[f"{key}_cpu_s"]
        lines.append(_row([title, f"{_fmt(wall['median'])} ({_fmt(wall['min'])}–{_fmt(wall['max'])})",
                           _fmt(cpu["median"])]))
    lines.append("")
    lines.append(f"Images {data['image']} on the RSRD half-resolution rig; budget "
                 f"{data['budget_s_per_stereo_frame']:g} s per stereo frame. Drive frame: {data['drive_frame_note']}.")
    return "\n".join(lines)


# --- the fleet's paper-scale plan ------------------------------------------------------------------

PLAN_HOURS = 1000  # hours of driving to label and evaluate
PLAN_RATE_HZ = 10  # stereo frames per second
PLAN_LIDAR_POINTS = 120_000  # points per LiDAR scan (a 64-beam spinning LiDAR at 10 Hz)
PLAN_SCANS = (1, 13)  # scans per labelled frame: the nearest (label.window_s 0) and +-0.6 s at 10 Hz
PLAN_DAY_H = 24.0  # a day's run


def fleet_plan(*results: Mapping[str, Any]) -> str:
    """What labelling and evaluating PLAN_HOURS of PLAN_RATE_HZ stereo costs in core-hours, and the
    one-core workers a day's run needs: evaluation from each backend's ``roadbev eval`` of the
    sample drive (one inference thread: the whole command per frame, decoding included), labels
    from the image decoding of that run and bench_labels' points-to-cells time."""
    *drives, labels = results
    frames = PLAN_HOURS * 3600 * PLAN_RATE_HZ
    lines = _head("job", "per frame (ms, one core)", f"core-hours for {PLAN_HOURS:,} h at {PLAN_RATE_HZ} Hz",
                  f"one-core workers for a {PLAN_DAY_H:g} h run")

    def row(job: str, ms: float) -> str:
        core_h = frames * ms / 1000.0 / 3600.0
        return _row([job, _fmt(ms, 1), f"{core_h:,.0f}", f"{math.ceil(core_h / PLAN_DAY_H):,}"])

    for d in drives:
        lines.append(row(f"`roadbev eval`, `{d['backend']}`", 1000.0 / d["fps"]))
    decode_ms = float(next(d for d in drives if d["backend"] == "bm")["stage_ms"]["decode"])
    per_point_ms = 1000.0 * labels["vectorized_s"] / labels["points"]
    for scans in PLAN_SCANS:
        what = "the nearest scan" if scans == 1 else f"{scans} scans accumulated"
        lines.append(row(f"`roadbev label`, {what}", decode_ms + scans * PLAN_LIDAR_POINTS * per_point_ms))
    lines.append("")
    lines.append(f"{frames:,} frames. Evaluation: each backend's whole `roadbev eval` per frame on the sample drive "
                 "(960 × 528 JPEG pairs, reading and decoding included, the default inference_threads). Labels: "
                 f"the image decoding of that run ({_fmt(decode_ms, 1)} ms) plus the label computation of bench_labels "
                 f"({_fmt(per_point_ms * 1e6, 1)} ms per million points) for scans of {PLAN_LIDAR_POINTS:,} points; "
                 "writing the labelled bag is not in it.")
    return "\n".join(lines)


# --- the demo ------------------------------------------------------------------------------------

def demo(data: Mapping[str, Any]) -> str:
    """``make demo``: the node over ROS 2 against the offline evaluation of the same bag."""
    report = data["report"]
    lines = _head("run", "abs. err. (cm)", "RMSE (cm)", "coverage (%)", "within 2σ (%)", "confidently wrong (%)",
                  "mean σ (cm)", "latency median (ms)")
    for r in report["runs"]:
        m = r["metrics"]
        lines.append(_row([r["label"], _fmt(m["abs_err_cm"], 3), _fmt(m["rmse_cm"], 3), _fmt(m["coverage_pct"], 1),
                           _fmt(m["within_2sigma_pct"], 1), _fmt(m["confident_wrong_pct"]), _fmt(m["mean_sigma_cm"], 3),
                           _fmt(m.get("latency_ms_median"), 0)]))
    after_first = np.asarray(report["timing"]["latency_ms"][1:])  # as the demo's summary: after the first frame
    agree = max(abs(v) for k, v in report["agreement"].items() if k.endswith("cm"))
    ci = data["ci_before_it"]
    lines.append("")
    lines.append(f"{report['settings']['frames']} frames, backend `{report['settings']['backend']}`, grid "
                 f"{report['settings']['grid']}; the two rows agree to within {agree:g} cm; latency after the first "
                 f"frame median {np.percentile(after_first, 50):.0f} ms, p95 {np.percentile(after_first, 95):.0f} ms. "
                 f"`make demo` took {data['wall_s']:.0f} s on a fresh clone, after a CI run had set it up "
                 f"({ci['tests_passed']} tests passed in {ci['wall_s']:.0f} s).")
    return "\n".join(lines)


def demo_stages(data: Mapping[str, Any]) -> str:
    """``make demo``: the wall time of each stage."""
    stages = data["report"]["stage_seconds"]
    lines = _head("stage of `make demo`", "s")
    lines.extend(_row([name, _fmt(s, 1)]) for name, s in stages.items())
    lines.append(_row(["all (from an empty cache)", _fmt(data["wall_s"], 1)]))
    return "\n".join(lines)


def demo_drive(data: Mapping[str, Any]) -> str:
    """``make demo``, the drive section: previews at arrival with the map on and off, the fused map,
    hazards against the features placed, and the ride."""
    drive = data["report"]["drive"]
    on, off = drive["map_on"], drive["map_off"]
    a_on = on["preview_at_arrival"]
    lines = _head(f"preview at arrival, lead {a_on['lead_time_s']:g} s ({a_on['points']} points)", "abs. error (cm)",
                  "features (cm)", "smooth (cm)", "vs contact plane (cm)", "coverage (%)")
    for title, run in (("map on (fused map)", on), ("map off (per frame)", off)):
        a = run["preview_at_arrival"]
        lines.append(_row([title, _fmt(a["abs_err_cm"], 3), _fmt(a["features_abs_err_cm"], 3),
                           _fmt(a["smooth_abs_err_cm"], 3), _fmt(a["contact_plane_abs_err_cm"], 3),
                           _fmt(a["coverage_pct"], 1)]))
    fused = on["map"]
    hz = drive["hazards"]
    found = sum(f.get("detection") is not None for f in hz["features"])
    lines.append("")
    lines.append(f"The fused map: {_fmt(fused['abs_err_cm'], 3)} cm over {_fmt(fused['coverage_pct'], 1)} % of its "
                 f"window. Hazards: {found} of {len(hz['features'])} features (reference: {hz['reference']}) found, "
                 f"{len(hz['false_alarms'])} false alarm(s).")
    if fused.get("bands"):
        lines.append("")
        lines.extend(_head("fused map, metres ahead of `base_link`", "abs. error (cm)", "mean σ (cm)",
                           "within 1σ (%)", "confidently wrong (%)"))
        lines.extend(_row([f"{band['x_from_m']:g} to {band['x_to_m']:g}", _fmt(band["abs_err_cm"]),
                           _fmt(band["mean_sigma_cm"]), _fmt(band["within_1sigma_pct"], 1),
                           _fmt(band["confident_wrong_pct"])]) for band in fused["bands"])
    lines.append("")
    ride = drive["ride"]
    lines.extend(_head("ride, both front wheels", "Wk RMS (m/s²)", "peak travel (cm)", "tyre load RMS ratio",
                       "share of the true road's gain"))
    for name, row in ride["rows"].items():
        m = row["mean"]
        share = ride["share"].get(name)
        lines.append(_row([name, _fmt(m["wk_rms_mps2"]), _fmt(100 * m["peak_travel_m"], 1),
                           _fmt(m["tyre_load_rms_ratio"]), _fmt(share)]))
    lines.append("")
    lines.append(f"Drive seed {drive['seed']}, {on['frames']} frames, backend `{on['backend']}`; the ride scored "
                 f"over {drive['ride_scored_s']:g} s after {drive['ride_warmup_s']:g} s of warm-up.")
    return "\n".join(lines)


@dataclass(frozen=True)
class Table:
    """A generated table: the result files it reads (under ``benchmarks/results/``, or from the
    repository root for ``roadbev_core/data/...``), the function that renders them (one argument
    per file, in order), the command that made them where the first file does not record it, and
    whether the table ends with that provenance line (not for a table that follows another of
    the same run on its page)."""

    sources: tuple[str, ...]
    make: Callable[..., str]
    command: str | None = None
    with_provenance: bool = True

    def render(self) -> str:
        loaded = [_load(s) for s in self.sources]
        text = self.make(*loaded)
        line = provenance(loaded[0], self.command) if self.with_provenance else ""
        return f"{text}\n\n{line}" if line else text


_NODE = ".venv/bin/python -m benchmarks.bench_node"

def _node_drive(name: str, backends: str, node_param: str = "", rate: int = 10) -> Table:
    """The table of a ``bench_node --drive`` run at ``rate`` Hz (60 frames, the bag's timing) of
    ``backends``, with ``node_param`` for every row, written to ``<name>.json``."""
    param = f" --node-param {node_param}" if node_param else ""
    command = (f"{_NODE} --drive --rate {rate} --frames 60 --modes 5hz --backends {backends}{param} "
               f"--out benchmarks/results/{name}.json")
    return Table((f"{name}.json",), node_candidates, command)


def _ride(name: str) -> dict[str, Table]:
    """The shares table (``<name>_shares``) and the preview-at-arrival table (``<name>_arrival``)
    of a ``bench_ride`` run written to ``<name>.json``."""
    return {f"{name}_shares": Table((f"{name}.json",), ride_shares),
            f"{name}_arrival": Table((f"{name}.json",), ride_arrival, with_provenance=False)}


TABLES: dict[str, Table] = {
    "demo": Table(("demo.json",), demo),
    "demo_stages": Table(("demo.json",), demo_stages, with_provenance=False),
    "demo_drive": Table(("demo.json",), demo_drive),
    "table1": Table(("table1.json",), table1),
    "uncertainty_targets": Table(("table1.json", *(f"sample_drive_{b}.json" for b in SAMPLE_DRIVE_BACKENDS)),
                                 uncertainty_targets, with_provenance=False),
    "sample_drive": Table(tuple(f"sample_drive_{b}.json" for b in SAMPLE_DRIVE_BACKENDS), sample_drive,
                          ".venv/bin/roadbev eval bags/sample_drive.mcap --backend B "
                          "--json benchmarks/results/sample_drive_B.json"),
    "sigma_calibration": Table(("roadbev_core/data/sigma_calibration.json",), sigma_calibration),
    "far_sigma_calibration": Table(("roadbev_core/data/far_sigma_calibration.json",), far_sigma_calibration),
    "far_field": Table(("far_field.json",), far_field),
    "far_field_physics": Table(("far_field.json",), far_field_physics, with_provenance=False),
    "far_field_parallax": Table(("far_field_parallax.json",), far_field_against),
    "far_field_parallax_sigma": Table(("far_field_parallax_sigma.json",), far_field),
    "datum_calibration": Table(("datum_calibration.json",), datum_calibration),
    "preview_sigma": Table(("preview_sigma.json",), preview_sigma),
    "robustness": Table(("robustness.json",), robustness),
    "bev_sweep_tuning": Table(("bev_sweep_tuning.json",), bev_sweep_tuning),
    "bev_sweep_limits": Table(("bev_sweep_limits.json",), bev_sweep_limits),
    "bev_sweep_limits_tuning": Table(("bev_sweep_limits_tuning.json",), bev_sweep_limits),
    "kitti": Table(("kitti.json",), kitti),
    "kitti_row_offsets": Table(("kitti.json",), kitti_row_offsets, with_provenance=False),
    "texture": Table(("texture.json",), texture),
    "texture_closest": Table(("texture.json",), texture_closest, with_provenance=False),
    "models": Table(("models.json", "clean/models.json"), models,
                    ".venv/bin/python -m benchmarks.bench_models --frames 20 --cache .cache/scenes "
                    "(and with --appearance clean --out benchmarks/results/clean/models.json)"),
    "drive_frames": Table(("drive_frames.json",), drive_frames),
    "baseline_training": Table(("baseline_training.json",), baseline_training),
    "adabins_beyond_budget": Table(("adabins_beyond_budget/baseline_training.json",), baseline_training),
    "tune_gwcnet": Table(("tune_gwcnet.json",), tune_gwcnet),
    "runtimes": Table(("runtimes.json",), runtimes),
    "node": Table(("node.json",), node_rows, f"{_NODE} --frames 40"),
    "node_map": Table(("node_map.json",), node_rows, f"{_NODE} --drive --rate 10 --frames 40 --backends bev_sweep "
                                                     "--out benchmarks/results/node_map.json"),
    "node_candidates": _node_drive("node_candidates", "ensemble bm sgbm stereo ensemble:members=stereo+sgbm "
                                   "ensemble:members=stereo+bm bev_sweep bev_sweep:min_score=0.7"),
    "node_far_field": _node_drive("node_far_field", "ensemble", "far_field.enabled=true"),
    "node_wait_split": _node_drive("node_wait_split", "ensemble"),
    "node_wait_split_far": _node_drive("node_wait_split_far", "ensemble", "far_field.enabled=true"),
    "node_refined": _node_drive("node_refined", "ensemble ensemble:sgbm.refine_width=21"),
    "node_refined_far": _node_drive("node_refined_far", "ensemble ensemble:sgbm.refine_width=21",
                                    "far_field.enabled=true"),
    "node_parallax_far": _node_drive("node_parallax_far", "ensemble ensemble:bm.plane_parallax_px=16",
                                     "far_field.enabled=true"),
    "node_speed": _node_drive("node_speed", "ensemble"),
    "node_speed_far": _node_drive("node_speed_far", "ensemble", "far_field.enabled=true"),
    "node_speed_bm": _node_drive("node_speed_bm", "bm"),
    "node_speed_bm_far": _node_drive("node_speed_bm_far", "bm", "far_field.enabled=true"),
    "node_speed_bm_parallax_far": _node_drive("node_speed_bm_parallax_far", "bm:plane_parallax_px=16",
                                              "far_field.enabled=true"),
    "node_paced": _node_drive("node_paced", "ensemble"),
    "node_paced_far": _node_drive("node_paced_far", "ensemble", "far_field.enabled=true"),
    "node_default": _node_drive("node_default", "ensemble bm"),
    **{name: _node_drive(name, "ensemble bm") for name in (
        "node_far_thread_before_run1", "node_far_thread_before_run2", "node_far_thread_after_run2")},
    "node_pace_parallax": _node_drive("node_pace_parallax", "ensemble bm:plane_parallax_px=16",
                                      "pace_backend=bm:plane_parallax_px=16"),
    "node_pace_parallax_bands": _node_drive("node_pace_parallax_bands", "bm bm:plane_parallax_px=16"),
    "node_paced_far_5hz": _node_drive("node_paced_far_5hz", "ensemble", "far_field.enabled=true", rate=5),
    "node_stereo": Table(("node_stereo.json",), node_rows, f"{_NODE} --backends stereo stereo:runtime=openvino "
                                                           "--frames 40 --out benchmarks/results/node_stereo.json"),
    "node_stereo_threads2": Table(("node_stereo_threads2.json",), node_rows,
                                  f"{_NODE} --backends stereo:runtime=openvino --modes 5hz --node-param "
                                  "inference_threads=2 --out benchmarks/results/node_stereo_threads2.json"),
    "node_stereo_int8": Table(("node_stereo_int8.json",), node_rows,
                              f"{_NODE} --backends stereo stereo:runtime=openvino "
                              "stereo:runtime=openvino,checkpoint=checkpoints/roadbev_stereo_lite_int8.onnx "
                              "--frames 40 --out benchmarks/results/node_stereo_int8.json"),
    "map_stage": Table(("map_stage.json",), map_stage),
    "flood": Table(("flood.json",), flood),
    "fleet": Table(("fleet.json",), fleet),
    "dds_sizes": Table(("dds_sizes.json",), dds_sizes, ".venv/bin/python -m benchmarks.bench_dds_sizes"),
    "msg_bridge": Table(("msg_bridge.json",), msg_bridge, ".venv/bin/python -m benchmarks.bench_msg_bridge"),
    "preview_stream": Table(("preview_stream.json",), preview_stream),
    "arrival": Table(("arrival.json",), arrival_rows),
    "arrival_budget": Table(("arrival.json",), arrival_budget, with_provenance=False),
    "ride_shares": Table(("ride.json",), ride_shares),
    "ride_truth": Table(("ride.json",), ride_truth, with_provenance=False),
    "ride_budget": Table(("ride.json",), ride_budget, with_provenance=False),
    "ride_budget_cells": Table(("ride_budget_cells.json",), ride_budget),
    "ride_arrival": Table(("ride.json",), ride_arrival, with_provenance=False),
    "ride_far_shares": Table(("ride_far_field.json",), ride_shares),
    "ride_far_truth": Table(("ride_far_field.json",), ride_truth, with_provenance=False),
    "ride_far_budget": Table(("ride_far_field.json",), functools.partial(ride_budget, candidate="ensemble_far"),
                             with_provenance=False),
    "ride_far_arrival": Table(("ride_far_field.json",), ride_arrival, with_provenance=False),
    "ride_far_stages": Table(("ride_far_stages.json",), functools.partial(ride_budget, candidate="ensemble_far")),
    **_ride("ride_refined"),
    **_ride("ride_refined_far"),
    **_ride("ride_parallax_far"),
    **_ride("ride_speed"),
    **_ride("ride_speed_bm"),
    **_ride("ride_equal_cost"),
    **_ride("ride_paced"),
    **_ride("ride_paced_low_speed"),
    **_ride("ride_paced_parallax"),
    **_ride("ride_latency"),
    **_ride("ride_paced_far_thread"),
    **_ride("ride_pace_parallax"),
    **_ride("ride_latency_pace"),
    **_ride("ride_pace_lead"),
    **_ride("ride_pace_lead_10mps"),
    "ride_pace_lead_roads": Table(("ride_pace_lead.json",), ride_roads, with_provenance=False),
    "ride_latency_pace_roads": Table(("ride_latency_pace.json",), ride_roads, with_provenance=False),
    "ride_pace_parallax_roads": Table(("ride_pace_parallax.json",), ride_roads, with_provenance=False),
    "ride_latency_roads": Table(("ride_latency.json",), ride_roads, with_provenance=False),
    "ride_paced_parallax_roads": Table(("ride_paced_parallax.json",), ride_roads, with_provenance=False),
    "ride_paced_roads": Table(("ride_paced.json",), ride_roads, with_provenance=False),
    "ride_far_roads": Table(("ride_far_field.json",), ride_roads, with_provenance=False),
    "ride_far_budget_roads": Table(("ride_far_stages.json",),
                                   functools.partial(ride_budget_roads, candidate="ensemble_far"),
                                   with_provenance=False),
    "ride_paced_no_gain": Table(("ride_paced_no_gain.json", "ride_paced.json"), ride_gain_roads),
    "ride_paced_sigma": Table(("ride_paced_no_gain.json",), ride_arrival_sigma, with_provenance=False),
    "hazards": Table(("hazards.json",), hazards),
    "hazards_map": Table(("hazards_map.json",), hazards_map),
    "hazards_map_far_field": Table(("hazards_map_far_field.json",), hazards_map),
    "hazards_map_far_field_30mps": Table(("hazards_map_far_field_30mps.json",), hazards_map),
    "labels": Table(("labels.json",), labels, ".venv/bin/python -m benchmarks.bench_labels"),
    "synth": Table(("synth.json",), synth, ".venv/bin/python -m benchmarks.bench_synth"),
    "fleet_plan": Table((*(f"sample_drive_{b}.json" for b in SAMPLE_DRIVE_BACKENDS), "labels.json"), fleet_plan,
                        ".venv/bin/roadbev eval bags/sample_drive.mcap --backend B --json "
                        "benchmarks/results/sample_drive_B.json and .venv/bin/python -m benchmarks.bench_labels"),
}


def render(name: str) -> str:
    """The table ``name`` from its committed result files.

    Raises:
        KeyError: an unknown table.
    """
    return TABLES[name].render()


def sources(names: Sequence[str]) -> set[str]:
    """The result files the tables ``names`` read."""
    return {s for name in names for s in TABLES[name].sources}


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


def doc_pages(root: Path = ROOT) -> list[Path]:
    """The pages that may quote generated tables: the README and every Markdown page under ``docs/``."""
    return [root / "README.md", *sorted((root / "docs").rglob("*.md"))]


def check_page(path: Path) -> list[str]:
    """The names of the marked tables on the page at ``path`` that differ from their results."""
    return _replace(path.read_text(), fix=False)[1]


def rewrite_page(path: Path) -> list[str]:
    """Rewrite the marked tables of the page at ``path`` from the results; returns those that changed."""
    page, stale = _replace(path.read_text(), fix=True)
    path.write_text(page)
    return stale


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.doc_tables", description=__doc__.split("\n")[0])
    parser.add_argument("names", nargs="*", help=f"tables to print (default all: {', '.join(TABLES)})")
    parser.add_argument("--write", nargs="*", type=Path, metavar="PAGE",
                        help="rewrite the marked tables of these pages in place (default: the README and docs/)")
    parser.add_argument("--check", nargs="*", type=Path, metavar="PAGE",
                        help="name the pages with a stale table (default: the README and docs/); exit 1 if any")
    args = parser.parse_args(argv)
    if args.write is not None:
        for page in args.write or doc_pages():
            changed = rewrite_page(page)
            if changed:
                print(f"{page}: {len(changed)} table(s) rewritten {changed}", file=sys.stderr)
        return 0
    if args.check is not None:
        stale_pages = 0
        for page in args.check or doc_pages():
            stale = check_page(page)
            if stale:
                stale_pages += 1
                print(f"{page}: {len(stale)} stale table(s) {stale}; run: python -m benchmarks.doc_tables --write",
                      file=sys.stderr)
        return 1 if stale_pages else 0
    for name in args.names or TABLES:
        if name not in TABLES:
            parser.error(f"unknown table {name!r} (one of {', '.join(TABLES)})")
        print(f"<!-- table: {name} -->\n{render(name)}\n<!-- /table -->\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
