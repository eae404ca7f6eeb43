"""Where a preview's worth goes: candidate configurations and an error budget on rendered drives.

A **candidate** is a configuration a user could run in the node (a backend with its options)
together with what it costs there: the end-to-end latency of its previews and the time the node
spends per frame, both measured in the node on this machine (``benchmarks.bench_node --drive``,
map on). On a drive the node's mailbox policy is replayed (:func:`node_schedule`): a frame that
arrives while the node is busy waits, a newer one replaces it, so a candidate slower than the
camera fuses fewer frames and its previews arrive later. A candidate whose spec names a
``pace_backend`` is paced as the node paces it: the node model's :class:`roadbev_core.pacing.Pacer`
hands a frame to the pace backend, charged that backend's own node row, while the chosen one takes
more than ``pace_load`` of the camera's period (:class:`PacedEstimates`); a candidate that names
none runs unpaced, as the node ran before it had a pace backend.

The **error budget** puts the truth into one stage at a time while everything else stays as
shipped (:data:`STAGES`):

* ``shipped``: the candidate as the node runs it (map on);
* ``true_answered``: the true heights on the cells the backend answered (what estimation error costs);
* ``true_features``, ``true_surface``: the true heights on the answered cells of the road's
  features only (bumps, potholes, patches: :func:`label_features`), or on the other answered cells
  only: which of the two the estimation error costs;
* ``true_short``: on the answered cells, the truth's relief shorter than :data:`SHORT_BAND_M`
  along x with the estimate's longer one (:func:`short_band`): whether the error is in the road's
  fine shape or in its slopes and level;
* ``true_all``: the true heights on every cell the camera sees (what declined cells cost as well);
* ``true_far``: a far-field candidate's far field alone with the true heights on its answered cells
  (the grid as shipped): what the far field's estimation error costs;
* ``far_error_halved``: its far field's error (and sigma) halved on the answered cells, the grid
  as shipped: what a far-field matcher twice as precise would give (the far field's error is
  1.5-3 times the physical limit of a tenth of a pixel, ``benchmarks.bench_far_field``);
* ``true_odometry``: the true planar pose of ``base_link`` instead of the drive's drifting odometry;
* ``true_datum``: each frame placed at the true height of ``base_link`` with no vertical alignment;
* ``true_plane``: the previews read against the contact plane of the true road at the four tyre
  contacts (on the map's own datum: the mean of the map's heights at them);
* ``no_latency``: every frame fused and its preview used at its stamp.

Every row is built from one set of estimates per frame (:class:`CachedEstimates`), so rows differ
only in the stage they replace. Lab code: it drives :class:`roadbev_core.pipeline.Pipeline` as
``roadbev eval --map`` does, with the truth of a :class:`roadbev_lab.synth.RidingDrive`.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from benchmarks.common import RESULTS
from roadbev_core.backends import Backend, create
from roadbev_core.box_filter import box_mean
from roadbev_core.config import GridSpec, RoadbevConfig, split_backend_spec
from roadbev_core.frame import Estimate, Frame
from roadbev_core.fusion import FrameFusion, FramePlacement, FusedMap, MapSettings, MapWindow
from roadbev_core.labels import ElevationLabel
from roadbev_core.pacing import Pacer, stand_in
from roadbev_core.pipeline import Pipeline, PipelineOutput, check_config
from roadbev_core.preview import ContactPlane, TrackProfile
from roadbev_core.vehicle import planar_yaw
from roadbev_lab.evaluation.arrival import (
    REFERENCE_CONTACT_PLANE,
    RoadMap,
    TimedPreview,
    Trajectory,
    per_frame_previews,
)
from roadbev_lab.evaluation.frames import evaluate
from roadbev_lab.ride import RideSettings, true_contact_planes
from roadbev_lab.synth import RidingDrive
from roadbev_lab.synth.drive import DriveSample
from roadbev_lab.synth.riding import DRIVE_VERSION, planar_odometry
from roadbev_lab.training.datasets import SCENE_VERSION

__all__ = [
    "DEFAULT_CANDIDATES",
    "FAR_STAGES",
    "LABEL_STAGES",
    "STAGES",
    "STAGE_SEPARATOR",
    "CachedEstimates",
    "Candidate",
    "DriveFrames",
    "Estimates",
    "PacedEstimates",
    "TrueDatumMap",
    "budgeted",
    "candidate_previews",
    "candidates_from_node",
    "far_label_grid",
    "label_features",
    "node_rows",
    "node_schedule",
    "parse_candidate",
    "short_band",
    "stages_of",
]

STAGES: tuple[str, ...] = ("shipped", "true_answered", "true_features", "true_surface", "true_short", "true_all",
                           "true_far", "far_error_halved", "true_odometry", "true_datum", "true_plane", "no_latency")
# The stages only a candidate with a far field has, each changing its far field alone: what each
# does there (a mode of _TruthBackend); the grid stays as shipped.
_FAR_ONLY: dict[str, str] = {"true_far": "true_answered", "far_error_halved": "half_error"}
FAR_STAGES: tuple[str, ...] = tuple(_FAR_ONLY)
# The stages that take the frame's labels (the far field's too, for a candidate with one).
LABEL_STAGES: tuple[str, ...] = ("true_answered", "true_features", "true_surface", "true_short", "true_all",
                                 *FAR_STAGES)
# A label cell is a feature's when it stands FEATURE_THRESHOLD_M off the road's mean over
# FEATURE_WINDOW_M along x (the preview-at-arrival metric's threshold), with FEATURE_MARGIN_M around it.
FEATURE_THRESHOLD_M = 0.015
FEATURE_WINDOW_M = (1.0, 0.27)
FEATURE_MARGIN_M = 0.06
# The relief shorter than this along x is the road's fine shape (true_short).
SHORT_BAND_M = 1.0
STAGE_SEPARATOR = ":"  # a budget row's name: "<candidate>:<stage>"
# The configurations the benchmarks compare by default: every backend a user could pick (bev_sweep
# also re-tuned for the ride on tuning drives: its defaults were tuned on single frames of the clean
# look) and ensembles of the learned model with an image-view matcher and of the two matchers.
DEFAULT_CANDIDATES: tuple[str, ...] = (
    "ensemble", "bm", "sgbm", "stereo",
    "ensemble_stereo_sgbm=ensemble:ensemble.members=stereo+sgbm",
    "ensemble_stereo_bm=ensemble:ensemble.members=stereo+bm",
    "bev_sweep", "bev_sweep_ride=bev_sweep:bev_sweep.min_score=0.7",
)


@dataclass(frozen=True)
class Candidate:
    """A configuration of the node and what it costs there.

    Attributes:
        name: the row's name (``stereo_int8``).
        backend: the backend.
        params: further node parameters (backend options as ``<backend>.<option>``, ``checkpoint``).
        latency_s: image stamp to preview received, when the node keeps up (p50, map on).
        period_s: the node's time per frame (inference and the rest of its work): frames that arrive
            faster wait in its one-set mailbox and the newest wins.
        pace: the pace backend's latency and period where ``params`` name a ``pace_backend``
            other than ``backend`` (the node model paces the candidate: :func:`node_schedule`).
    """

    name: str
    backend: str
    params: Mapping[str, Any] = field(default_factory=dict)
    latency_s: float = 0.1
    period_s: float = 0.0
    pace: tuple[float, float] | None = None

    def config(self, grid: GridSpec, extra: Mapping[str, Any] | None = None) -> RoadbevConfig:
        """The pipeline's config for this candidate on ``grid`` (map on). Its pipeline builds no
        pace backend: the node model paces (:func:`node_schedule`, :class:`PacedEstimates`)."""
        params = {**grid.to_dict(), "backend": self.backend, "map.enabled": True, **self.params, **(extra or {}),
                  "pace_backend": ""}
        return check_config(RoadbevConfig.from_params(params))

    @property
    def pace_backend(self) -> str:
        """The pace backend its spec names ("" where none, or the chosen backend itself)."""
        return stand_in(str(self.params.get("pace_backend", "")), self.backend)

    @property
    def pace_load(self) -> float:
        """Its ``pace_load`` (the node's default where its spec names none)."""
        return float(self.params.get("pace_load", RoadbevConfig().backend.pace_load))

    @property
    def pace_lead_m(self) -> float:
        """Its ``pace_lead_m`` (the node's default where its spec names none)."""
        return float(self.params.get("pace_lead_m", RoadbevConfig().backend.pace_lead_m))

    def pace_candidate(self) -> Candidate:
        """Its pace backend as a candidate of its own (the options and far field it runs with).

        Raises:
            ValueError: it names no pace backend, or has no pace costs.
        """
        if not self.pace_backend or self.pace is None:
            raise ValueError(f"candidate {self.name!r} is not paced")
        name, params = self.pace_params()
        return Candidate(f"{self.name}:{name}", name, params, *self.pace)

    def pace_params(self) -> tuple[str, dict[str, Any]]:
        """Its pace backend's name and node parameters: its own but those of the pacing and of
        its chosen backend, with the options the ``pace_backend`` spec gives over them (as
        :func:`roadbev_core.pipeline.build_pace_backends` builds it)."""
        name, options = split_backend_spec(self.pace_backend, "pace_backend")
        params = {k: v for k, v in self.params.items() if not k.startswith(("pace_", f"{self.backend}."))}
        return name, {**params, **{f"{name}.{key}": value for key, value in options.items()}}

    def backend_options(self) -> dict[str, Any]:
        """The options the registry builds the backend with (as the node's config gives them)."""
        return self.config(GridSpec()).backend.options_of()


def add_candidate_arguments(parser: argparse.ArgumentParser, frame_cache: Path, candidates_help: str) -> None:
    """The options of a benchmark that runs node candidates with their error budget:
    ``--candidates``, ``--node-results``, ``--budget`` and ``--frame-cache``."""
    parser.add_argument("--candidates", nargs="*", default=list(DEFAULT_CANDIDATES), metavar="NAME=BACKEND[:P=V,...]",
                        help=candidates_help)
    parser.add_argument("--node-results", nargs="+", default=[str(RESULTS / "node_candidates.json")], metavar="JSON",
                        help="bench_node --drive results (one or more): each candidate's latency and time per "
                             "frame in the node")
    parser.add_argument("--charge", nargs="+", default=[], metavar="NAME=LATENCY_MS/PERIOD_MS",
                        help="charge these candidates a stated latency on arrival and time per frame (ms) instead "
                             "of their node rows: what another machine measured, or one cost for every "
                             "candidate so that only their estimates differ")
    parser.add_argument("--budget", nargs="*", default=None, metavar="NAME",
                        help="add the error budget of these candidates (all when none is named): one row per "
                             "stage taken from the truth (preview_budget.STAGES)")
    parser.add_argument("--frame-cache", default=str(frame_cache), metavar="DIR",
                        help="rendered drive frames are kept here and read back by later runs")


def candidates_from_args(args: argparse.Namespace) -> list[Candidate]:
    """The candidates :func:`add_candidate_arguments`' options ask for (none without ``--candidates``),
    each charged its node row's cost or its ``--charge``.

    Raises:
        ValueError: a bad ``--charge``; an unreadable ``--node-results``, or a candidate without a
            row there or a charge (the message names the files).
    """
    charges = parse_charges(args.charge)
    if not args.candidates:
        return []
    try:
        rows = node_rows([json.loads(Path(path).read_text()) for path in args.node_results])
        return candidates_from_node(args.candidates, rows, charges)
    except (OSError, ValueError, KeyError) as exc:
        raise ValueError(f"--node-results {args.node_results}: {exc}") from None


def parse_candidate(spec: str) -> tuple[str, str, dict[str, Any]]:
    """``NAME=BACKEND[:PARAM=VALUE,...]`` -> (name, backend, node params); a bare ``BACKEND`` names itself.
    Values are read as JSON where they parse (numbers, true/false), else kept as strings."""
    name, eq, rest = spec.partition("=")
    if not eq:
        name, rest = spec.split(":", 1)[0], spec
    backend, _, options = rest.partition(":")
    params: dict[str, Any] = {}
    for item in filter(None, options.split(",")):
        key, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"{spec!r}: option {item!r} is not PARAM=VALUE")
        try:
            params[key] = json.loads(value)
        except ValueError:
            params[key] = value
    return name, backend, params


