"""The summary of a run over many bags: one JSON and one report, per bag and pooled.

Each bag's entry carries its result exactly as the one-bag command writes it (``roadbev eval BAG
--json``; ``roadbev label``'s report), read back from the result store, and the pooled result is
that of all the bags at once:

* evaluation: :class:`roadbev_lab.evaluation.pooled.BagSums` of the bags added in the bags'
  order (the same pooled numbers whatever order the workers finished in) and their metrics; bags
  on different grids are pooled per grid (a distance band means another distance on another grid);
* labelling: the counts added; the mean share of labelled cells and scans per frame over all the
  labelled frames (each bag's mean times its labelled frames is its per-frame sum).

Failed bags are listed with their reasons, duplicates with the bag they repeat.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, cast

from roadbev_core.config import GridSpec
from roadbev_lab.evaluation.frames import json_safe
from roadbev_lab.evaluation.pooled import BagSums
from roadbev_lab.fleet.runner import DONE, DUPLICATE, FAILED, STORED, BagOutcome
from roadbev_lab.fleet.store import ResultStore

__all__ = ["eval_report", "eval_summary", "label_report", "label_summary"]

_LABEL_COUNTS = ("frames", "labelled_frames", "scans")
_LABEL_TALLIES = ("skipped", "rejected_points", "counts")


@dataclass
class _Pool:
    """The bags of one grid pooled so far."""

    sums: BagSums
    losses: list[str]
    bags: int
    backend_options: dict[str, Any]


def _counts(outcomes: Sequence[BagOutcome]) -> dict[str, int]:
    return {"bags": len(outcomes), **{s: sum(o.status == s for o in outcomes) for s in (DONE, STORED, FAILED,
                                                                                          DUPLICATE)}}


def _entry(outcome: BagOutcome) -> dict[str, Any]:
    entry: dict[str, Any] = {"bag": str(outcome.bag), "status": outcome.status, "key": outcome.key}
    if outcome.error:
        entry["error"] = outcome.error
    return entry


def eval_summary(outcomes: Sequence[BagOutcome], store: ResultStore, run: Mapping[str, Any]) -> dict[str, Any]:
    """The summary JSON of ``roadbev eval`` over many bags.

    Args:
        outcomes: the run's outcomes (:func:`roadbev_lab.fleet.runner.run_bags`).
        store: where the finished bags' results are.
        run: what ran (settings, executor, wall time), kept under ``run``.

    Returns:
        ``run``; ``counts`` (bags, done, stored, failed, duplicate); ``bags``: per bag its
        ``status``, ``key``, ``error`` and ``result`` (the JSON of ``roadbev eval BAG --json``);
        ``pooled``: the metrics of all evaluated bags at once (None when none was; with ``bags``
        and ``losses``, each prefixed by its bag) and, when the bags lie on several grids,
        ``pooled_by_grid`` (one pooled entry per grid) with ``pooled`` None.
    """
    entries = []
    pools: dict[GridSpec, _Pool] = {}  # per grid, in the order the bags come
    for outcome in outcomes:
        entry = _entry(outcome)
        if outcome.status in (DONE, STORED) and outcome.key is not None:
            record, arrays = store.get(outcome.key)
            record["bag"] = str(outcome.bag)  # the result is the content's: it may have been made under another path
            entry["result"] = record
            sums = BagSums.from_arrays(arrays)
            losses = [f"{outcome.bag}: {line}" for line in record.get("losses", [])]
            pool = pools.get(sums.grid)
            if pool is None:
                pools[sums.grid] = _Pool(sums, losses, 1, record.get("backend_options", {}))
            else:
                pool.sums, pool.bags = pool.sums.merge(sums), pool.bags + 1
                pool.losses.extend(losses)
        entries.append(entry)
    pooled = [{**pool.sums.metrics(), "losses": pool.losses, "bags": pool.bags, "grid": grid.to_dict(),
               "backend_options": pool.backend_options} for grid, pool in pools.items()]
    summary: dict[str, Any] = {"run": dict(run), "counts": _counts(outcomes), "bags": entries,
                               "pooled": pooled[0] if len(pooled) == 1 else None}
    if len(pooled) > 1:
        summary["pooled_by_grid"] = pooled
    return cast("dict[str, Any]", json_safe(summary))


def label_summary(outcomes: Sequence[BagOutcome], store: ResultStore, run: Mapping[str, Any]) -> dict[str, Any]:
    """The summary JSON of ``roadbev label`` over many bags (as :func:`eval_summary`; each bag's
    ``result`` is its label report and output path, ``pooled`` the totals)."""
    entries = []
    records = []
    for outcome in outcomes:
        entry = _entry(outcome)
        if outcome.status in (DONE, STORED) and outcome.key is not None:
            record, _ = store.get(outcome.key)
            record["bag"] = str(outcome.bag)
            entry["result"] = record
            records.append(record)
        entries.append(entry)
    pooled: dict[str, Any] | None = None
    if records:
        pooled = {k: sum(int(r[k]) for r in records) for k in _LABEL_COUNTS}
        labelled = pooled["labelled_frames"]
        for key in ("mean_labelled_pct", "mean_scans_per_frame"):
            total = sum(float(r[key]) * int(r["labelled_frames"]) for r in records if r["labelled_frames"])
            pooled[key] = total / labelled if labelled else math.nan
        for key in _LABEL_TALLIES:
            tally: dict[str, int] = {}
            for r in records:
                for name, n in r.get(key, {}).items():
                    tally[name] = tally.get(name, 0) + int(n)
            pooled[key] = dict(sorted(tally.items()))
        pooled["bags"] = len(records)
    summary = {"run": dict(run), "counts": _counts(outcomes), "bags": entries, "pooled": pooled}
    return cast("dict[str, Any]", json_safe(summary))


def _fmt(value: Any, digits: int) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return f"{value:.{digits}f}"


def _row(cells: Sequence[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _tail(summary: Mapping[str, Any], verb: str) -> list[str]:
    counts, run = summary["counts"], summary["run"]
    executor = run.get("executor", {})
    lines = ["", f"{counts[DONE]} bag(s) {verb} now ({executor.get('kind', '?')}, {executor.get('workers', '?')} "
                 f"worker(s)), {counts[STORED]} from the store (done by an earlier run), {counts[FAILED]} failed, "
                 f"{counts[DUPLICATE]} duplicate(s)" + (f"; {run['wall_s']:.1f} s" if "wall_s" in run else "") + "."]
    failed = [b for b in summary["bags"] if b["status"] in (FAILED, DUPLICATE)]
    if failed:
        lines += ["", "Not pooled:", ""]
        lines += [f"- {b['bag']}: {b['status']}: {b.get('error', '')}" for b in failed]
    return lines


def eval_report(summary: Mapping[str, Any]) -> str:
    """The report of :func:`eval_summary`: a Markdown table, a row per bag and the pooled row(s)."""
    run = summary["run"]
    lines = [f"# roadbev eval: {summary['counts']['bags']} bag(s), backend {run.get('backend', '?')}", "",
             _row(["bag", "frames", "abs. err. (cm)", "median (cm)", "RMSE (cm)", ">0.5 cm (%)", "coverage (%)",
                   "within 2σ (%)", "FPS", "status"]),
             "|" + "---|" * 10]

    def cells(name: str, m: Mapping[str, Any], status: str) -> list[str]:
        return [name, str(m.get("frames", "–")), _fmt(m.get("abs_err_cm"), 3), _fmt(m.get("median_abs_err_cm"), 3),
                _fmt(m.get("rmse_cm"), 3), _fmt(m.get("gt_0p5cm_pct"), 1), _fmt(m.get("coverage_pct"), 1),
                _fmt(m.get("within_2sigma_pct"), 1), _fmt(m.get("fps"), 1), status]

    for bag in summary["bags"]:
        lines.append(_row(cells(bag["bag"], bag.get("result", {}), bag["status"])))
    for pooled in summary.get("pooled_by_grid") or ([summary["pooled"]] if summary.get("pooled") else []):
        grid = pooled["grid"]
        name = f"**pooled, {pooled['bags']} bag(s)**" + (
            f" (grid {grid['resolution']:g} m from x {grid['x_min']:g} m)" if summary.get("pooled_by_grid") else "")
        lines.append(_row(cells(name, pooled, "")))
        arrival = pooled.get("preview_at_arrival")
        if arrival:
            lines += ["", f"Pooled preview at arrival (lead {arrival['lead_time_s']:g} s, {arrival['points']} "
                          f"points): abs. error {_fmt(arrival['abs_err_cm'], 3)} cm, coverage "
                          f"{_fmt(arrival['coverage_pct'], 1)} %, within 1 / 2 sigma "
                          f"{_fmt(arrival.get('within_1sigma_pct'), 1)} / "
                          f"{_fmt(arrival.get('within_2sigma_pct'), 1)} %, "
                          f"mean sigma {_fmt(arrival.get('mean_sigma_cm'), 3)} cm."]
        if pooled.get("lost_frames"):
            lines += ["", f"{pooled['lost_frames']} frame(s) lost to damage: " + "; ".join(pooled["losses"])]
    return "\n".join(lines + _tail(summary, "evaluated")) + "\n"


def label_report(summary: Mapping[str, Any]) -> str:
    """The report of :func:`label_summary`: a Markdown table, a row per bag and the pooled row."""
    lines = [f"# roadbev label: {summary['counts']['bags']} bag(s)", "",
             _row(["bag", "output", "frames", "labelled", "scans", "cells labelled (%)", "scans per frame",
                   "plane offset (cm)", "status"]),
             "|" + "---|" * 9]

    def cells(name: str, out: str, r: Mapping[str, Any], status: str) -> list[str]:
        return [name, out, str(r.get("frames", "–")), str(r.get("labelled_frames", "–")), str(r.get("scans", "–")),
                _fmt(r.get("mean_labelled_pct"), 1), _fmt(r.get("mean_scans_per_frame"), 1),
                _fmt(r.get("plane_offset_cm"), 1), status]

    for bag in summary["bags"]:
        result = bag.get("result", {})
        lines.append(_row(cells(bag["bag"], result.get("out", "–"), result, bag["status"])))
    if summary.get("pooled"):
        lines.append(_row(cells(f"**pooled, {summary['pooled']['bags']} bag(s)**", "", summary["pooled"], "")))
    return "\n".join(lines + _tail(summary, "labelled")) + "\n"
