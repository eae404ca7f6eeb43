"""ONNX export of the RoadBEV networks and the ONNX Runtime / OpenVINO runners against torch."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch

from roadbev_core.backends import BackendError, create
from roadbev_core.checkpoint import save_checkpoint
from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.deploy import (
    BASELINE_IO,
    FORMAT,
    DeployError,
    OnnxRunner,
    export_baseline_onnx,
    export_onnx,
    frame_feeds,
    geometry_feeds,
    image_feeds,
    input_names,
    quantize_int8,
    read_onnx,
)
from roadbev_core.frame import Frame
from roadbev_core.geometry import Attitude
from roadbev_core.models.adabins import AdaBinsConfig, AdaBinsLite
from roadbev_core.models.gwcnet import GwcNetConfig, GwcNetLite
from roadbev_core.models.presets import model_config
from roadbev_core.models.roadbev import RoadBEV, voxel_geometry
from roadbev_core.models.voxel_query import gather_voxels, query_voxels

CAMERA = StereoCamera.rsrd_half().scaled(0.25)  # 240 x 132
ATTITUDES = [Attitude.from_degrees(0.4, 18.5), Attitude.from_degrees(-0.8, 16.9), Attitude.from_degrees(1.2, 21.0)]
TOLERANCE_CM = 0.005  # the bound on the mean |ONNX - torch| of elevation and uncertainty


def _frames(stereo: bool, camera: StereoCamera = CAMERA) -> list[Frame]:
    """A few frames of textured noise, each with its own attitude."""
    rng = np.random.default_rng(3)
    frames = []
    for attitude in ATTITUDES:
        left = rng.integers(0, 255, (camera.height, camera.width, 3), dtype=np.uint8)
        right = np.roll(left, -2, axis=1) if stereo else None  # a shifted copy: something to match
        frames.append(Frame(left, right, camera, attitude))
    return frames


@pytest.fixture(scope="module", params=["stereo", "mono"])
def tiny(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> tuple[str, Path, Path]:
    """A tiny-preset checkpoint with trained-looking BatchNorm statistics and its ONNX export."""
    kind = str(request.param)
    torch.manual_seed(1)
    model = RoadBEV(model_config("tiny", kind), GridSpec())
    with torch.no_grad():  # non-trivial BatchNorm statistics, so that folding them is exercised
        for module in model.modules():
            if isinstance(module, torch.nn.modules.batchnorm._BatchNorm):
                assert module.running_mean is not None and module.running_var is not None
                module.running_mean.uniform_(-0.1, 0.1)
                module.running_var.uniform_(0.5, 1.5)
    folder = tmp_path_factory.mktemp(kind)
    checkpoint = save_checkpoint(folder / f"{kind}.pt", model, meta={"note": "test"})
    onnx_path = folder / f"{kind}.onnx"
    export_onnx(model, onnx_path, meta={"note": "test"})
    return kind, checkpoint, onnx_path


def _mean_diff_cm(a: np.ndarray, b: np.ndarray) -> float:
    assert np.array_equal(np.isfinite(a), np.isfinite(b))
    seen = np.isfinite(a)
    assert seen.mean() > 0.5
    return float(np.abs(a[seen] - b[seen]).mean() * 100.0)


def test_the_graph_documents_itself(tiny: tuple[str, Path, Path]) -> None:
    kind, _, path = tiny
    proto = onnx.load(str(path))
    onnx.checker.check_model(proto)
    props = {p.key: p.value for p in proto.metadata_props}
    assert props["roadbev_format"] == FORMAT
    config = json.loads(props["model_config"])
    assert config["kind"] == kind and config["input_width"] == 224
    assert GridSpec.from_dict(json.loads(props["grid"])) == GridSpec()
    assert json.loads(props["meta"]) == {"note": "test"}
    names = [i.name for i in proto.graph.input]
    assert names == input_names(read_onnx(path).config)
    assert [o.name for o in proto.graph.output] == ["elevation", "uncertainty", "observed"]
    assert ("right" in names) == (kind == "stereo") and ("grey" in names) == (kind == "stereo")
    batch = {i.name: i.type.tensor_type.shape.dim[0].dim_param for i in proto.graph.input}
    assert set(batch.values()) == {"batch"}  # one dynamic batch axis on every input
    assert json.loads(props["inputs"])["left"] == ["B", 3, 128, 224]


@pytest.mark.parametrize("runtime", ["onnxruntime", "openvino"])
def test_onnx_backend_equals_torch_on_every_rig_and_attitude(tiny: tuple[str, Path, Path], runtime: str) -> None:
    """The exported graph, fed by the geometry step, gives torch's elevation and uncertainty on
    frames of different attitudes and on a second rig (another image size) from one file."""
    pytest.importorskip(runtime)
    kind, checkpoint, path = tiny
    reference = create(kind, checkpoint=str(checkpoint))
    backends = [create(kind, checkpoint=str(path), runtime=runtime, threads=1)]
    if runtime == "onnxruntime":  # a .pt exported at start-up (once: each export takes seconds)
        backends.append(create(kind, checkpoint=str(checkpoint), runtime=runtime, threads=1))
    other_rig = StereoCamera.rsrd_half().scaled(0.3).cropped(4, 2, 280, 150)
    for frame in _frames(kind == "stereo") + _frames(kind == "stereo", other_rig)[:1]:
        want = reference.estimate(frame)
        for backend in backends:
            got = backend.estimate(frame)
            assert _mean_diff_cm(want.elevation, got.elevation) < TOLERANCE_CM
            assert _mean_diff_cm(want.uncertainty, got.uncertainty) < TOLERANCE_CM
            assert {"preprocess", "projection", "network", "post"} <= set(got.timings_ms)
    assert not np.allclose(want.elevation[np.isfinite(want.elevation)], 0.0)  # a real comparison


def test_geometry_comes_in_as_inputs(tiny: tuple[str, Path, Path]) -> None:
    """Different attitudes change only the geometry feeds, and the outputs follow them."""
    kind, _, path = tiny
    exported = read_onnx(path)
    runner = OnnxRunner(exported.data, "onnxruntime", threads=1)
    frame = _frames(kind == "stereo")[0]
    images = image_feeds(exported.config, frame.left, frame.right)
    outputs = []
    for attitude in ATTITUDES[:2]:
        feeds = {**images, **geometry_feeds(exported.config, exported.grid, [frame.camera], [attitude])}
        assert set(feeds) == set(input_names(exported.config))
        outputs.append(runner.run(feeds)[0])
    assert not np.allclose(outputs[0], outputs[1], rtol=0.0, atol=1e-6)  # (random weights: small changes)


def test_batched_feeds_run_in_one_call(tiny: tuple[str, Path, Path]) -> None:
    kind, _, path = tiny
    exported = read_onnx(path)
    runner = OnnxRunner(exported.data, "onnxruntime", threads=1)
    frames = _frames(kind == "stereo")[:2]
    singles = []
    for frame in frames:
        feeds = {**image_feeds(exported.config, frame.left, frame.right),
                 **geometry_feeds(exported.config, exported.grid, [frame.camera], [frame.attitude])}
        singles.append(runner.run(feeds)[0][0])
    per_frame = [image_feeds(exported.config, f.left, f.right) for f in frames]
    batch = {k: np.concatenate([p[k] for p in per_frame]) for k in per_frame[0]}
    batch.update(geometry_feeds(exported.config, exported.grid, [f.camera for f in frames],
                                [f.attitude for f in frames]))
    elevation = runner.run(batch)[0]
    assert elevation.shape == (2, *GridSpec().shape)
    np.testing.assert_allclose(elevation, np.stack(singles), atol=1e-5)


@pytest.mark.parametrize("sampling", ["bilinear", "integer"])
def test_gather_voxels_equals_grid_sample(sampling: str) -> None:
    """The Gather form of the voxel query (``--gather`` exports) reads the same numbers."""
    config = model_config("tiny", "stereo", sampling=sampling)
    geometry = voxel_geometry(config, GridSpec(), [CAMERA, CAMERA], ATTITUDES[:2])
    features = torch.randn(2, 5, 64, 112, generator=torch.Generator().manual_seed(0))
    for look in (geometry.left, geometry.right):
        assert look is not None
        want = query_voxels(features, look, sampling)
        got = gather_voxels(features, look, sampling)
        torch.testing.assert_close(got, want, atol=1e-5, rtol=1e-5)


def test_bad_files_options_and_grids_are_clear_errors(tiny: tuple[str, Path, Path], tmp_path: Path) -> None:
    kind, checkpoint, path = tiny
    other = "mono" if kind == "stereo" else "stereo"
    with pytest.raises(BackendError, match=f"RoadBEV-{kind}"):
        create(other, checkpoint=str(path), runtime="onnxruntime")
    with pytest.raises(BackendError, match="runtime onnxruntime or openvino"):
        create(kind, checkpoint=str(path), runtime="torch")  # an ONNX file with the torch runtime
    with pytest.raises(BackendError, match="runtime must be one of"):
        create(kind, checkpoint=str(checkpoint), runtime="tflite")
    with pytest.raises(BackendError, match="exported for a 164x64 grid"):
        create(kind, GridSpec(x_max=6.18), checkpoint=str(path), runtime="onnxruntime")
    # Another window and base height of the same shape: the same graph, other geometry inputs.
    moved = GridSpec(x_min=2.46, x_max=7.38, base_height=1.2)  # (within the training envelope)
    assert create(kind, moved, checkpoint=str(path), runtime="onnxruntime").grid == moved
    with pytest.raises(BackendError, match="has no CUDAExecutionProvider"):
        create(kind, checkpoint=str(path), runtime="onnxruntime", provider="cuda").estimate(
            _frames(kind == "stereo")[0])
    with pytest.raises(BackendError, match="provider must be one of"):
        create(kind, checkpoint=str(path), runtime="onnxruntime", provider="npu").estimate(
            _frames(kind == "stereo")[0])
    foreign = tmp_path / "foreign.onnx"
    foreign.write_bytes(b"\x08\x07not a model at all")
    with pytest.raises(BackendError, match=r"not a (readable ONNX file|RoadBEV export)"):
        create(kind, checkpoint=str(foreign), runtime="onnxruntime")
    with pytest.raises(DeployError, match="does not exist"):
        read_onnx(tmp_path / "none.onnx")
    with pytest.raises(DeployError, match="GridSample"):
        export_onnx(RoadBEV(model_config("tiny", kind), GridSpec()), opset=13)


def _consumers(proto: onnx.ModelProto) -> dict[str, set[str]]:
    """Tensor name -> op types of the nodes that read it, through Identity nodes (the exporter
    shares equal constants, a bias say, through them)."""
    direct: dict[str, list[onnx.NodeProto]] = {}
    for node in proto.graph.node:
        for name in node.input:
            direct.setdefault(name, []).append(node)

    def readers(name: str) -> set[str]:
        out: set[str] = set()
        for node in direct.get(name, []):
            out |= readers(node.output[0]) if node.op_type == "Identity" else {node.op_type}
        return out

    return {name: readers(name) for name in direct}


def test_int8_quantisation_touches_the_convolutions_only_and_keeps_the_metadata(tiny: tuple[str, Path, Path],
                                                                                tmp_path: Path) -> None:
    kind, _, onnx_path = tiny
    exported = read_onnx(onnx_path)
    feeds = [frame_feeds(exported.config, exported.grid, f) for f in _frames(kind == "stereo")]
    data = quantize_int8(exported.data, feeds)
    proto = onnx.load_from_string(data)
    readers = _consumers(proto)
    producer = {out: node for node in proto.graph.node for out in node.output}
    dequantized = [n for n in proto.graph.node if n.op_type == "DequantizeLinear"]

    def beside_a_conv(dq: onnx.NodeProto) -> bool:
        """A Conv's input (weight, bias, activation: a residual's Add may read it too) or a Conv's
        output: no other op's tensors are quantised."""
        if "Conv" in readers[dq.output[0]]:
            return True
        quantize = producer.get(dq.input[0])
        source = None if quantize is None else producer.get(quantize.input[0])
        return quantize is not None and quantize.op_type == "QuantizeLinear" and source is not None \
            and source.op_type == "Conv"

    assert dequantized and all(beside_a_conv(n) for n in dequantized)
    convs = [n for n in proto.graph.node if n.op_type == "Conv"]
    from_dq = {n.output[0] for n in dequantized}
    assert convs and all(n.input[0] in from_dq and n.input[1] in from_dq for n in convs)  # every convolution is
    assert not [n for n in proto.graph.node if n.op_type in ("QLinearConv", "ConvInteger")]  # QDQ, not fused ops
    path = tmp_path / "int8.onnx"
    path.write_bytes(data)
    written = read_onnx(path)
    assert written.config == exported.config and written.grid == exported.grid
    assert written.meta["note"] == "test"
    assert written.meta["quantization"]["calibration_frames"] == len(feeds)
    assert "Conv" in written.meta["quantization"]["scheme"]
    with pytest.raises(DeployError, match="quantised already"):
        quantize_int8(data, feeds)
    with pytest.raises(DeployError, match="calibration frame"):
        quantize_int8(exported.data, [])