def parse_charges(specs: Sequence[str]) -> dict[str, tuple[float, float]]:
    """``NAME=LATENCY_MS/PERIOD_MS`` (``--charge``) -> {name: (latency s, period s)}.

    Raises:
        ValueError: a spec not of that form, a cost that is not a positive number, or a name twice.
    """
    out: dict[str, tuple[float, float]] = {}
    for spec in specs:
        name, eq, costs = spec.partition("=")
        latency, slash, period = costs.partition("/")
        try:
            values = (float(latency), float(period))
        except ValueError:
            values = (math.nan, math.nan)
        if not (name and eq and slash) or not all(math.isfinite(v) and v > 0 for v in values):
            raise ValueError(f"--charge {spec!r}: not NAME=LATENCY_MS/PERIOD_MS with positive milliseconds")
        if name in out:
            raise ValueError(f"--charge: {name!r} is charged twice")
        out[name] = (values[0] * 1e-3, values[1] * 1e-3)
    return out


def candidates_from_node(specs: Sequence[str], node_results: Sequence[Mapping[str, Any]],
                         charges: Mapping[str, tuple[float, float]] | None = None) -> list[Candidate]:
    """Candidates (``NAME=BACKEND[:PARAM=VALUE,...]``) with the latency and period their node row
    measured, or those ``charges`` states for them (:func:`parse_charges`: no node row needed).

    A node row (``benchmarks.bench_node`` JSON, ``rows``) matches a candidate when its backend and
    options are the candidate's; the latency is its p50 on arrival in real time (``latency_on_arrival_ms``:
    the end-to-end latency less each frame's wait for the node, which :func:`node_schedule` adds
    itself; a row measured before that key existed gives its end-to-end p50, which counts the waits
    of a node slower than the camera twice), the period its inference p50 plus the node's own
    overhead (mean).

    Raises:
        ValueError: a candidate without a node row (measure it first) or a charge, or a charge for
            no candidate.
    """
    charges = dict(charges or {})
    out = []
    for spec in specs:
        name, backend, params = parse_candidate(spec)
        if name in charges:
            latency_s, period_s = charges.pop(name)
            out.append(Candidate(name, backend, params, latency_s, period_s))
            continue
        latency_s, period_s = _row_costs(spec, backend, params, node_results)
        candidate = Candidate(name, backend, params, latency_s, period_s)
        if candidate.pace_backend:
            pace = _row_costs(f"{spec} (its pace_backend)", *candidate.pace_params(), node_results)
            candidate = replace(candidate, pace=pace)
        out.append(candidate)
    if charges:
        raise ValueError(f"--charge: no candidate named {', '.join(sorted(charges))}")
    return out


