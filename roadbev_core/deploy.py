"""Deploying the learned models: ONNX export and the inference engines that run the export.

``roadbev export CKPT OUT --format onnx`` writes the network of a checkpoint as one ONNX graph
(:func:`export_onnx`) and :class:`OnnxRunner` runs such a graph in ONNX Runtime (CPU, CUDA or
TensorRT execution provider) or OpenVINO (CPU); the learned backends use it for their
``runtime`` option.

What is in the graph, and what is not: everything that depends on the images (backbone, feature
pyramid, voxel feature query, photometric channel, head, soft-argmin). What depends only on the
rig and the attitude, where every voxel is read in each image (:func:`roadbev_core.models.roadbev.voxel_geometry`,
a few milliseconds of arithmetic), stays outside and comes in as inputs, so one file serves
every rig and attitude of the checkpoint's grid (:func:`geometry_feeds`).

Graph (``FORMAT``, opset :data:`OPSET`; B is dynamic, so are the grey frames' H and W):

======================= ======= ================================== =============================
input                   dtype   shape                              what
======================= ======= ================================== =============================
``left`` (``right``)    uint8   [B, 3, h, w]                       RGB at the model's input size
                                                                   (:func:`prepare_image`)
``grey``                uint8   [B, 2, H, W]                       full-size grey left / right
                                                                   (stereo ``lite``: the
                                                                   photometric channel)
``coords_left`` (...)   float32 [B, Nz*Ny, Nx, 2]                  feature-map lookup, grid_sample
                                                                   coordinates in [-1, 1]
``mask_left`` (...)     float32 [B, Nz, Ny, Nx]                    1 where the voxel is in view
``fine_coords_*``,      float32 [B, Nz*nNy, nNx, 2],               the photometric channel's
``fine_mask_*``                 [B, Nz, nNy, nNx]                  lookups (n = zncc_subsamples)
======================= ======= ================================== =============================

Outputs: ``elevation`` and ``uncertainty`` (float32 [B, R, C] metres, the output grid) and
``observed`` (bool [B, R, C]). Nz, Ny, Nx are the model's internal grid; the ONNX metadata
(``metadata_props``) carries ``roadbev_format``, ``model_config`` and ``grid`` (JSON, the
checkpoint's), ``inputs`` (name -> shape), ``opset`` and the checkpoint's ``meta``.
"""

from __future__ import annotations

import copy
import json
import tempfile
import threading
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch
from torch import nn

from roadbev_core.config import ConfigError, GridSpec, StereoCamera
from roadbev_core.geometry import Attitude
from roadbev_core.models.adabins import AdaBinsLite
from roadbev_core.models.efficientnet import fold_batchnorm
from roadbev_core.models.gwcnet import GwcNetConfig, GwcNetLite
from roadbev_core.models.loss import soft_argmin
from roadbev_core.models.presets import ModelConfig
from roadbev_core.models.roadbev import (
    RoadBEV,
    VoxelGeometry,
    needs_full_grey,
    prepare_grey,
    prepare_image,
    voxel_geometry,
)
from roadbev_core.models.voxel_query import VoxelLookup

__all__ = [
    "FORMAT",
    "OPSET",
    "RUNTIMES",
    "DeployError",
    "OnnxModel",
    "OnnxRunner",
    "export_onnx",
    "frame_feeds",
    "geometry_feeds",
    "image_feeds",
    "input_names",
    "quantize_int8",
    "read_onnx",
    "trtexec_shapes",
    "write_graph",
]

FORMAT = "roadbev-onnx/1"
OPSET = 17  # GridSample needs 16; 17 is what TensorRT 8.6+ and every current ONNX Runtime read
RUNTIMES = ("torch", "onnxruntime", "openvino")
OUTPUTS = ("elevation", "uncertainty", "observed")
# ONNX Runtime execution providers by the short names the backends' ``provider`` option takes.
PROVIDERS = {
    "cpu": "CPUExecutionProvider",
    "cuda": "CUDAExecutionProvider",
    "tensorrt": "TensorrtExecutionProvider",
}
_EYES = ("left", "right")


class DeployError(RuntimeError):
    """An export or a runtime that cannot work here (missing package, foreign file, bad option)."""


