"""AdaBins-lite: adaptive bins inside the depth range, the losses, the encoder layer, the shapes."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from roadbev_core.config import ConfigError
from roadbev_core.models.adabins import AdaBinsConfig, AdaBinsLite, _EncoderLayer, chamfer_loss, silog_loss

SMALL = AdaBinsConfig(channels=8, n_bins=16, embedding=16, heads=2, layers=1, queries=8)


def test_depth_lies_among_each_images_own_bins() -> None:
    torch.manual_seed(0)
    net = AdaBinsLite(SMALL).eval()
    image = torch.randint(0, 255, (2, 3, SMALL.input_height, SMALL.input_width), dtype=torch.uint8)
    with torch.inference_mode():
        depth, sigma, centres = net(image)
    assert depth.shape == sigma.shape == (2, SMALL.input_height // 2, SMALL.input_width // 2)
    assert centres.shape == (2, SMALL.n_bins)
    assert torch.all(centres[:, 1:] > centres[:, :-1])  # ordered bins inside the range
    assert torch.all((centres > SMALL.min_depth) & (centres < SMALL.max_depth))
    for b in range(2):  # an expectation over the bins lies between the first and the last centre
        assert torch.all((depth[b] >= centres[b, 0] - 1e-4) & (depth[b] <= centres[b, -1] + 1e-4))
    assert torch.all(sigma > 0)


def test_the_encoder_layer_is_a_post_norm_transformer_layer() -> None:
    torch.manual_seed(1)
    ours = _EncoderLayer(16, 2).eval()
    reference = nn.TransformerEncoderLayer(16, 2, dim_feedforward=32, dropout=0.0, batch_first=True).eval()
    reference.self_attn.in_proj_weight.data.copy_(ours.qkv.weight.data)
    reference.self_attn.in_proj_bias.data.copy_(ours.qkv.bias.data)
    reference.self_attn.out_proj.weight.data.copy_(ours.project.weight.data)
    reference.self_attn.out_proj.bias.data.copy_(ours.project.bias.data)
    reference.linear1.load_state_dict(ours.feed[0].state_dict())
    reference.linear2.load_state_dict(ours.feed[2].state_dict())
    reference.norm1.load_state_dict(ours.norm1.state_dict())
    reference.norm2.load_state_dict(ours.norm2.state_dict())
    x = torch.randn(2, 5, 16)
    with torch.no_grad():
        torch.testing.assert_close(ours(x), reference(x), atol=1e-5, rtol=1e-5)


def test_the_losses_vanish_on_the_truth_and_see_a_scale_error() -> None:
    target = torch.tensor([[[2.0, 3.0], [4.0, 5.0]]])
    labelled = torch.ones_like(target, dtype=torch.bool)
    assert float(silog_loss(target, target, labelled)) < 2e-3  # the square root's guard
    # scale-invariant in part: 15 % of a pure scale error is left (1 - 0.85), so it is not zero
    scaled = float(silog_loss(target * 1.2, target, labelled))
    assert 0.5 < scaled < 10.0 * abs(torch.log(torch.tensor(1.2)).item())
    centres = torch.tensor([[2.0, 3.0, 4.0, 5.0]])
    assert float(chamfer_loss(centres, target, labelled)) == pytest.approx(0.0)
    assert float(chamfer_loss(centres + 0.5, target, labelled)) == pytest.approx(0.5, rel=1e-5)


def test_config_is_checked_and_round_trips() -> None:
    assert AdaBinsConfig.from_dict(SMALL.to_dict()) == SMALL
    with pytest.raises(ConfigError, match="min_depth"):
        AdaBinsConfig(min_depth=5.0, max_depth=2.0)
    with pytest.raises(ConfigError, match="multiple of heads"):
        AdaBinsConfig(embedding=30, heads=4)
    with pytest.raises(ConfigError, match="tokens"):
        AdaBinsConfig(patch_size=64)
    with pytest.raises(ConfigError, match="unknown backbone"):
        AdaBinsConfig(backbone="resnet50")
