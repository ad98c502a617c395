"""The whole chain runs on the device of its input: a CPU check that fails when any tensor of
the chain is made on a fixed (default) device, the ``--device`` option, and, where there is a
GPU, the CUDA path against the CPU one."""

from __future__ import annotations

import pytest
import torch

from panogrf.app.errors import UserError
from panogrf.app.runtime import resolve_device
from panogrf.app.scene.folder import load_scene
from panogrf.app.scene.session import default_models
from panogrf.assets import path as asset_path
from panogrf.model.metrics import ws_psnr
from panogrf.model.refine import PREPARE_REFINE
from panogrf.renderer.cache import resize_erp
from panogrf.renderer.methods import METHODS, SourceViews, render_perspective_view, render_view


@pytest.fixture(scope="module")
def models():
    m = default_models()
    m.estimator("full")  # every network loaded before the default device changes
    m.estimator("mvs")
    m.renderer("panogrf")
    return m


@pytest.fixture(scope="module")
def demo():
    data = load_scene(asset_path("demo"), load_images=True).images
    return resize_erp(data.images, 64), data.c2w


def _chain(images, c2w, models, device=None):
    """Exposure balance, nadir masks, mode full's depth with the refinement, the feature maps,
    a panorama and a pinhole view: (depth, panorama, pinhole)."""
    views = SourceViews(
        images[[0, 2]], c2w[[0, 2]], refine=PREPARE_REFINE, nadir="auto", device=device
    )
    depth = views.depth_for("full", models)
    rgb = render_view("panogrf", views, c2w[1], 32, models, "fast")
    pinhole = render_perspective_view("panogrf", views, c2w[1], 24, 16, 90.0, models)
    return depth, rgb, pinhole


@pytest.mark.skipif(
    tuple(int(x) for x in torch.__version__.split("+")[0].split(".")[:2]) < (2, 13),
    reason="torch < 2.13's Adam makes its step counter on the default device",
)
def test_no_tensor_of_the_chain_is_made_on_a_fixed_device(models, demo, monkeypatch):
    """With the default device set to "meta", a tensor made without its input's device is a
    meta tensor, and the first operation mixing it with the CPU input (or reading its value)
    fails: the chain passes only if every tensor follows its input."""
    images, c2w = demo
    torch.set_default_device("meta")
    try:
        depth, rgb, pinhole = _chain(images, c2w, models)
        meshwarp = render_view(
            "meshwarp", SourceViews(images[[0, 2]], c2w[[0, 2]]), c2w[1], 32, models
        )
    finally:
        torch.set_default_device(None)
    for t in (depth, rgb, pinhole, meshwarp):
        assert t.device.type == "cpu" and bool(torch.isfinite(t).all())
    assert METHODS["panogrf"].depth_mode == "full"


def test_the_check_catches_a_tensor_made_on_the_default_device(demo):
    """The check above can fail: a stage that makes a tensor without a device breaks it."""
    images, _ = demo
    torch.set_default_device("meta")
    try:
        with pytest.raises((RuntimeError, NotImplementedError)):
            float((images[0] * torch.ones(images.shape[-2:])).sum())
    finally:
        torch.set_default_device(None)


def test_resolve_device_names_what_this_machine_has():
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    for bad in ("tpu", "gpu0", "cuda:x"):
        with pytest.raises(UserError, match="--device"):
            resolve_device(bad)
    if not torch.cuda.is_available():
        with pytest.raises(UserError, match="CUDA is not available"):
            resolve_device("cuda")
    else:
        with pytest.raises(UserError, match="CUDA device"):
            resolve_device(f"cuda:{torch.cuda.device_count()}")


def test_render_refuses_a_device_it_does_not_have(tmp_path, capsys):
    from panogrf.app.cli import main

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    out = tmp_path / "x.png"
    code = main(["render", str(asset_path("demo")), "--target-frame", "1", "--out", str(out),
                 "--device", "cuda"])  # fmt: skip
    assert code == 2 and not out.exists()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--device cuda" in err[0]


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_chain_matches_the_cpu_chain(demo):
    """The estimated depth within 0.002 m L1 of the CPU's and the render within 0.05 dB WS-PSNR
    of the CPU's (both against the truth). Without the per-scene refinement: its 60 Adam steps
    carry the devices' rounding apart by millimetres (measured: `gpu_parity.json`)."""
    images, c2w = demo
    cpu, gpu = default_models("cpu"), default_models("cuda")
    out = {}
    for name, models in (("cpu", cpu), ("gpu", gpu)):
        views = SourceViews(images[[0, 2]], c2w[[0, 2]], nadir="auto", device=models.device)
        depth = views.depth_for("full", models)
        rgb = render_view("panogrf", views, c2w[1], 32, models, "fast")
        out[name] = (depth, rgb)
    assert out["gpu"][0].is_cuda and out["gpu"][1].is_cuda
    assert float((out["gpu"][0].cpu() - out["cpu"][0]).abs().mean()) < 0.002
    truth = resize_erp(images[1:2], 32)
    scores = {k: float(ws_psnr(rgb.cpu()[None], truth)) for k, (_, rgb) in out.items()}
    assert abs(scores["gpu"] - scores["cpu"]) < 0.05
