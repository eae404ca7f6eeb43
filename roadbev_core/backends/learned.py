"""Learned backends ``stereo`` and ``mono``: RoadBEV networks from a checkpoint.

Options:
    checkpoint: path of a RoadBEV checkpoint (``roadbev train`` / ``roadbev export``) or of an ONNX
        export (``roadbev export CKPT OUT.onnx --format onnx``); default the shipped
        ``checkpoints/roadbev_{stereo,mono}_lite.pt`` of this repository.
    threads: intra-op threads of the runtime (default: torch's current setting, which the node's
        ``inference_threads`` sets).
    runtime: ``torch``, ``onnxruntime`` or ``openvino`` (:mod:`roadbev_core.deploy`): the network
        as an ONNX graph in that engine; a ``.pt`` checkpoint is exported in memory at start-up (a
        few seconds), an ``.onnx`` file is read as it is. Default (:data:`DEFAULT_RUNTIMES`):
        ``openvino`` for stereo, which then runs the shipped int8 graph where it was exported for
        the grid (else the ``.pt`` exported in memory), ``torch`` for mono.
    provider: ONNX Runtime's execution provider, ``cpu`` (default), ``cuda`` or ``tensorrt``
        (with ``onnxruntime-gpu`` on a GPU machine).
    out_of_distribution: ``refuse`` (default): a grid (at creation) or a rig (per frame) beyond
        the checkpoint's training envelope (:class:`roadbev_core.checkpoint.TrainingEnvelope`) is
        refused with the reason; ``flag``: run anyway and mark every cell out of distribution with
        a sigma of the grid's whole height range.

Inference folds BatchNorm into the convolutions and runs channels-last with denormals flushed
(both roughly halve the backbone's CPU time). Cells whose voxels the camera(s) do
not see get NaN elevation and uncertainty.
"""

from __future__ import annotations

import importlib.util
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from roadbev_core.backends import BackendError
from roadbev_core.checkpoint import CheckpointError, load_model, training_envelope
from roadbev_core.config import GridSpec
from roadbev_core.deploy import (
    RUNTIMES,
    DeployError,
    OnnxRunner,
    export_onnx,
    geometry_feeds,
    image_feeds,
    read_onnx,
    same_graph_grid,
)
from roadbev_core.frame import Estimate, Frame, FrameError
from roadbev_core.models.efficientnet import fold_batchnorm
from roadbev_core.models.roadbev import needs_full_grey, prepare_grey, prepare_image
from roadbev_core.share import find_shared, shared_candidates

__all__ = [
    "DEFAULT_RUNTIMES",
    "OOD_MODES",
    "LearnedBackend",
    "OutOfDistributionError",
    "checkpoint_dir",
    "create_mono",
    "create_stereo",
    "default_checkpoint",
]

OOD_MODES = ("refuse", "flag")


class OutOfDistributionError(FrameError):
    """A frame whose rig lies beyond what the checkpoint was trained for (refused)."""

def checkpoint_dir() -> Path:
    """The shipped checkpoints: the source tree's ``checkpoints/``, else an install's share
    (``share/roadbev_ros/checkpoints``, :mod:`roadbev_core.share`); the source tree's path when
    neither exists (the error then names it)."""
    return find_shared("checkpoints") or shared_candidates("checkpoints")[0]


# The engine each kind runs without a ``runtime`` option: stereo's int8 graph on OpenVINO is the
# fastest CPU inference of it at the same accuracy (docs/results/learned_models.md, "Inference runtimes"), which is what
# lets it fuse every frame of a 10 Hz camera; mono has no int8 graph.
DEFAULT_RUNTIMES = {"stereo": "openvino", "mono": "torch"}


def default_checkpoint(kind: str, runtime: str = "torch", grid: GridSpec | None = None) -> Path:
    """The shipped checkpoint of ``kind`` for ``runtime`` (may not exist in a stripped install):
    stereo on OpenVINO takes the int8 graph when it was exported for ``grid`` (any grid when None),
    everything else the ``.pt``."""
    if kind == "stereo" and runtime == "openvino":
        int8 = checkpoint_dir() / "roadbev_stereo_lite_int8.onnx"
        if int8.is_file():
            try:
                fits = grid is None or same_graph_grid(read_onnx(int8).grid, grid)
            except DeployError:
                fits = False  # a damaged graph: the .pt, exported in memory, still runs
            if fits:
                return int8
    return checkpoint_dir() / f"roadbev_{kind}_lite.pt"


