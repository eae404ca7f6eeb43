"""Training: the tiny models learn, resume continues, torchrun/DDP matches one process."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch

from roadbev_core.checkpoint import read_checkpoint
from roadbev_core.config import GridSpec, StereoCamera
from roadbev_core.models.presets import ModelConfig, model_config
from roadbev_lab.training.datasets import SyntheticSet
from roadbev_lab.training.train import TrainConfig, TrainError, train

REPO = Path(__file__).resolve().parents[3]
CAMERA = StereoCamera.rsrd_half().scaled(0.25)  # 240 x 132 renders in about a second
GRID = GridSpec(resolution=0.12)  # 41 x 16 cells: the tiny models' own resolution
SEEDS = (100_000, 100_001)


@pytest.fixture(scope="module")
def frames(tmp_path_factory: pytest.TempPathFactory) -> SyntheticSet:
    return SyntheticSet(tmp_path_factory.mktemp("synth"), SEEDS, camera=CAMERA, grid=GRID)


def _tiny(kind: str) -> ModelConfig:
    return model_config("tiny", kind, grid_factor=1, label="one_hot")


def test_tiny_mono_overfits_a_few_frames(frames: SyntheticSet, tmp_path: Path) -> None:
    result = train(_tiny("mono"), GRID, frames, TrainConfig(epochs=45, batch_size=2, lr=3e-3, seed=1),
                   tmp_path / "mono.pt", progress=False)
    first, last = result.history[0], result.history[-1]
    assert last["loss"] < first["loss"] / 10, (first, last)
    assert last["abs_err_cm"] < 1.0 < first["abs_err_cm"], (first, last)


def test_tiny_stereo_learns(frames: SyntheticSet, tmp_path: Path) -> None:
    result = train(_tiny("stereo"), GRID, frames, TrainConfig(epochs=12, batch_size=2, lr=3e-3, seed=1),
                   tmp_path / "stereo.pt", progress=False)
    first, last = result.history[0], result.history[-1]
    assert last["loss"] < 0.85 * first["loss"], (first, last)
    assert last["abs_err_cm"] < first["abs_err_cm"], (first, last)


def test_resume_continues_the_schedule_and_checkpoints_carry_config(frames: SyntheticSet, tmp_path: Path) -> None:
    cfg = TrainConfig(epochs=2, batch_size=1, lr=1e-3, seed=3)
    out = tmp_path / "run.pt"
    train(_tiny("mono"), GRID, frames, TrainConfig(epochs=1, batch_size=1, lr=1e-3, seed=3), out, progress=False)
    with pytest.raises(TrainError, match="already finished"):
        train(_tiny("mono"), GRID, frames, TrainConfig(epochs=1, batch_size=1, lr=1e-3, seed=3), tmp_path / "x.pt",
              resume=out, progress=False)
    with pytest.raises(TrainError, match="not both"):
        train(_tiny("mono"), GRID, frames, cfg, tmp_path / "x.pt", resume=out, init=out, progress=False)
    warm = train(_tiny("stereo"), GRID, frames, TrainConfig(epochs=1, batch_size=2, lr=1e-9), tmp_path / "warm.pt",
                 init=out, progress=False)  # init takes the checkpoint's model (mono), weights kept
    assert warm.checkpoint is not None
    warm_payload = read_checkpoint(warm.checkpoint)
    assert warm_payload["model_config"]["kind"] == "mono" and warm_payload["meta"]["init"] == str(out)
    before = read_checkpoint(out)["state_dict"]
    torch.testing.assert_close(warm_payload["state_dict"]["head.classify.weight"], before["head.classify.weight"],
                               atol=1e-6, rtol=0)
    payload = torch.load(out, weights_only=True)
    assert payload["model_config"]["kind"] == "mono" and GridSpec.from_dict(payload["grid"]) == GRID
    assert payload["train_state"]["step"] == 2
    # A 1-epoch schedule cannot be stretched: resuming a 2-epoch run from its own first epoch can.
    train(_tiny("mono"), GRID, frames, cfg, tmp_path / "full.pt", progress=False)
    half = tmp_path / "half.pt"
    train(_tiny("mono"), GRID, frames, TrainConfig(epochs=2, batch_size=1, lr=1e-3, seed=3, max_minutes=1e-9),
          half, progress=False)
    assert read_checkpoint(half)["train_state"]["step"] == 1  # stopped by the time cap after one step
    resumed = train(_tiny("mono"), GRID, frames, cfg, tmp_path / "resumed.pt", resume=half, progress=False)
    assert resumed.steps == 4
    full = read_checkpoint(tmp_path / "full.pt")["state_dict"]
    again = read_checkpoint(tmp_path / "resumed.pt")["state_dict"]
    for key in full:
        torch.testing.assert_close(again[key], full[key], rtol=1e-4, atol=1e-5)


_WORKER = textwrap.dedent(
    """
    import sys
    import torch
    torch.set_num_threads(1)
    from roadbev_core.config import GridSpec, StereoCamera
    from roadbev_lab.training.datasets import SyntheticSet
    from roadbev_core.models.presets import model_config
    from roadbev_lab.training.train import TrainConfig, train
    cache, out = sys.argv[1], sys.argv[2]
    data = SyntheticSet(cache, (100000, 100001), camera=StereoCamera.rsrd_half().scaled(0.25),
                        grid=GridSpec(resolution=0.12))
    cfg = model_config("tiny", "mono", grid_factor=1, label="one_hot")
    train(cfg, data.grid, data, TrainConfig(epochs=2, batch_size=2, lr=1e-3, seed=5), out, progress=False)
    """
)


def test_two_gloo_processes_match_one_process_with_the_same_global_batch(frames: SyntheticSet, tmp_path: Path) -> None:
    single = train(_tiny("mono"), GRID, frames, TrainConfig(epochs=2, batch_size=2, lr=1e-3, seed=5),
                   tmp_path / "single.pt", progress=False)
    script = tmp_path / "worker.py"
    script.write_text(_WORKER)
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(REPO)}
    cmd = [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", "2", "--master_port", "29517",
           str(script), str(frames.folder.parent), str(tmp_path / "ddp.pt")]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr[-2000:]
    ddp = read_checkpoint(tmp_path / "ddp.pt")
    assert ddp["meta"]["world_size"] == 2
    losses_ddp = [h["loss"] for h in ddp["train_state"]["history"]]
    np.testing.assert_allclose(losses_ddp, [h["loss"] for h in single.history], rtol=1e-4)
    reference = read_checkpoint(tmp_path / "single.pt")["state_dict"]
    diffs = torch.cat([(ddp["state_dict"][k].double() - v.double()).abs().flatten() for k, v in reference.items()])
    # Adam divides each gradient by its own magnitude, so float rounding in a near-zero gradient
    # can flip an update (at most 2 steps x lr; ~0.1 % of the weights here); the rest agree tightly.
    assert float((diffs < 1e-5).double().mean()) > 0.99, float((diffs < 1e-5).double().mean())
    assert float(diffs.max()) <= 2 * 1e-3 * 1.01


def test_bad_settings_fail_clearly(frames: SyntheticSet, tmp_path: Path) -> None:
    with pytest.raises(TrainError, match="fewer than one batch"):
        train(_tiny("mono"), GRID, frames, TrainConfig(epochs=1, batch_size=3), tmp_path / "a.pt", progress=False)
    with pytest.raises(TrainError, match=">= 1"):
        TrainConfig(epochs=0)


def test_model_overrides_change_an_init_checkpoints_model_but_not_its_weights(
    frames: SyntheticSet, tmp_path: Path
) -> None:
    base = model_config("tiny", "stereo", grid_factor=1, zncc_full_resolution=False, zncc_subsamples=1)
    out = tmp_path / "base.pt"
    train(base, GRID, frames, TrainConfig(epochs=1, batch_size=2, lr=1e-3, seed=2), out, progress=False)
    sharper = train(base, GRID, frames, TrainConfig(epochs=1, batch_size=2, lr=1e-9), tmp_path / "sharp.pt", init=out,
                    model_overrides={"zncc_full_resolution": True, "zncc_subsamples": 2}, progress=False)
    assert sharper.checkpoint is not None
    payload = read_checkpoint(sharper.checkpoint)
    assert payload["model_config"]["zncc_full_resolution"] is True and payload["model_config"]["zncc_subsamples"] == 2
    before = read_checkpoint(out)["state_dict"]
    key = "head.out.1.weight"
    torch.testing.assert_close(payload["state_dict"][key], before[key], atol=1e-6, rtol=0)
    with pytest.raises(TrainError, match="do not fit"):  # a wider network cannot take these weights
        train(base, GRID, frames, TrainConfig(epochs=1, batch_size=2), tmp_path / "x.pt", init=out,
              model_overrides={"channels": 12}, progress=False)
    with pytest.raises(TrainError, match="resumed run keeps its model"):
        train(base, GRID, frames, TrainConfig(epochs=2, batch_size=2), tmp_path / "x.pt", resume=out,
              model_overrides={"zncc_subsamples": 2}, progress=False)


def test_roadbev_train_on_two_nodes_matches_one_process(tmp_path: Path) -> None:
    """``roadbev train`` under torchrun as on two nodes (``--nnodes 2``, one process each, gloo),
    both on this machine: the losses and weights of one process with the same global batch."""
    from roadbev_cli.cli import main
    from roadbev_lab.evaluation.evalbag import write_eval_bag
    from roadbev_lab.synth import DriveConfig, SyntheticDrive

    bag = tmp_path / "labelled.mcap"
    write_eval_bag(bag, SyntheticDrive(DriveConfig(frames=4, seed=3, camera=CAMERA, grid=GRID)))
    args = ["train", "--kind", "mono", "--preset", "tiny", "--bag", str(bag), "--epochs", "2", "--batch-size", "2",
            "--seed", "5", "--no-progress"]
    assert main([*args, "--out", str(tmp_path / "single.pt")]) == 0
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(REPO)}
    nodes = [subprocess.Popen([sys.executable, "-m", "torch.distributed.run", "--nnodes", "2", "--node-rank", str(rank),
                               "--nproc-per-node", "1", "--master-addr", "127.0.0.1", "--master-port", "29523",
                               "-m", "roadbev_cli.cli", *args, "--out", str(tmp_path / "nodes.pt")],
                              env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for rank in (0, 1)]
    for node in nodes:
        _out, err = node.communicate(timeout=240)
        assert node.returncode == 0, err[-2000:]
    two = read_checkpoint(tmp_path / "nodes.pt")
    one = read_checkpoint(tmp_path / "single.pt")
    assert two["meta"]["world_size"] == 2
    np.testing.assert_allclose([h["loss"] for h in two["train_state"]["history"]],
                               [h["loss"] for h in one["train_state"]["history"]], rtol=1e-4)
    diffs = torch.cat([(two["state_dict"][k].double() - v.double()).abs().flatten()
                       for k, v in one["state_dict"].items()])
    # Adam divides each gradient by its own magnitude: float rounding in a near-zero gradient can
    # move a weight by up to a step's learning rate (4 steps here); the rest agree tightly
    assert float((diffs < 1e-4).double().mean()) > 0.99, float((diffs < 1e-4).double().mean())
    assert float(diffs.max()) <= 4 * 8e-4 * 1.01  # mono's peak learning rate
