"""``roadbev train`` input checks and ``roadbev export``."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from roadbev_cli.cli import main
from roadbev_core.checkpoint import read_checkpoint, save_checkpoint
from roadbev_core.config import GridSpec
from roadbev_core.models.presets import model_config
from roadbev_core.models.roadbev import RoadBEV


def test_train_refuses_missing_data_and_test_seeds(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["train", "--kind", "mono", "--out", str(tmp_path / "m.pt")]) == 2
    assert "no training data" in capsys.readouterr().err
    args = ["train", "--kind", "stereo", "--out", str(tmp_path / "s.pt"), "--synth", "5", "--synth-seed", "99998"]
    assert main(args) == 2
    assert "training seeds" in capsys.readouterr().err
    assert main(["train", "--kind", "mono", "--out", str(tmp_path / "m.pt"), "--rsrd", str(tmp_path)]) == 2
    assert "--rsrd-info" in capsys.readouterr().err
    args = ["train", "--kind", "stereo", "--out", str(tmp_path / "s.pt"), "--synth", "1", "--synth-appearance", "sunny",
            "--cache", str(tmp_path)]
    assert main(args) == 2
    assert "unknown appearance" in capsys.readouterr().err
    assert main(["train", "--kind", "gwcnet", "--augment", "--out", str(tmp_path / "g.pt"), "--synth", "1"]) == 2
    assert "--augment is AdaBins' augmentation" in capsys.readouterr().err


def test_export_drops_training_state_and_can_halve(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    torch.manual_seed(0)
    model = RoadBEV(model_config("tiny", "mono"), GridSpec())
    source = save_checkpoint(tmp_path / "train.pt", model,
                             train_state={"step": 3, "history": [{"epoch": 1, "loss": 2.0}]})
    out = tmp_path / "deploy.pt"
    assert main(["export", str(source), str(out), "--half"]) == 0
    assert "RoadBEV-mono" in capsys.readouterr().out
    payload = read_checkpoint(out)
    assert "train_state" not in payload and payload["meta"]["final_epoch"]["loss"] == 2.0
    assert payload["state_dict"]["head.classify.weight"].dtype == torch.float16
    assert main(["export", str(tmp_path / "missing.pt"), str(out)]) == 2



def test_export_onnx_writes_a_graph_the_runtime_option_runs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`roadbev export CKPT OUT --format onnx`, then `mono.runtime: onnxruntime` as a params YAML gives it."""
    pytest.importorskip("onnxruntime")
    import numpy as np

    from roadbev_core.backends import create
    from roadbev_core.config import RoadbevConfig, StereoCamera
    from roadbev_core.deploy import read_onnx
    from roadbev_core.frame import Frame
    from roadbev_core.geometry import Attitude

    torch.manual_seed(0)
    source = save_checkpoint(tmp_path / "mono.pt", RoadBEV(model_config("tiny", "mono"), GridSpec()))
    out = tmp_path / "mono.onnx"
    assert main(["export", str(source), str(out), "--format", "onnx"]) == 0
    printed = capsys.readouterr().out
    assert "RoadBEV-mono" in printed and "ONNX opset 17" in printed
    assert read_onnx(out).meta["exported_from"] == "mono.pt"
    config = RoadbevConfig.from_params({"backend": "mono", "mono.runtime": "onnxruntime", "checkpoint": str(out)})
    options = config.backend.options_of()
    backend = create("mono", GridSpec(), **options)
    camera = StereoCamera.rsrd_half().scaled(0.25)
    image = np.random.default_rng(0).integers(0, 255, (camera.height, camera.width, 3), dtype=np.uint8)
    estimate = backend.estimate(Frame(image, None, camera, Attitude.from_degrees(0.0, 18.0)))
    assert estimate.elevation.shape == GridSpec().shape and np.isfinite(estimate.elevation).mean() > 0.9
    assert main(["export", str(source), str(out), "--format", "onnx", "--half"]) == 2
    assert "--half is for --format pt" in capsys.readouterr().err


def test_export_int8_writes_a_quantised_graph_and_refuses_bad_options(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    """`roadbev export CKPT OUT --format onnx --int8`: int8 convolutions calibrated on training scenes."""
    pytest.importorskip("onnxruntime")
    import onnx

    from roadbev_core.deploy import read_onnx

    torch.manual_seed(0)
    source = save_checkpoint(tmp_path / "mono.pt", RoadBEV(model_config("tiny", "mono"), GridSpec()))
    out = tmp_path / "mono_int8.onnx"
    assert main(["export", str(source), str(out), "--format", "onnx", "--int8", "--calibration-scenes", "1"]) == 0
    assert "int8 convolutions calibrated on 1 training scenes" in capsys.readouterr().out
    exported = read_onnx(out)
    assert exported.meta["quantization"]["calibration_frames"] == 1 and exported.meta["exported_from"] == "mono.pt"
    assert any(n.op_type == "QuantizeLinear" for n in onnx.load(str(out)).graph.node)
    assert not out.with_name(out.name + ".tmp").exists()
    assert main(["export", str(source), str(tmp_path / "x.pt"), "--int8"]) == 2
    assert "--int8 is for --format onnx" in capsys.readouterr().err
    assert main(["export", str(source), str(tmp_path / "y.onnx"), "--format", "onnx", "--int8",
                 "--calibration-scenes", "0"]) == 2
    assert "--calibration-scenes must be >= 1" in capsys.readouterr().err
    assert not (tmp_path / "y.onnx").exists()


def test_the_image_view_baselines_train_and_export_from_the_cli(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    import onnx

    from roadbev_core.checkpoint import TrainingEnvelope, load_baseline, save_baseline
    from roadbev_core.config import StereoCamera
    from roadbev_core.models.gwcnet import GwcNetConfig, GwcNetLite

    out = tmp_path / "gwcnet.pt"
    args = ["train", "--kind", "gwcnet", "--out", str(out), "--synth", "2", "--synth-seed", "0", "--cache",
            str(tmp_path / "scenes"), "--epochs", "1", "--batch-size", "2", "--threads", "1"]
    assert main([*args, "--resume", str(out)]) == 2
    assert "takes --init" in capsys.readouterr().err
    assert main(args) == 0
    assert "wrote" in capsys.readouterr().out
    _, payload = load_baseline(out, "gwcnet")
    assert "--kind gwcnet" in payload["meta"]["command"] and len(payload["meta"]["history"]) == 1
    camera = StereoCamera.rsrd_half()
    small = save_baseline(tmp_path / "small.pt", "gwcnet", GwcNetLite(GwcNetConfig(features=16, groups=4)).eval(),
                          TrainingEnvelope(GridSpec(), (camera.fx, camera.fx), camera.width,
                                           (camera.baseline, camera.baseline)))
    graph = tmp_path / "gwcnet.onnx"
    assert main(["export", str(small), str(graph), "--format", "onnx"]) == 0
    assert "exported gwcnet" in capsys.readouterr().out
    assert {i.name for i in onnx.load(str(graph)).graph.input} == {"left", "right"}
    assert main(["export", str(small), str(graph), "--format", "onnx", "--int8"]) == 2
    assert "not gwcnet" in capsys.readouterr().err