def _row_costs(spec: str, backend: str, params: Mapping[str, Any], rows: Sequence[Mapping[str, Any]]
               ) -> tuple[float, float]:
    """The latency (p50 on arrival) and period (inference p50 plus overhead) of ``backend``'s node row.

    Raises:
        ValueError: no such row.
    """
    row = _node_row(backend, params, rows)
    if row is None:
        raise ValueError(f"candidate {spec!r}: no bench_node row with backend {backend} and these options")
    period = (float(row["inference_p50_ms"]) + float(row["overhead_mean_ms"])) * 1e-3
    latency = row.get("latency_on_arrival_ms", row["latency_ms"])
    return float(latency["p50"]) * 1e-3, period


FAR_FIELD_KEY = "far_field.enabled"


def node_rows(results: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The rows of ``bench_node --drive`` results (their JSONs), each with the node parameters its
    run set for every row (``node_params``, e.g. ``far_field.enabled``)."""
    return [{**row, "node_params": dict(data.get("node_params") or {})} for data in results for row in data["rows"]]


def _costs(backend: str, params: Mapping[str, Any]) -> dict[str, str]:
    """The parameters among ``params`` that change what the node spends on a frame: the backend's
    options (``<backend>.<option>``) and the far field's (``far_field.*``); the preview's do not."""
    return {key: str(value) for key, value in params.items()
            if key.startswith(f"{backend}.") or key.startswith("far_field.")}


def _node_row(backend: str, params: Mapping[str, Any], rows: Sequence[Mapping[str, Any]]) -> Mapping[str, Any] | None:
    """The ``5hz`` row (the bag's own timing, as a camera delivers it) of ``backend`` run with
    exactly the cost-bearing parameters (:func:`_costs`) of ``params``: its backend options and
    the node parameters of its run (:func:`node_rows`). A row where a pace backend answered frames
    (``paced_frames``) measured two backends at once and is never one backend's cost.

    ``far_field.enabled`` takes its default where the candidate leaves it out. ``bench_node`` names
    it in every result it writes; a result that does not recorded only the parameters it was given,
    with the far field off unless given, and its rows count as measured with it off."""
    want = _costs(backend, {FAR_FIELD_KEY: RoadbevConfig().far_field.enabled, **params})
    for row in rows:
        name, _, options = str(row["backend"]).partition(":")
        have = {f"{name}.{item.partition('=')[0]}": item.partition("=")[2] for item in filter(None, options.split(","))}
        have.update(_costs(name, {FAR_FIELD_KEY: False, **(row.get("node_params") or {})}))
        if row.get("mode") == "5hz" and name == backend and have == want and not row.get("paced_frames"):
            return row
    return None


def node_schedule(stamps_ns: Sequence[int], period_s: float, latency_s: float, *,
                  pace: tuple[float, float] | None = None, pace_load: float = 1.0, pace_lead_m: float = 0.0,
                  speed_mps: float | None = None) -> list[tuple[int, int, bool]]:
    """The frames a node with a one-set mailbox processes, when each preview is received, and
    which ones its pace backend answers.

    A frame that arrives while the node is busy waits in the mailbox; a newer one replaces it. A
    frame processed on arrival is received ``latency_s`` after its stamp; one that waited, that
    much plus its wait. With ``pace`` (the pace backend's latency and period) a
    :class:`roadbev_core.pacing.Pacer` with ``pace_load`` and ``pace_lead_m`` chooses for each
    frame the node takes, as the node's does: told every set by the time the frame is taken, the
    car's speed (``speed_mps``) and each frame's time (the period of the backend that answered it).

    Returns:
        [(index into ``stamps_ns``, received ns, answered by the pace backend)] in stamp order.
    """
    costs = {False: (int(round(period_s * 1e9)), int(round(latency_s * 1e9)))}
    pacer = None
    if pace is not None:
        costs[True] = (int(round(pace[1] * 1e9)), int(round(pace[0] * 1e9)))
        pacer = Pacer(pace_load, lead_m=pace_lead_m)
    out: list[tuple[int, int, bool]] = []
    free_at = -(2**62)
    told = 0  # sets the pacer has been told of
    i, n = 0, len(stamps_ns)
    while i < n:
        if stamps_ns[i] >= free_at:
            start = int(stamps_ns[i])
        else:  # busy: the newest frame that arrived before the node is free waits for it
            j = i
            while j + 1 < n and stamps_ns[j + 1] <= free_at:
                j += 1
            i, start = j, free_at
        paced = False
        if pacer is not None:
            while told < n and stamps_ns[told] <= start:
                pacer.note_set(stamps_ns[told] * 1e-9)  # each set arrives at its stamp
                told += 1
            paced = pacer.choose(speed_mps)
        period, latency = costs[paced]
        out.append((i, start + latency, paced))
        if pacer is not None:
            pacer.note_cost(paced, period * 1e-9)
        free_at = start + period
        i += 1
    return out


class CachedEstimates:
    """A backend whose estimates are kept by frame stamp, so that every row of a drive (budget
    stages, camera rates, per frame and fused) uses the same estimate of a frame.

    ``on_grid`` builds (``build(grid)``) and caches the same kind of backend on another grid: the
    far-field one the pipeline asks for with ``far_field.enabled``.
    """

    def __init__(self, inner: Backend, build: Callable[[GridSpec], Backend] | None = None) -> None:
        self.inner = inner
        self.name = inner.name
        self.grid = inner.grid
        self.needs_stereo = inner.needs_stereo
        self.far_field = bool(getattr(inner, "far_field", False))
        self.estimates: dict[int, Estimate] = {}
        self._build = build
        self._other_grids: dict[GridSpec, CachedEstimates] = {}

    def estimate(self, frame: Frame) -> Estimate:
        stamp = int(frame.stamp_ns)
        if stamp not in self.estimates:
            self.estimates[stamp] = self.inner.estimate(frame)
        return self.estimates[stamp]

    def on_grid(self, grid: GridSpec) -> CachedEstimates:
        """This backend on ``grid`` (itself on its own grid), its estimates cached too.

        Raises:
            ValueError: another grid, and no way to build the backend on it.
        """
        if grid == self.grid:
            return self
        if grid not in self._other_grids:
            if self._build is None:
                raise ValueError(f"{self.name}: no backend on the grid {grid} (built without a factory)")
            self._other_grids[grid] = CachedEstimates(self._build(grid))
        return self._other_grids[grid]


class PacedEstimates:
    """A paced candidate's estimates: its pace backend's on the frames the node model handed to it
    (``paced``: their stamps, set by :func:`candidate_previews` for each schedule), the chosen
    backend's on the others; each cached by stamp, and on another grid (the far field's) alike."""

    def __init__(self, chosen: CachedEstimates, pace: CachedEstimates, paced: set[int] | None = None) -> None:
        self.chosen, self.pace = chosen, pace
        self.paced: set[int] = set() if paced is None else paced
        self.name, self.grid, self.needs_stereo = chosen.name, chosen.grid, chosen.needs_stereo
        self.far_field = chosen.far_field
        self._other_grids: dict[GridSpec, PacedEstimates] = {}

    def estimate(self, frame: Frame) -> Estimate:
        return (self.pace if int(frame.stamp_ns) in self.paced else self.chosen).estimate(frame)

    def on_grid(self, grid: GridSpec) -> PacedEstimates:
        """Both backends on ``grid``, paced on the same frames."""
        if grid == self.grid:
            return self
        if grid not in self._other_grids:
            self._other_grids[grid] = PacedEstimates(self.chosen.on_grid(grid), self.pace.on_grid(grid), self.paced)
        return self._other_grids[grid]


# a candidate's estimates (make_backend)
Estimates = CachedEstimates | PacedEstimates


def _window_mean(values: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """[R, C] the mean of the finite cells of ``values`` [R, C] in a ``rows`` x ``cols`` window
    (odd) around each cell (NaN where the window holds none): the ratio of the window means
    (:func:`roadbev_core.box_filter.box_mean`) of the known heights and of the known mask."""
    known = np.isfinite(values)
    planes = torch.from_numpy(np.stack([np.where(known, values, 0.0), known]).astype(np.float64))  # [2, R, C]
    total, count = box_mean(planes, (rows, cols)).numpy()
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / count, np.nan)


def _odd_cells(length_m: float, resolution: float) -> int:
    return 2 * int(round(0.5 * length_m / resolution)) + 1


def label_features(label: np.ndarray, resolution: float) -> np.ndarray:
    """[R, C] bool: the cells of a label [R, C] (NaN = unlabelled) that belong to the road's
    features: at least :data:`FEATURE_THRESHOLD_M` off the label's mean over :data:`FEATURE_WINDOW_M`
    (along x, across), and the cells within :data:`FEATURE_MARGIN_M` of them."""
    mean = _window_mean(label, _odd_cells(FEATURE_WINDOW_M[0], resolution), _odd_cells(FEATURE_WINDOW_M[1], resolution))
    with np.errstate(invalid="ignore"):
        off = np.abs(label - mean) > FEATURE_THRESHOLD_M
    margin = _odd_cells(2 * FEATURE_MARGIN_M, resolution)
    return np.asarray((_window_mean(off.astype(np.float64), margin, margin) > 0) & np.isfinite(label))


def short_band(elevation: np.ndarray, resolution: float) -> np.ndarray:
    """[R, C] the relief of ``elevation`` [R, C] shorter than :data:`SHORT_BAND_M` along x: the
    heights less their mean over that length (NaN where the height is)."""
    return np.asarray(elevation - _window_mean(elevation, _odd_cells(SHORT_BAND_M, resolution), 1))


def stages_of(candidate: Candidate, grid: GridSpec) -> tuple[str, ...]:
    """The error budget's stages of ``candidate`` on ``grid``: :data:`STAGES`, less
    :data:`FAR_STAGES` where it has no far field."""
    if candidate.config(grid).far_grid is not None:
        return STAGES
    return tuple(s for s in STAGES if s not in FAR_STAGES)


class _TruthBackend:
    """The cached estimates with the truth in one label mode: the frame's labels on the cells
    the backend answered (``true_answered``), on those of the road's features or the others
    (``true_features``, ``true_surface``), the labels' short band with the estimate's long one
    (``true_short``), the labels on every labelled cell (``true_all``; sigma there: the frame's
    median), or the estimate's error and sigma halved on the answered cells (``half_error``)."""

    MODES = ("true_answered", "true_features", "true_surface", "true_short", "true_all", "half_error")

    def __init__(self, cached: Estimates, labels: Mapping[int, np.ndarray], stage: str) -> None:
        if stage not in self.MODES:
            raise ValueError(f"{stage!r} is not a label mode (one of {', '.join(self.MODES)})")
        self.cached, self.labels, self.stage = cached, labels, stage
        self.name, self.grid, self.needs_stereo = cached.name, cached.grid, cached.needs_stereo
        self.far_field = cached.far_field

    def estimate(self, frame: Frame) -> Estimate:
        est = self.cached.estimate(frame)
        truth = self.labels[int(frame.stamp_ns)]
        answered = np.isfinite(est.elevation) & np.isfinite(truth)
        resolution = self.grid.resolution
        sigma = est.uncertainty
        if self.stage == "true_all":
            elevation = truth
            known = est.uncertainty[np.isfinite(est.uncertainty)]
            fill = float(np.median(known)) if known.size else 0.005
            sigma = np.where(np.isfinite(est.uncertainty), est.uncertainty, fill)
        elif self.stage == "true_answered":
            elevation = np.where(np.isfinite(est.elevation), truth, np.nan)
        elif self.stage == "half_error":
            elevation = np.where(answered, 0.5 * (est.elevation + truth), est.elevation)
            sigma = np.where(answered, 0.5 * sigma, sigma)
        elif self.stage == "true_short":
            mixed = est.elevation - short_band(est.elevation, resolution) + short_band(truth, resolution)
            elevation = np.where(answered & np.isfinite(mixed), mixed, est.elevation)
        else:
            features = label_features(truth, resolution)
            take = answered & (features if self.stage == "true_features" else ~features)
            elevation = np.where(take, truth, est.elevation)
        sigma = np.where(np.isfinite(elevation), sigma, np.nan)
        return Estimate(elevation.astype(np.float32), sigma.astype(np.float32), dict(est.timings_ms))


class TrueDatumMap(FusedMap):
    """A fused map that places every frame at the true height of ``base_link`` (``odom`` z, which
    planar odometry never gives); run it with ``map.align`` off so that no alignment moves it."""

    def __init__(self, settings: MapSettings, truth: Trajectory) -> None:
        super().__init__(settings)
        self._truth = truth

    def integrate(self, elevation: np.ndarray, sigma: np.ndarray, grid: GridSpec, placement: FramePlacement,
                  stamp_ns: int, *, base_z_prediction: float) -> FrameFusion:
        position, _ = self._truth.interpolate(np.array([stamp_ns], np.int64))
        return super().integrate(elevation, sigma, grid, placement, stamp_ns,
                                 base_z_prediction=float(position[0, 2]))


def with_true_plane(previews: Sequence[TimedPreview], truth: Trajectory, road_map: RoadMap,
                    settings: RideSettings) -> list[TimedPreview]:
    """Contact-plane previews re-read against the true road's contact plane at their stamps, on the
    map's own datum (the true plane moved to the mean height the message's plane has at the four
    tyre contacts); other previews unchanged."""
    planes = [p for p in previews if p.reference == REFERENCE_CONTACT_PLANE and p.profiles.contact_plane]
    if not planes:
        return list(previews)
    stamps = np.array([p.stamp_ns for p in planes], np.int64)
    pos, R = truth.interpolate(stamps)
    yaw = planar_yaw(R)
    true = true_contact_planes(truth, road_map, settings, stamps)  # [M, 3] z = a + b x + c y in odom
    wheels = settings.arrival.vehicle.wheel_positions()  # [4, 2] base_link
    replaced: dict[int, TimedPreview] = {}
    for m, msg in enumerate(planes):
        plane = msg.profiles.contact_plane
        assert plane is not None
        c, s = math.cos(yaw[m]), math.sin(yaw[m])
        # the true plane in base_link's heading frame: height at the origin and slopes along / across
        slope_x, slope_y = true[m, 1] * c + true[m, 2] * s, -true[m, 1] * s + true[m, 2] * c
        height0 = true[m, 0] + true[m, 1] * pos[m, 0] + true[m, 2] * pos[m, 1] - pos[m, 2]
        true_at = height0 + slope_x * wheels[:, 0] + slope_y * wheels[:, 1]  # [4]
        est_at = plane.height_at(wheels[:, 0], wheels[:, 1])  # [4]
        offset = float(np.mean(est_at - true_at))  # the map's datum against the truth's, at the contacts
        x = msg.profiles.distances()  # [S]
        tracks = []
        for track in msg.profiles.tracks:
            est_ref = plane.height_at(x, np.full(x.size, track.lateral_offset))
            true_ref = height0 + offset + slope_x * x + slope_y * track.lateral_offset
            tracks.append(TrackProfile(track.name, track.lateral_offset, track.width,
                                       (track.elevation + est_ref - true_ref).astype(np.float32), track.uncertainty))
        pitch = -math.atan(slope_x)
        roll = math.atan(slope_y * math.cos(pitch))
        new_plane = ContactPlane(height0 + offset, roll, pitch, 0.0, 0.0, 0.0, plane.source)
        profiles = replace(msg.profiles, tracks=tuple(tracks), contact_plane=new_plane)
        replaced[msg.stamp_ns] = replace(msg, profiles=profiles)
    return [replaced.get(p.stamp_ns, p) if p.reference == REFERENCE_CONTACT_PLANE else p for p in previews]


def candidate_previews(drive: RidingDrive, samples: Sequence[DriveSample], candidate: Candidate,
                       cached: Estimates, stage: str, *, step: int = 1, ride_settings: RideSettings,
                       map_on: bool = True, on_map: Callable[[MapWindow], Any] | None = None) -> list[TimedPreview]:
    """The previews of ``candidate`` with the map on, with ``stage`` of the error budget taken from
    the truth, on every ``step``-th frame of a rendered drive as the node's schedule lets it fuse
    them (each stamped with when it is received).

    Args:
        map_on: False: the per-frame pipeline (``map.enabled`` false; its previews in ``roadbev_road``).
        on_map: called with every published map window (map on).

    Raises:
        ValueError: an unknown stage, or a far stage (:data:`FAR_STAGES`) of a candidate without a far
            field.
    """
    if stage not in STAGES:
        raise ValueError(f"unknown budget stage {stage!r} (one of {', '.join(STAGES)})")
    gt = drive.ground_truth_poses()
    truth = Trajectory(gt.stamp_ns, gt.position, gt.orientation_xyzw)
    frames = list(samples)[::step]
    stamps = [int(s.frame.stamp_ns) for s in frames]
    if stage == "no_latency":  # every frame at its stamp, by the chosen backend
        schedule = [(i, stamp, False) for i, stamp in enumerate(stamps)]
    else:
        schedule = node_schedule(stamps, candidate.period_s, candidate.latency_s, pace=candidate.pace,
                                 pace_load=candidate.pace_load, pace_lead_m=candidate.pace_lead_m,
                                 speed_mps=drive.config.speed_mps)
    if isinstance(cached, PacedEstimates):
        cached.paced.clear()
        cached.paced.update(stamps[i] for i, _, paced in schedule if paced)
    fused_frames = [frames[i] for i, _, _ in schedule]
    received = {stamps[i]: at for i, at, _ in schedule}
    backend: Backend = cached
    extra: dict[str, Any] = {} if map_on else {"map.enabled": False}
    map_factory: Callable[[MapSettings], FusedMap] = FusedMap
    if stage == "true_datum":
        extra["map.align"] = False
        map_factory = lambda settings: TrueDatumMap(settings, truth)  # noqa: E731
    config = candidate.config(drive.config.grid, extra)
    far_backend: Backend | None = None
    if stage in FAR_STAGES and config.far_grid is None:
        raise ValueError(f"budget stage {stage!r} changes the far field, and {candidate.name!r} has none")
    if stage in LABEL_STAGES:
        labels = {int(s.frame.stamp_ns): s.truth.elevation for s in samples}
        if stage not in FAR_STAGES:
            backend = _TruthBackend(cached, labels, stage)
        if config.far_grid is not None:  # the truth in the same stage on the far field (or a far stage's)
            far_labels = {int(s.frame.stamp_ns): s.far_truth.elevation for s in samples if s.far_truth is not None}
            if len(far_labels) != len(labels) or any(v.shape != config.far_grid.shape for v in far_labels.values()):
                raise ValueError(f"budget stage {stage!r} needs the far field's labels on {config.far_grid}: "
                                 "render the drive with that far_grid (DriveConfig.far_grid)")
            far_backend = _TruthBackend(cached.on_grid(config.far_grid), far_labels, _FAR_ONLY.get(stage, stage))

    def backend_on(_name: str, grid: GridSpec, **_options: Any) -> Backend:
        if grid == config.grid:
            return backend
        return far_backend if far_backend is not None else cached.on_grid(grid)  # the far field on its own grid

    pipeline = Pipeline(config, backend_factory=backend_on, map_factory=map_factory, configure_process=False)
    pipeline.set_camera_mount(*drive.base_to_camera)
    odometry = drive.ground_truth_poses() if stage == "true_odometry" else drive.odometry()
    outputs: list[Any] = []

    def keep(output: PipelineOutput) -> None:
        outputs.extend(per_frame_previews([output]))
        if on_map is not None and output.map is not None:
            on_map(output.map)

    evaluate(pipeline, fused_frames, odometry=planar_odometry(odometry) if map_on else None, on_output=keep)
    previews = [replace(p, received_ns=received[p.stamp_ns]) for p in outputs]
    if stage == "true_plane":
        previews = with_true_plane(previews, truth, drive.road_map(), ride_settings)
    return previews


def budgeted(name: str, budget: Sequence[str] | None) -> bool:
    """Whether the candidate ``name`` gets the error budget's rows: ``budget`` names it, or is
    empty (every candidate); None: no budget."""
    return budget is not None and (not budget or name in budget)


def far_label_grid(candidates: Sequence[Candidate], budget: Sequence[str] | None, grid: GridSpec) -> GridSpec | None:
    """The far-field grid a drive on ``grid`` must label for the budget's label stages
    (:data:`LABEL_STAGES`): the one of the budgeted candidates with a far field, or None.

    Raises:
        ValueError: budgeted candidates on different far-field grids (a drive labels one).
    """
    grids = {c.config(grid).far_grid for c in candidates if budgeted(c.name, budget)} - {None}
    if len(grids) > 1:
        raise ValueError("the budgeted candidates ask for different far-field grids; a drive labels one: budget them "
                         "in separate runs")
    return next(iter(grids), None)


def make_backend(candidate: Candidate, grid: GridSpec) -> Estimates:
    """The candidate's backend on ``grid`` (and on the far-field grid when asked), its estimates
    cached by stamp; a paced candidate's with its pace backend's (:class:`PacedEstimates`)."""
    chosen = _cached(candidate, grid)
    return chosen if candidate.pace is None else PacedEstimates(chosen, _cached(candidate.pace_candidate(), grid))


def _cached(candidate: Candidate, grid: GridSpec) -> CachedEstimates:
    options = candidate.backend_options()
    return CachedEstimates(create(candidate.backend, grid, **options),
                           lambda other: create(candidate.backend, other, **options))


class DriveFrames:
    """The rendered frames of riding drives kept on disk, so that a benchmark renders a drive once
    and every later run (other candidates, other stages) reads it back (keyed by the drive's whole
    configuration and the renderer's versions).

    A drive with a far-field grid (``DriveConfig.far_grid``) also gets that grid's labels
    (``DriveSample.far_truth``), kept beside the frame's with the grid they are on. The far labels
    are drawn after everything else a frame draws, so a frame stored without them is rendered once
    more to add them: its images and grid labels come out the same (checked), and it is stored
    again with the far labels.
    """

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)

    def folder(self, drive: RidingDrive) -> Path:
        # A far-field grid only adds labels drawn after everything a frame draws: the frames are the
        # same with it or without, so it is no part of the key (which also keeps the keys of frames
        # stored before the drive's config had the field).
        riding = replace(drive.riding, drive=replace(drive.riding.drive, far_grid=None))
        key = f"{riding!r}".replace(", far_grid=None", "") + f"/scene-v{SCENE_VERSION}/drive-v{DRIVE_VERSION}"
        return self.root / hashlib.sha1(key.encode()).hexdigest()[:16]

    def samples(self, drive: RidingDrive) -> list[DriveSample]:
        """Every frame of ``drive`` (rendered and stored when not on disk yet, or when the drive
        asks for far-field labels the stored frame lacks).

        Raises:
            ValueError: a drive that does not render stereo frames, or a stored frame the renderer
                no longer reproduces (a stale store: remove its folder).
        """
        folder = self.folder(drive)
        folder.mkdir(parents=True, exist_ok=True)
        far_grid = drive.config.far_grid
        out = []
        for index in range(len(drive)):
            path = folder / f"{index:05d}.npz"
            stored = _read_frame(path, far_grid) if path.exists() else None
            if stored is not None and (far_grid is None or stored[3] is not None):
                left, right, labels, far_labels = stored
                _, attitude = drive.pose(index)
                frame = Frame(left, right, drive.config.camera, attitude, drive.frame_stamps_ns[index])
                out.append(DriveSample(frame, _label(labels), np.zeros((0, 3), np.float32),
                                       None if far_labels is None else _label(far_labels)))
                continue
            sample = drive[index]
            if sample.frame.right is None:
                raise ValueError("a riding drive renders stereo frames")
            if stored is not None and not (np.array_equal(stored[0], sample.frame.left)
                                           and np.array_equal(stored[1], sample.frame.right)
                                           and np.array_equal(stored[2], sample.truth.elevation, equal_nan=True)):
                raise ValueError(f"{path}: the stored frame is not the one the renderer draws now (remove {folder})")
            arrays: dict[str, Any] = {"left": sample.frame.left, "right": sample.frame.right,
                                      "truth": sample.truth.elevation}
            if sample.far_truth is not None and far_grid is not None:
                arrays.update(far_truth=sample.far_truth.elevation, far_grid=np.array(repr(far_grid)))
            tmp = path.with_suffix(".tmp.npz")
            np.savez(tmp, **arrays)
            tmp.replace(path)  # atomic: a killed run never leaves half a frame
            out.append(DriveSample(sample.frame, sample.truth, np.zeros((0, 3), np.float32), sample.far_truth))
        return out


def _label(elevation: np.ndarray) -> ElevationLabel:
    """A stored label map (NaN = unlabelled) as an :class:`ElevationLabel`."""
    known = np.isfinite(elevation)
    return ElevationLabel(elevation, known, known.astype(np.int32))


def _read_frame(path: Path, far_grid: GridSpec | None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """A stored frame: left, right, the grid's labels and the far-field labels on ``far_grid``
    (None when not asked for, or stored on another far grid or not at all)."""
    with np.load(path) as data:
        far = None
        if far_grid is not None and "far_truth" in data.files and str(data["far_grid"]) == repr(far_grid):
            far = data["far_truth"]
        return data["left"], data["right"], data["truth"], far