@pytest.mark.parametrize("runtime", ["onnxruntime", "openvino"])
def test_the_int8_graph_runs_as_a_checkpoint_close_to_the_fp32_graph(tiny: tuple[str, Path, Path], tmp_path: Path,
                                                                     runtime: str) -> None:
    kind, _, onnx_path = tiny
    exported = read_onnx(onnx_path)
    frames = _frames(kind == "stereo")
    path = tmp_path / f"{kind}_int8.onnx"
    path.write_bytes(quantize_int8(exported.data, [frame_feeds(exported.config, exported.grid, f) for f in frames]))
    fp32 = create(kind, GridSpec(), checkpoint=str(onnx_path), runtime=runtime, raw=True)
    int8 = create(kind, GridSpec(), checkpoint=str(path), runtime=runtime, raw=True)
    for frame in frames:
        a, b = fp32.estimate(frame), int8.estimate(frame)
        assert np.array_equal(np.isfinite(a.elevation), np.isfinite(b.elevation))  # the same cells are seen
        assert _mean_diff_cm(a.elevation, b.elevation) < 1.0  # calibrated on these frames: close, not equal
        assert np.isfinite(b.uncertainty[np.isfinite(b.elevation)]).all()


def test_openvino_computes_every_frame_of_a_shape_with_that_shapes_fixed_graph(
    tiny: tuple[str, Path, Path],
) -> None:
    """Each input shape is compiled fixed before its first frame runs, so a frame's numbers do not
    depend on which shapes came before it (the node warms up on another rig than ``roadbev eval``
    sees first, and the two must agree)."""
    from roadbev_core.deploy import _OpenVinoEngine

    kind, _, onnx_path = tiny
    exported = read_onnx(onnx_path)
    small = StereoCamera.rsrd_half().scaled(0.3)
    first = frame_feeds(exported.config, exported.grid, _frames(kind == "stereo")[0])
    other_rig = frame_feeds(exported.config, exported.grid, _frames(kind == "stereo", small)[0])
    key = tuple(sorted((name, tuple(value.shape)) for name, value in first.items()))
    other = tuple(sorted((name, tuple(value.shape)) for name, value in other_rig.items()))
    assert other != key or kind == "mono"  # the full-size grey frames change shape (stereo)
    warmed = _OpenVinoEngine(exported.data, threads=1)
    warmed(first)  # the node's warm-up on the common rig
    assert warmed._fixed[key] is not None  # compiled before the call returned
    after_warm_up = warmed(other_rig)
    assert warmed._fixed[other] is not None or other == key
    fresh = _OpenVinoEngine(exported.data, threads=1)
    for a, b in zip(after_warm_up, fresh(other_rig), strict=True):
        np.testing.assert_array_equal(a, b)
    assert [o.shape[1:] for o in after_warm_up] == [exported.grid.shape] * 3