def input_names(config: ModelConfig) -> list[str]:
    """The graph's inputs for a ``config`` model, in order."""
    stereo = config.kind == "stereo"
    eyes = _EYES if stereo else _EYES[:1]
    names = list(eyes)
    if needs_full_grey(config):
        names.append("grey")
    for eye in eyes:
        names += [f"coords_{eye}", f"mask_{eye}"]
    if stereo and config.photometric:
        for eye in eyes:
            names += [f"fine_coords_{eye}", f"fine_mask_{eye}"]
    return names


def geometry_feeds(
    config: ModelConfig, grid: GridSpec, cameras: Sequence[StereoCamera], attitudes: Sequence[Attitude]
) -> dict[str, np.ndarray]:
    """The graph's geometry inputs for a batch (the rig- and attitude-only part of the model)."""
    geometry = voxel_geometry(config, grid, list(cameras), list(attitudes))
    feeds: dict[str, np.ndarray] = {}
    for prefix, looks in (("", (geometry.left, geometry.right)), ("fine_", (geometry.fine_left, geometry.fine_right))):
        for eye, look in zip(_EYES, looks, strict=True):
            if look is not None:
                feeds[f"{prefix}coords_{eye}"] = look.coords.numpy()
                feeds[f"{prefix}mask_{eye}"] = look.mask.numpy().astype(np.float32)
    return feeds


def image_feeds(config: ModelConfig, left: np.ndarray, right: np.ndarray | None) -> dict[str, np.ndarray]:
    """The graph's image inputs of one frame (batch 1) from RGB (or grey) uint8 [H, W(, 3)] images."""
    feeds = {"left": prepare_image(left, config)[None]}
    if config.kind == "stereo":
        if right is None:
            raise DeployError("RoadBEV-stereo needs a right image")
        feeds["right"] = prepare_image(right, config)[None]
        if needs_full_grey(config):
            feeds["grey"] = prepare_grey(left, right)[None]
    return feeds


class _Exportable(nn.Module):
    """A RoadBEV network with its geometry as tensor inputs and soft-argmin inside (what is traced)."""

    def __init__(self, model: RoadBEV, gather: bool = False) -> None:
        super().__init__()
        self.model = model
        self.names = input_names(model.config)
        self.gather = gather

    def forward(self, *inputs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        named = dict(zip(self.names, inputs, strict=True))

        def look(prefix: str, eye: str) -> VoxelLookup | None:
            coords = named.get(f"{prefix}coords_{eye}")
            mask = named.get(f"{prefix}mask_{eye}")
            return None if coords is None or mask is None else VoxelLookup(coords, mask > 0.5)

        left = look("", "left")
        assert left is not None  # always an input (input_names)
        geometry = VoxelGeometry(left, look("", "right"), look("fine_", "left"), look("fine_", "right"))
        logits, observed = self.model.logits(named["left"], named.get("right"), named.get("grey"), geometry,
                                             gather=self.gather)
        elevation, uncertainty = soft_argmin(logits, self.model.centres)
        return elevation, uncertainty, observed


def _example_inputs(model: RoadBEV, camera: StereoCamera) -> tuple[torch.Tensor, ...]:
    cfg = model.config
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (camera.height, camera.width, 3), dtype=np.uint8)
    feeds = {**image_feeds(cfg, image, image if cfg.kind == "stereo" else None),
             **geometry_feeds(cfg, model.grid, [camera], [Attitude.from_degrees(0.0, 18.0)])}
    return tuple(torch.from_numpy(np.ascontiguousarray(feeds[name])) for name in input_names(cfg))


