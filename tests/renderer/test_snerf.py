"""The S-NeRF baseline on the analytic room: fitting must explain the sources it saw, render a
new pose from the field (not a copy of a source), and stay finite and in range."""

from __future__ import annotations

import torch
from helpers.room import pose, render

from panogrf.model.erp import rotation_about
from panogrf.renderer.snerf import SNeRFConfig, fit_snerf, render_snerf

SRC_A = pose(rotation_about("y", 0.3), [-0.6, 0.0, 0.1])
SRC_B = pose(rotation_about("y", -1.1), [0.7, 0.1, -0.2])
TGT = pose(rotation_about("y", 2.0), [0.1, 0.05, -0.05])
QUICK = SNeRFConfig(grid=(12, 16, 32), samples=24, steps=80, rays=1024, fit_height=32)


def _psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(10 * torch.log10(1 / ((a - b) ** 2).mean()))


def test_fitted_field_explains_its_sources_and_renders_a_new_pose():
    images = torch.cat([render(c, ball=True)[0] for c in (SRC_A, SRC_B)]).float()
    c2w = torch.stack((SRC_A, SRC_B)).float()
    untrained = fit_snerf(images, c2w, SNeRFConfig(**{**QUICK.__dict__, "steps": 0}))
    model = fit_snerf(images, c2w, QUICK)
    at_a = render_snerf(model, SRC_A.float(), 32)
    assert at_a.shape == (3, 32, 64)
    before = _psnr(render_snerf(untrained, SRC_A.float(), 32), images[0])
    after = _psnr(at_a, images[0])
    assert after > before + 10 and after > 25, (before, after)

    target = render(TGT, ball=True)[0][0].float()
    novel = render_snerf(model, TGT.float(), 32)
    assert torch.isfinite(novel).all() and novel.min() >= 0 and novel.max() <= 1
    # Better than the untrained field there too: the fit is a field, not the sources' pixels.
    assert _psnr(novel, target) > _psnr(render_snerf(untrained, TGT.float(), 32), target) + 3


def test_same_seed_same_field():
    images = torch.cat([render(c)[0] for c in (SRC_A, SRC_B)]).float()
    c2w = torch.stack((SRC_A, SRC_B)).float()
    cfg = SNeRFConfig(**{**QUICK.__dict__, "steps": 5})
    assert torch.equal(fit_snerf(images, c2w, cfg).grid, fit_snerf(images, c2w, cfg).grid)
