"""Scores of a rendered panorama against a reference: one function for render, eval, benchmarks."""

from __future__ import annotations

import torch

from panogrf.app.lpips_weights import load_lpips
from panogrf.model.lpips import MIN_SIZE
from panogrf.model.metrics import psnr, ssim, ws_psnr


def image_scores(rgb: torch.Tensor, reference: torch.Tensor) -> dict[str, float]:
    """PSNR, WS-PSNR (dB), SSIM and LPIPS (AlexNet) of a render [3, H, W] in [0, 1] against
    ``reference`` [1, 3, H', W'] (area-resized to the render's size when they differ); LPIPS is
    NaN below its minimum size."""
    from panogrf.renderer.cache import resize_erp

    gt = resize_erp(reference, rgb.shape[-2]).clamp(0, 1)
    x = rgb[None].clamp(0, 1)
    lp = float("nan")  # LPIPS needs a minimum size
    if min(x.shape[-2:]) >= MIN_SIZE:
        with torch.no_grad():
            lp = float(load_lpips()(x, gt).mean())
    return {
        "psnr": float(psnr(x, gt)),
        "ws_psnr": float(ws_psnr(x, gt)),
        "ssim": float(ssim(x, gt)),
        "lpips": lp,
    }