def export_onnx(
    model: RoadBEV,
    out: str | Path | None = None,
    *,
    meta: dict[str, Any] | None = None,
    camera: StereoCamera | None = None,
    opset: int = OPSET,
    gather: bool = False,
) -> bytes:
    """The ONNX graph of ``model`` (BatchNorm folded, fp32), written to ``out`` when given.

    Args:
        model: the network (not changed: a folded copy is traced).
        out: the ``.onnx`` file to write (atomically), or None.
        meta: recorded in the metadata (e.g. the checkpoint's ``meta``).
        camera: the rig of the example inputs that are traced (default the RSRD half rig); the
            graph serves any rig, this one only fixes nothing but the example values.
        opset: ONNX opset (>= 16 for GridSample).
        gather: voxel features by explicit gathers instead of GridSample nodes (the same numbers;
            ``voxel_query.gather_voxels``), for engines without a fast GridSample.

    Returns:
        The serialised model.
    """
    if opset < 16:
        raise DeployError(f"opset {opset} lacks GridSample: use 16 or later")
    folded = copy.deepcopy(model).float().eval()
    fold_batchnorm(folded)
    net = _Exportable(folded, gather).eval()
    cfg = model.config
    names = input_names(cfg)
    example = _example_inputs(model, camera or StereoCamera.rsrd_half())
    dynamic: dict[str, dict[int, str]] = {name: {0: "batch"} for name in [*names, *OUTPUTS]}
    if "grey" in dynamic:
        dynamic["grey"] = {0: "batch", 2: "height", 3: "width"}
    proto = _traced(net, example, names, list(OUTPUTS), dynamic, opset)
    shapes: dict[str, list[str | int]] = {
        name: ["B" if i == 0 else int(n) for i, n in enumerate(t.shape)] for name, t in zip(names, example, strict=True)
    }
    if "grey" in shapes:
        shapes["grey"] = ["B", 2, "H", "W"]
    props = {
        "roadbev_format": FORMAT,
        "model_config": json.dumps(cfg.to_dict()),
        "grid": json.dumps(model.grid.to_dict()),
        "inputs": json.dumps(shapes),
        "outputs": json.dumps({name: ["B", model.grid.n_rows, model.grid.n_cols] for name in OUTPUTS}),
        "opset": str(opset),
        "meta": json.dumps(meta or {}, default=str),
    }
    return _finished(proto, props, out)


def _traced(net: nn.Module, example: tuple[torch.Tensor, ...], inputs: Sequence[str], outputs: Sequence[str],
            dynamic: dict[str, dict[int, str]], opset: int) -> Any:
    """The ONNX model proto of ``net`` traced on ``example`` (fp32, constants folded)."""
    # lazy: an optional extra (pip install .[onnx] / .[openvino]), loaded only to export or run that runtime
    import onnx

    with torch.no_grad(), warnings.catch_warnings(), tempfile.TemporaryDirectory(prefix="roadbev_onnx_") as tmp:
        # the tracer warns about every Python-level shape check; the graph's shapes are fixed by
        # the config except the documented dynamic axes, which the equality tests exercise
        warnings.simplefilter("ignore", category=torch.jit.TracerWarning)
        traced = Path(tmp) / "model.onnx"
        torch.onnx.export(net, example, str(traced), dynamo=False, input_names=list(inputs),
                          output_names=list(outputs), dynamic_axes=dynamic, opset_version=opset,
                          do_constant_folding=True)
        return onnx.load_from_string(traced.read_bytes())


def _finished(proto: Any, props: dict[str, str], out: str | Path | None) -> bytes:
    """``proto`` with its metadata ``props``, serialised, and written to ``out`` when given."""
    import onnx

    onnx.helper.set_model_props(proto, props)
    proto.producer_name = "roadbev"
    data = proto.SerializeToString()
    if out is not None:
        write_graph(data, out)
    return cast("bytes", data)


# The baselines' graphs: kind -> (input names, output names).
BASELINE_IO = {"gwcnet": (("left", "right"), ("disparity", "sigma")),
               "adabins": (("image",), ("depth", "sigma", "centres"))}


def export_baseline_onnx(model: GwcNetLite | AdaBinsLite, kind: str, out: str | Path | None = None, *,
                         meta: dict[str, Any] | None = None, opset: int = OPSET) -> bytes:
    """The ONNX graph of an image-view baseline (``gwcnet``: inputs ``left``, ``right`` [B, 3, H, W]
    uint8 of any size that is a multiple of 8, outputs ``disparity``, ``sigma`` [B, H, W];
    ``adabins``: input ``image`` [B, 3, h, w] uint8 at its input size, outputs ``depth``, ``sigma``
    [B, h / 2, w / 2] and ``centres`` [B, n_bins]), fp32, written to ``out`` when given."""
    if kind not in BASELINE_IO:
        raise DeployError(f"unknown baseline {kind!r}; one of {', '.join(BASELINE_IO)}")
    inputs, outputs = BASELINE_IO[kind]
    net = copy.deepcopy(model).float().eval()
    config = net.config
    if isinstance(config, GwcNetConfig):
        example: tuple[torch.Tensor, ...] = (torch.zeros(1, 3, 64, 128, dtype=torch.uint8),) * 2
        dynamic = {name: {0: "batch", 2: "height", 3: "width"} for name in inputs}
        dynamic.update({name: {0: "batch", 1: "height", 2: "width"} for name in outputs})
    else:
        example = (torch.zeros(1, 3, config.input_height, config.input_width, dtype=torch.uint8),)
        dynamic = {name: {0: "batch"} for name in (*inputs, *outputs)}
    proto = _traced(net, example, inputs, outputs, dynamic, opset)
    return _finished(proto, {"roadbev_baseline": kind, "model_config": json.dumps(config.to_dict()),
                             "opset": str(opset), "meta": json.dumps(meta or {}, default=str)}, out)