@pytest.mark.parametrize("kind", ["gwcnet", "adabins"])
def test_the_baselines_export_to_graphs_that_compute_what_torch_does(kind: str, tmp_path: Path) -> None:
    import onnxruntime as ort

    torch.manual_seed(0)
    if kind == "gwcnet":
        small = GwcNetConfig(max_disparity=16, features=16, groups=4, volume_channels=4)
        model: GwcNetLite | AdaBinsLite = GwcNetLite(small)
        left = torch.randint(0, 255, (1, 3, 48, 96), dtype=torch.uint8)
        inputs: tuple[torch.Tensor, ...] = (left, left.roll(2, dims=-1))
    else:
        model = AdaBinsLite(AdaBinsConfig(channels=8, n_bins=16, embedding=16, heads=2, layers=1, queries=8))
        inputs = (torch.randint(0, 255, (1, 3, 264, 480), dtype=torch.uint8),)
    model.eval()
    data = export_baseline_onnx(model, kind, tmp_path / f"{kind}.onnx", meta={"command": "test"})
    proto = onnx.load(str(tmp_path / f"{kind}.onnx"))
    props = {p.key: p.value for p in proto.metadata_props}
    assert props["roadbev_baseline"] == kind and json.loads(props["meta"])["command"] == "test"
    session = ort.InferenceSession(data, providers=["CPUExecutionProvider"])
    names, outputs = BASELINE_IO[kind]
    got = session.run(None, {name: x.numpy() for name, x in zip(names, inputs, strict=True)})
    with torch.no_grad():
        expected = model(*inputs)
    assert len(got) == len(outputs)
    for g, e in zip(got, expected, strict=True):
        np.testing.assert_allclose(g, e.numpy(), rtol=1e-4, atol=1e-4)
    if kind == "gwcnet":  # any window size that is a multiple of the stride
        bigger = torch.randint(0, 255, (1, 3, 64, 136), dtype=torch.uint8)
        out = session.run(None, {"left": bigger.numpy(), "right": bigger.numpy()})
        assert out[0].shape == (1, 64, 136)
    with pytest.raises(DeployError, match="unknown baseline"):
        export_baseline_onnx(model, "psmnet")
