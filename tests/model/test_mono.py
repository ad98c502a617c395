"""The monocular network's frozen pretrained trunk (`MonoDepthConfig.trunk`)."""

from __future__ import annotations

import json

import pytest
import torch

from panogrf.model.mono import MonoDepthConfig, MonoDepthNet, PretrainedTrunk


def _image(h: int = 64, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(1, 3, h, 2 * h, generator=g)


def test_a_zero_trunk_projection_leaves_the_network_as_it_was():
    torch.manual_seed(0)
    plain = MonoDepthNet(MonoDepthConfig()).eval()
    with_trunk = MonoDepthNet(MonoDepthConfig(trunk=3)).eval()
    missing, unexpected = with_trunk.load_state_dict(plain.state_dict(), strict=False)
    assert not unexpected
    assert missing and all(k.startswith(("trunk.", "from_trunk.")) for k in missing)
    torch.nn.init.normal_(with_trunk.trunk.convs[0].weight)  # any trunk: projections are zero
    x = _image()
    assert torch.equal(plain(x).depth, with_trunk(x).depth)
    # A non-zero projection does change the output: the trunk is wired in.
    torch.nn.init.normal_(with_trunk.from_trunk[0].weight, std=0.1)
    assert not torch.allclose(plain(x).depth, with_trunk(x).depth)


def test_the_trunk_is_frozen_and_the_rest_trains():
    torch.manual_seed(0)
    net = MonoDepthNet(MonoDepthConfig(trunk=2))
    for proj in net.from_trunk:
        torch.nn.init.normal_(proj.weight, std=0.1)
    net(_image(seed=1)).depth.mean().backward()
    assert all(p.grad is None for p in net.trunk.parameters())
    assert all(p.grad is not None for p in net.from_trunk.parameters())
    assert net.erp_encoder.stages[0][0].weight.grad is not None


@pytest.mark.parametrize("h", [32, 64, 128])
def test_trunk_features_sit_on_the_encoder_grids(h):
    feats = PretrainedTrunk(3)(_image(h))
    assert [tuple(f.shape[1:]) for f in feats] == [
        (64, h // 4, h // 2),
        (192, h // 8, h // 4),
        (384, h // 16, h // 8),
    ]
    assert all(torch.isfinite(f).all() for f in feats)


def test_trunk_features_wrap_at_the_seam():
    """Turning the panorama by 16 pixels turns every feature map by whole cells: the seam is
    invisible to the trunk (circular padding wider than its receptive field)."""
    torch.manual_seed(0)
    trunk = PretrainedTrunk(3)
    for conv in trunk.convs:
        torch.nn.init.normal_(conv.weight, std=0.05)
    x = _image(128, seed=2)
    base = trunk(x)
    turned = trunk(torch.roll(x, 16, -1))
    for f, g, scale in zip(base, turned, (4, 8, 16), strict=True):
        expect = torch.roll(f, 16 // scale, -1)
        assert torch.allclose(g, expect, atol=1e-4 * float(f.abs().max())), scale


def test_config_round_trips_through_the_weights_metadata():
    cfg = MonoDepthConfig(trunk=3)
    stored = json.loads(json.dumps(cfg.__dict__))
    assert MonoDepthConfig.from_dict(stored) == cfg
    with pytest.raises(ValueError, match="trunk"):
        MonoDepthNet(MonoDepthConfig(trunk=4))