def write_graph(data: bytes, out: str | Path) -> Path:
    """Write a serialised graph to ``out`` atomically (a partial file never has the final name)."""
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.name + ".tmp")
    partial.write_bytes(data)
    partial.replace(path)
    return path


def frame_feeds(config: ModelConfig, grid: GridSpec, frame: Any) -> dict[str, np.ndarray]:
    """Every input of the graph for one :class:`~roadbev_core.frame.Frame` (batch 1)."""
    feeds = image_feeds(config, frame.left, frame.right)
    feeds.update(geometry_feeds(config, grid, [frame.camera], [frame.attitude]))
    return feeds


# What int8 quantisation touches: the convolutions (2-D backbone and 3-D head), nothing else. The
# voxel sampling coordinates, GridSample, the classification's softmax and soft-argmin stay fp32:
# quantising every op the quantiser can (NNCF's default scope) ruins the shipped stereo model's
# accuracy.
INT8_OP_TYPES = ("Conv",)


def quantize_int8(data: bytes, calibration: Sequence[dict[str, np.ndarray]]) -> bytes:
    """Post-training static int8 quantisation of a RoadBEV ONNX graph (ONNX Runtime's quantiser).

    The convolutions get int8 weights per output channel and uint8 activations in and out,
    whose ranges are the min / max seen over the ``calibration`` feeds (QuantizeLinear /
    DequantizeLinear pairs, QDQ: ONNX Runtime, OpenVINO and TensorRT run them as int8 kernels);
    every other op computes in fp32 (:data:`INT8_OP_TYPES`). The RoadBEV metadata is kept; its ``meta``
    records the scheme and the number of calibration frames under ``quantization``.

    Args:
        data: a graph from :func:`export_onnx` (fp32).
        calibration: feeds of representative frames (:func:`frame_feeds`): training frames,
            never the test set.

    Raises:
        DeployError: not a RoadBEV fp32 graph, no calibration frames, or the quantiser failed.
    """
    # lazy: an optional extra (pip install .[onnx] / .[openvino]), loaded only to export or run that runtime
    import onnx
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.calibrate import CalibrationMethod

    if not calibration:
        raise DeployError("int8 quantisation needs at least one calibration frame")
    proto = onnx.load_from_string(data)
    props = {p.key: p.value for p in proto.metadata_props}
    if props.get("roadbev_format") != FORMAT:
        raise DeployError(f"not a RoadBEV export (metadata roadbev_format {FORMAT!r})")
    meta = json.loads(props.get("meta", "{}"))
    if "quantization" in meta:
        raise DeployError(f"the graph is quantised already ({meta['quantization']['scheme']})")

    class _Frames(CalibrationDataReader):
        def __init__(self) -> None:
            self._feeds = iter(calibration)

        def get_next(self) -> dict[str, np.ndarray] | None:
            return next(self._feeds, None)

    with tempfile.TemporaryDirectory(prefix="roadbev_int8_") as tmp:
        source, target = Path(tmp) / "fp32.onnx", Path(tmp) / "int8.onnx"
        source.write_bytes(data)
        try:
            quantize_static(str(source), str(target), _Frames(), quant_format=QuantFormat.QDQ,
                            op_types_to_quantize=list(INT8_OP_TYPES), per_channel=True,
                            activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8,
                            calibrate_method=CalibrationMethod.MinMax)
        except Exception as exc:  # the quantiser raises bare Exceptions and onnx/ORT errors
            raise DeployError(f"int8 quantisation failed: {exc.__class__.__name__}: {exc}") from exc
        quantized = onnx.load_from_string(target.read_bytes())
    meta["quantization"] = {
        "scheme": "int8 QDQ: " + "/".join(INT8_OP_TYPES) + " weights per channel (int8), activations uint8, min/max",
        "calibration_frames": len(calibration),
    }
    onnx.helper.set_model_props(quantized, {**props, "meta": json.dumps(meta, default=str)})
    quantized.producer_name = "roadbev"
    return bytes(quantized.SerializeToString())