class LearnedBackend:
    """A RoadBEV network behind the backend protocol."""

    def __init__(self, kind: str, grid: GridSpec, *, checkpoint: str | Path | None = None,
                 threads: int | None = None, runtime: str | None = None, provider: str = "cpu",
                 out_of_distribution: str = "refuse") -> None:
        if out_of_distribution not in OOD_MODES:
            raise BackendError(f"{kind} backend: out_of_distribution must be one of {', '.join(OOD_MODES)}, "
                               f"got {out_of_distribution!r}")
        self.flag_out_of_distribution = out_of_distribution == "flag"
        runtime = runtime or DEFAULT_RUNTIMES[kind]
        path = Path(checkpoint) if checkpoint else default_checkpoint(kind, runtime, grid)
        if not path.is_file():
            raise BackendError(
                f"{kind} backend: checkpoint {path} not found (train one with `roadbev train --kind {kind}` "
                "or pass checkpoint=PATH)"
            )
        if runtime not in RUNTIMES:
            raise BackendError(f"{kind} backend: runtime must be one of {', '.join(RUNTIMES)}, got {runtime!r}")
        self.runtime = runtime
        self.provider = str(provider)
        self.threads = int(threads) if threads else None
        self._runner: OnnxRunner | None = None
        self._onnx: bytes | None = None
        self.name = kind
        if runtime != "torch":
            self._check_runtime()
        if path.suffix == ".onnx":
            self._init_onnx(kind, grid, path)
            return
        try:
            model, payload = load_model(path, grid=grid)
        except CheckpointError as exc:
            raise BackendError(f"{kind} backend: {exc}") from exc
        if model.config.kind != kind:
            raise BackendError(f"{kind} backend: {path} holds a RoadBEV-{model.config.kind} model")
        self._check_envelope(kind, grid, path, payload)
        if threads and runtime == "torch":
            torch.set_num_threads(int(threads))
        self.name = kind
        self.grid = grid
        self.needs_stereo = kind == "stereo"
        self.checkpoint = path
        self.meta: dict[str, Any] = dict(payload.get("meta", {}))
        self.model = fold_batchnorm(model.eval())
        for part in (self.model.backbone, self.model.fusion) if self.needs_stereo else (self.model,):
            # 2-D convs only (the 3-D head stays NCDHW). Module.to takes memory_format at run time;
            # torch's overloads of it do not list the keyword.
            part.to(memory_format=torch.channels_last)  # type: ignore[call-overload]
        self.config = model.config
        if runtime != "torch":
            self._onnx = export_onnx(model, meta=self.meta)

    def _init_onnx(self, kind: str, grid: GridSpec, path: Path) -> None:
        """An exported graph: its metadata instead of the checkpoint's, no torch network."""
        if self.runtime == "torch":
            raise BackendError(f"{kind} backend: {path} is an ONNX export: run it with runtime onnxruntime or openvino")
        try:
            exported = read_onnx(path)
        except DeployError as exc:
            raise BackendError(f"{kind} backend: {exc}") from exc
        if exported.config.kind != kind:
            raise BackendError(f"{kind} backend: {path} holds a RoadBEV-{exported.config.kind} model")
        if not same_graph_grid(exported.grid, grid):
            raise BackendError(
                f"{kind} backend: {path} was exported for a {exported.grid.n_rows}x{exported.grid.n_cols} grid "
                f"with {exported.grid.n_classes} classes; export it for this grid ({grid.n_rows}x{grid.n_cols})"
            )
        self._check_envelope(kind, grid, path, {"grid": exported.grid.to_dict(), **exported.meta})
        self.name = kind
        self.grid = grid
        self.needs_stereo = kind == "stereo"
        self.checkpoint = path
        self.meta = dict(exported.meta)
        self.config = exported.config
        self._onnx = exported.data

    def _check_runtime(self) -> None:
        """Fail at creation (not at the first frame) when the engine or provider is missing."""
        if self.runtime == "openvino" and self.provider != "cpu":
            raise BackendError(
                f"{self.name} backend: provider {self.provider!r} is ONNX Runtime's; openvino runs on the CPU"
            )
        module = {"onnxruntime": "onnxruntime", "openvino": "openvino"}[self.runtime]
        if importlib.util.find_spec(module) is None:
            raise BackendError(f"{self.name} backend: runtime {self.runtime} needs the {module} package "
                               f"(pip install {module})")

    def _engine(self) -> OnnxRunner:
        """The inference session, made on the first frame (so it takes the threads set by then)."""
        if self._runner is None:
            assert self._onnx is not None
            try:
                self._runner = OnnxRunner(self._onnx, self.runtime, threads=self.threads or torch.get_num_threads(),
                                          provider=self.provider)
            except DeployError as exc:
                raise BackendError(f"{self.name} backend: {exc}") from exc
        return self._runner

    @torch.inference_mode()
    def estimate(self, frame: Frame) -> Estimate:
        """Elevation and 1-sigma uncertainty for one frame (NaN where the camera sees no voxel)."""
        if self.needs_stereo and frame.right is None:
            raise FrameError("the stereo backend needs a right image")
        rig_problems = self.envelope.rig_problems(frame.camera, self.needs_stereo)
        if rig_problems and not self.flag_out_of_distribution:
            raise OutOfDistributionError(
                f"{self.name} backend: the rig is outside what {self.checkpoint.name} was trained for: "
                f"{'; '.join(rig_problems)} (or run with out_of_distribution=flag)"
            )
        outside = self.grid_out_of_distribution or bool(rig_problems)
        torch.set_flush_denormal(True)
        if self._onnx is not None:
            return self._flagged(self._estimate_onnx(frame), outside)
        t0 = time.perf_counter()
        left = torch.from_numpy(prepare_image(frame.left, self.config))[None]
        right = (
            torch.from_numpy(prepare_image(frame.right, self.config))[None]
            if self.needs_stereo and frame.right is not None  # (checked above)
            else None
        )
        grey = (
            torch.from_numpy(prepare_grey(frame.left, frame.right))[None]
            if frame.right is not None and needs_full_grey(self.config)
            else None
        )
        t1 = time.perf_counter()
        pred = self.model.predict(
            left.contiguous(memory_format=torch.channels_last),
            None if right is None else right.contiguous(memory_format=torch.channels_last),
            [frame.camera], [frame.attitude], grey,
        )
        t2 = time.perf_counter()
        seen = pred.observed[0].numpy()
        elevation = np.where(seen, pred.elevation[0].numpy(), np.nan).astype(np.float32)
        uncertainty = np.where(seen, pred.uncertainty[0].numpy(), np.nan).astype(np.float32)
        t3 = time.perf_counter()
        timings = {"preprocess": 1e3 * (t1 - t0), "network": 1e3 * (t2 - t1), "post": 1e3 * (t3 - t2)}
        return self._flagged(Estimate(elevation=elevation, uncertainty=uncertainty, timings_ms=timings), outside)

    def _flagged(self, estimate: Estimate, outside: bool) -> Estimate:
        """Out of the training envelope (with ``out_of_distribution=flag``): every cell as unsure as
        the grid's whole height range, and the estimate marked."""
        if outside:
            seen = np.isfinite(estimate.elevation)
            estimate.uncertainty = np.where(seen, self.grid.z_max - self.grid.z_min, np.nan).astype(np.float32)
            estimate.out_of_distribution = True
        return estimate

    def _check_envelope(self, kind: str, grid: GridSpec, path: Path, payload: dict[str, Any]) -> None:
        """The grid must be one the network was trained for (refused, or flagged on request)."""
        try:
            self.envelope = training_envelope(payload)
        except CheckpointError as exc:
            raise BackendError(f"{kind} backend: {path}: {exc}") from exc
        problems = self.envelope.grid_problems(grid)
        if problems and not self.flag_out_of_distribution:
            raise BackendError(
                f"{kind} backend: the grid is outside what {path.name} was trained for: {'; '.join(problems)} "
                "(train for this grid, or pass out_of_distribution=flag to run with every cell flagged)"
            )
        self.grid_out_of_distribution = bool(problems)

    def _estimate_onnx(self, frame: Frame) -> Estimate:
        engine = self._engine()
        t0 = time.perf_counter()
        feeds = image_feeds(self.config, frame.left, frame.right)
        t1 = time.perf_counter()
        feeds.update(geometry_feeds(self.config, self.grid, [frame.camera], [frame.attitude]))
        t2 = time.perf_counter()
        elevation, uncertainty, observed = engine.run(feeds)
        t3 = time.perf_counter()
        seen = observed[0]
        elevation = np.where(seen, elevation[0], np.nan).astype(np.float32)
        uncertainty = np.where(seen, uncertainty[0], np.nan).astype(np.float32)
        t4 = time.perf_counter()
        timings = {"preprocess": 1e3 * (t1 - t0), "projection": 1e3 * (t2 - t1), "network": 1e3 * (t3 - t2),
                   "post": 1e3 * (t4 - t3)}
        return Estimate(elevation=elevation, uncertainty=uncertainty, timings_ms=timings)


def create_stereo(grid: GridSpec, **options: Any) -> LearnedBackend:
    """Backend factory of RoadBEV-stereo (options: see :class:`LearnedBackend`)."""
    return LearnedBackend("stereo", grid, **options)


def create_mono(grid: GridSpec, **options: Any) -> LearnedBackend:
    """Backend factory of RoadBEV-mono (options: see :class:`LearnedBackend`)."""
    return LearnedBackend("mono", grid, **options)
