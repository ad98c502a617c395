"""`image_scores`: PSNR and WS-PSNR at the render's size, SSIM and LPIPS at `SCORE_ROWS` rows at
most."""

from __future__ import annotations

import torch

from panogrf.app import scoring
from panogrf.model.metrics import psnr, ws_psnr
from panogrf.renderer.cache import resize_erp


def _pair(rows: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(rows)
    truth = torch.rand(1, 3, rows, 2 * rows, generator=g)
    render = (truth[0] + 0.1 * torch.randn(3, rows, 2 * rows, generator=g)).clamp(0, 1)
    return render, truth


def test_a_large_render_gets_ssim_and_lpips_at_the_score_rows(monkeypatch):
    monkeypatch.setattr(scoring, "SCORE_ROWS", 32)
    render, truth = _pair(64)
    got = scoring.image_scores(render, truth)
    x, gt = render[None], truth
    assert got["psnr"] == float(psnr(x, gt)) and got["ws_psnr"] == float(ws_psnr(x, gt))
    small = scoring.image_scores(resize_erp(x, 32)[0], resize_erp(gt, 32))
    assert got["ssim"] == small["ssim"] and got["lpips"] == small["lpips"]
    full = scoring.banded_ssim(x, gt)
    assert abs(full - got["ssim"]) > 1e-3  # at 64 rows it would have been another figure


def test_a_render_within_the_score_rows_is_scored_whole(monkeypatch):
    render, truth = _pair(32)
    got = scoring.image_scores(render, truth)
    assert got["ssim"] == scoring.banded_ssim(render[None], truth)