def trtexec_shapes(config: ModelConfig, grid: GridSpec, width: int, height: int, batch: int = 1) -> str:
    """The ``--shapes`` argument of TensorRT's ``trtexec`` for frames of ``width`` x ``height``."""
    camera = StereoCamera(fx=width, fy=width, cx=(width - 1) / 2, cy=(height - 1) / 2, baseline=0.5,
                          width=width, height=height)  # shapes only: any rig of that image size
    image = np.zeros((height, width, 3), np.uint8)
    feeds = {**image_feeds(config, image, image if config.kind == "stereo" else None),
             **geometry_feeds(config, grid, [camera], [Attitude.from_degrees(0.0, 18.0)])}
    return ",".join(f"{name}:" + "x".join(str(batch if i == 0 else n) for i, n in enumerate(feeds[name].shape))
                    for name in input_names(config))


@dataclass(frozen=True)
class OnnxModel:
    """A RoadBEV ONNX graph and what its metadata says about it."""

    data: bytes
    config: ModelConfig
    grid: GridSpec
    meta: dict[str, Any]


def read_onnx(path: str | Path) -> OnnxModel:
    """Read an exported ``.onnx`` file and its RoadBEV metadata.

    Raises:
        DeployError: missing, unreadable or not a RoadBEV export.
    """
    # lazy: an optional extra (pip install .[onnx] / .[openvino]), loaded only to export or run that runtime
    import onnx

    path = Path(path)
    if not path.is_file():
        raise DeployError(f"ONNX file {path} does not exist")
    data = path.read_bytes()
    try:
        proto = onnx.load_from_string(data)
    except Exception as exc:  # protobuf raises its own DecodeError types
        raise DeployError(f"{path} is not a readable ONNX file: {exc.__class__.__name__}") from exc
    props = {p.key: p.value for p in proto.metadata_props}
    if props.get("roadbev_format") != FORMAT:
        raise DeployError(f"{path} is not a RoadBEV export (metadata roadbev_format {FORMAT!r})")
    try:
        config = ModelConfig.from_dict(json.loads(props["model_config"]))
        grid = GridSpec.from_dict(json.loads(props["grid"]))
        meta = json.loads(props.get("meta", "{}"))
    except (KeyError, ValueError, TypeError, ConfigError) as exc:
        raise DeployError(f"{path} has bad RoadBEV metadata: {exc}") from exc
    return OnnxModel(data, config, grid, meta)


def same_graph_grid(a: GridSpec, b: GridSpec) -> bool:
    """Whether a graph built for grid ``a`` computes grid ``b``: same cell, voxel and class counts
    and bins. Window position and ``base_height`` only move the geometry inputs."""
    return (a.shape == b.shape and a.n_z == b.n_z and np.allclose(a.class_centres(), b.class_centres())
            and abs(a.resolution - b.resolution) < 1e-9)


