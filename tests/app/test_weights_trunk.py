"""The frozen ImageNet trunk of the depth networks is stored once: the bundled LPIPS AlexNet's
convolutions (`assets/lpips_alex.safetensors`), put into the monocular and MVS networks when they
are loaded, and left out of every depth weights file, shipped or newly trained."""

from __future__ import annotations

import torch
from safetensors.torch import load_file

from panogrf.app.train.loop import save_weights
from panogrf.app.weights import networks as nw
from panogrf.app.weights.lpips import ASSET_NAME
from panogrf.assets import path as asset_path
from panogrf.model.mono import MonoDepthConfig, MonoDepthNet


def test_shipped_depth_files_hold_no_trunk_and_loading_puts_the_lpips_one_back():
    alex = load_file(str(asset_path(ASSET_NAME)))
    est = nw.load_depth_estimator(("full", "mvs"))
    nets = {"mono": est.mono, "full": est.mvs["full"], "mvs": est.mvs["mvs"]}
    for role, net in nets.items():
        stored = load_file(str(nw.weights_path(nw.WEIGHTS[role])))
        assert stored and not [k for k in stored if k.startswith("trunk.")]
        trunk = net.trunk.state_dict()
        assert trunk  # every shipped depth network has the trunk
        for key, value in trunk.items():
            assert torch.equal(value, alex[key].float()), (role, key)


def test_saved_weights_leave_the_trunk_out_and_load_back_the_same(tmp_path):
    torch.manual_seed(0)
    net = MonoDepthNet(MonoDepthConfig(trunk=2))
    net.load_state_dict(nw.trunk_tensors(net), strict=False)
    path = tmp_path / "mono.safetensors"
    save_weights(net, path, {"config": {"trunk": 2}})
    stored = load_file(str(path))
    assert set(stored) == {k for k in net.state_dict() if not k.startswith("trunk.")}
    back = MonoDepthNet(MonoDepthConfig(trunk=2))
    back.load_state_dict({**nw.trunk_tensors(back), **stored})
    for key, value in net.state_dict().items():
        assert torch.equal(back.state_dict()[key], value), key
