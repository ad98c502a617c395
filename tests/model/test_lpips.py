"""AlexNet-LPIPS: the published reference distances with the bundled weights, and bad input."""

from __future__ import annotations

from pathlib import Path

import cv2
import pytest
import torch

from panogrf.app.weights.lpips import load_lpips
from panogrf.model.lpips import LPIPS, MIN_SIZE

# The LPIPS authors' example images, with their licence, in the repository (tests/data/lpips).
REFERENCE_DIR = Path(__file__).resolve().parents[1] / "data" / "lpips"


def _read_rgb(name: str) -> torch.Tensor:
    bgr = cv2.imread(str(REFERENCE_DIR / name), cv2.IMREAD_COLOR)
    assert bgr is not None, f"missing reference image {REFERENCE_DIR / name}"
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    return torch.from_numpy(rgb).permute(2, 0, 1).float() / 255.0  # [3, H, W] in [0, 1]


@pytest.fixture(scope="module")
def net() -> LPIPS:
    return load_lpips("cpu")


def test_reference_distances(net):
    ref, p0, p1 = (_read_rgb(f"ex_{n}.png") for n in ("ref", "p0", "p1"))
    with torch.no_grad():
        d0, d1 = float(net(ref, p0)), float(net(ref, p1))
    # Published AlexNet-LPIPS v0.1 values (PerceptualSimilarity README).
    assert d0 == pytest.approx(0.722, abs=1e-3)
    assert d1 == pytest.approx(0.138, abs=1e-3)
    # Batched call gives the same per-image values.
    with torch.no_grad():
        both = net(torch.stack([ref, ref]), torch.stack([p0, p1]))
    assert both.shape == (2,)
    torch.testing.assert_close(both, torch.tensor([d0, d1]), atol=1e-5, rtol=0)


def test_identical_is_zero_and_symmetric(net):
    g = torch.Generator().manual_seed(0)
    x = torch.rand(2, 3, 32, 64, generator=g)
    y = torch.rand(2, 3, 32, 64, generator=g)
    with torch.no_grad():
        assert torch.equal(net(x, x), torch.zeros(2))
        torch.testing.assert_close(net(x, y), net(y, x))
        assert bool((net(x, y) > 0).all())


def test_loader_is_cached_frozen_and_float32(net):
    assert load_lpips("cpu") is net
    assert not net.training
    assert all(p.dtype == torch.float32 and not p.requires_grad for p in net.parameters())


def test_gradient_reaches_inputs(net):
    x = torch.rand(1, 3, 32, 32, generator=torch.Generator().manual_seed(1), requires_grad=True)
    y = torch.rand(1, 3, 32, 32, generator=torch.Generator().manual_seed(2))
    net(x, y).sum().backward()
    assert x.grad is not None and bool(torch.isfinite(x.grad).all())
    assert float(x.grad.abs().sum()) > 0


def test_from_state_dict_is_strict():
    state = LPIPS().state_dict()
    LPIPS.from_state_dict(state)
    del state["heads.0.weight"]
    with pytest.raises(RuntimeError, match="heads.0.weight"):
        LPIPS.from_state_dict(state)


def test_bad_input_raises(net):
    x = torch.rand(1, 3, 32, 32, generator=torch.Generator().manual_seed(3))
    with pytest.raises(ValueError, match="shapes differ"):
        net(x, x[..., :31])
    with pytest.raises(ValueError, match=rf"H, W >= {MIN_SIZE}, got \(1, 3, 16, 16\)"):
        net(x[..., :16, :16], x[..., :16, :16])
    with pytest.raises(ValueError, match=r"RGB images \[B, 3, H, W\]"):
        net(x[:, :1], x[:, :1])
    with pytest.raises(ValueError, match=r"values in \[0, 1\]"):
        net(x * 2 - 1, x)
    nan = x.clone()
    nan[0, 0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        net(x, nan)


def test_min_size_is_the_backbone_minimum():
    net = LPIPS().eval()
    x = torch.zeros(1, 3, MIN_SIZE, MIN_SIZE)
    assert [t.shape[-1] for t in net.features(x)][-1] == 1
    with pytest.raises(RuntimeError):  # one pixel less no longer fits the two pools
        net.features(torch.zeros(1, 3, MIN_SIZE - 1, MIN_SIZE - 1))


def test_missing_asset_error_says_how_to_fix(monkeypatch, tmp_path):
    from panogrf.app.weights import lpips as lpips_weights

    monkeypatch.setattr(lpips_weights.assets, "path", lambda name: tmp_path / name)
    lpips_weights._load_cached.cache_clear()
    try:
        with pytest.raises(FileNotFoundError, match="scripts/convert_lpips.py"):
            load_lpips("cpu")
    finally:
        lpips_weights._load_cached.cache_clear()