class OnnxRunner:
    """One RoadBEV ONNX graph in an inference engine (``onnxruntime`` or ``openvino``).

    Args:
        data: the serialised graph (:func:`export_onnx`).
        runtime: ``onnxruntime`` or ``openvino``.
        threads: intra-op threads (None: the engine's default, all cores).
        provider: ONNX Runtime execution provider, ``cpu``, ``cuda`` or ``tensorrt`` (the GPU ones
            need the ``onnxruntime-gpu`` package and a GPU; ONNX Runtime falls back to the CPU for
            nodes they cannot run). OpenVINO runs on its ``CPU`` device.

    Raises:
        DeployError: the engine is not installed, or the provider is not available.
    """

    def __init__(self, data: bytes, runtime: str, *, threads: int | None = None, provider: str = "cpu") -> None:
        if runtime not in RUNTIMES[1:]:
            raise DeployError(f"runtime must be one of {', '.join(RUNTIMES[1:])} for an ONNX graph, got {runtime!r}")
        self.runtime = runtime
        self.provider = provider
        if runtime == "onnxruntime":
            self._run = self._onnxruntime(data, threads, provider)
        else:
            if provider != "cpu":
                raise DeployError(f"the openvino runtime runs on the CPU here; provider {provider!r} is ONNX Runtime's")
            self._run = self._openvino(data, threads)

    @staticmethod
    def _onnxruntime(data: bytes, threads: int | None, provider: str) -> Any:
        try:
            # lazy: an optional extra (pip install .[onnx] / .[openvino]), loaded only to export or run that runtime
            import onnxruntime as ort
        except ImportError as exc:
            raise DeployError("runtime onnxruntime needs the onnxruntime package (pip install onnxruntime)") from exc
        if provider not in PROVIDERS:
            raise DeployError(f"provider must be one of {', '.join(PROVIDERS)}, got {provider!r}")
        available = ort.get_available_providers()
        if PROVIDERS[provider] not in available:
            raise DeployError(f"ONNX Runtime has no {PROVIDERS[provider]} here (available: {', '.join(available)})")
        options = ort.SessionOptions()
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.intra_op_num_threads = int(threads or 0)
        options.inter_op_num_threads = 1
        options.add_session_config_entry("session.set_denormal_as_zero", "1")
        # the chosen provider first; TensorRT falls back to CUDA (where present), every one to the CPU
        fallbacks = {"tensorrt": ("tensorrt", "cuda", "cpu"), "cuda": ("cuda", "cpu"), "cpu": ("cpu",)}[provider]
        chain = [PROVIDERS[name] for name in fallbacks if PROVIDERS[name] in available]
        session = ort.InferenceSession(data, sess_options=options, providers=chain)

        def run(feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
            return list(session.run(list(OUTPUTS), feeds))

        return run

    @staticmethod
    def _openvino(data: bytes, threads: int | None) -> Any:
        try:
            import openvino  # noqa: F401
        except ImportError as exc:
            raise DeployError("runtime openvino needs the openvino package (pip install openvino)") from exc
        return _OpenVinoEngine(data, threads)

    def run(self, feeds: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """elevation, uncertainty [B, R, C] float32 and observed [B, R, C] bool for the graph's inputs."""
        elevation, uncertainty, observed = self._run(feeds)
        return elevation, uncertainty, observed.astype(bool, copy=False)


class _OpenVinoEngine:
    """OpenVINO on the CPU: the graph compiled for any shape, and for each input shape it meets
    compiled again with those shapes fixed (faster than the any-shape graph), before that shape's
    first frame runs. The two compilations do not give the same numbers to the last bit, so
    every frame of a shape is computed by the same one whatever came before (the node and
    ``roadbev eval`` agree): the first shape is compiled by the node's warm-up (``Pipeline.warm_up``,
    on the common rig, before the node subscribes to its inputs); a new rig's first frame waits
    for its compilation (seconds, once; the node drops the frames that arrive meanwhile)."""

    def __init__(self, data: bytes, threads: int | None) -> None:
        # lazy: an optional extra (pip install .[onnx] / .[openvino]), loaded only to export or run that runtime
        import openvino as ov

        self._core = ov.Core()
        with tempfile.TemporaryDirectory(prefix="roadbev_ov_") as tmp:
            path = Path(tmp) / "model.onnx"
            path.write_bytes(data)
            self._model = self._core.read_model(str(path))
        self._config: dict[str, Any] = {"PERFORMANCE_HINT": "LATENCY", "INFERENCE_PRECISION_HINT": "f32",
                                        "CPU_DENORMALS_OPTIMIZATION": True}
        if threads:
            self._config["INFERENCE_NUM_THREADS"] = int(threads)
        self._any_shape = self._compile(self._model)
        self._fixed: dict[tuple[tuple[str, tuple[int, ...]], ...], Any] = {}
        self._lock = threading.Lock()

    def _compile(self, model: Any) -> Any:
        compiled = self._core.compile_model(model, "CPU", self._config)
        names = [out.get_any_name() for out in compiled.outputs]
        return compiled.create_infer_request(), names

    def _compile_fixed(self, key: tuple[tuple[str, tuple[int, ...]], ...]) -> Any:
        try:
            model = self._model.clone()
            model.reshape({name: list(shape) for name, shape in key})
            return self._compile(model)
        except Exception:  # the any-shape model serves this shape (a shape OpenVINO cannot fix)
            return None

    def __call__(self, feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
        key = tuple(sorted((name, tuple(int(n) for n in value.shape)) for name, value in feeds.items()))
        with self._lock:
            if key not in self._fixed:
                self._fixed[key] = self._compile_fixed(key)
            fixed = self._fixed[key]
        request, names = fixed or self._any_shape
        results = request.infer(feeds)
        by_name = {names[i]: np.asarray(value) for i, value in enumerate(results.values())}
        return [by_name[name] for name in OUTPUTS]
