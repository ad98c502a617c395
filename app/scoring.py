"""Scores of a rendered panorama against a reference: one function for render, eval, benchmarks."""

from __future__ import annotations

import math

import torch

from panogrf.app.weights.lpips import load_lpips
from panogrf.model.lpips import MIN_SIZE
from panogrf.model.metrics import psnr, ssim, ws_psnr

#: Side of `ssim`'s Gaussian window: smaller images have no SSIM (NaN, like LPIPS below its size).
SSIM_WINDOW = 11
#: Pixels per channel of one band of rows in `banded_ssim`. The whole-image SSIM holds about 20
#: float copies of the image (2.5 GB at 1024 x 2048 rows, 32 GB at 4096); a band, a few MB.
SSIM_BAND_PIXELS = 1 << 19
#: SSIM and LPIPS of a larger render are taken at this many rows (both images area-resized):
#: at the 3840 rows of an 8K capture they took 25 s each and 7 GB on 2 cores, at 1024 rows
#: 2 s. PSNR and WS-PSNR are always at the render's own size.
SCORE_ROWS = 1024


def banded_ssim(x: torch.Tensor, y: torch.Tensor) -> float:
    """`ssim` of [1, C, H, W] images in [0, 1], computed band of rows by band of rows (each
    band overlaps the next by the window, so the mean over the valid pixels is the same); NaN
    when H or W is below the window."""
    h, w = x.shape[-2:]
    if min(h, w) < SSIM_WINDOW:
        return math.nan
    valid, pad = h - (SSIM_WINDOW - 1), SSIM_WINDOW - 1
    rows = max(1, SSIM_BAND_PIXELS // w)  # valid rows per band
    total = 0.0
    for r in range(0, valid, rows):
        n = min(rows, valid - r)
        band = slice(r, r + n + pad)
        total += n * float(ssim(x[..., band, :], y[..., band, :]))
    return total / valid


def image_scores(rgb: torch.Tensor, reference: torch.Tensor) -> dict[str, float]:
    """PSNR, WS-PSNR (dB), SSIM and LPIPS (AlexNet) of a render [3, H, W] in [0, 1] against
    ``reference`` [1, 3, H', W'] (area-resized to the render's size when they differ); SSIM and
    LPIPS at `SCORE_ROWS` rows at most, NaN below their minimum sizes. A stage
    ("scoring") shows the progress when it takes a while (an 8K render)."""
    from panogrf.model.progress import stage
    from panogrf.renderer.cache import resize_erp

    with stage("scoring", 3) as progress:
        rgb = rgb.detach().float().cpu()  # scored on the CPU, whatever device rendered it
        gt = resize_erp(reference.detach().float().cpu(), rgb.shape[-2]).clamp(0, 1)
        x = rgb[None].clamp(0, 1)
        scores = {"psnr": float(psnr(x, gt)), "ws_psnr": float(ws_psnr(x, gt))}
        if x.shape[-2] > SCORE_ROWS:
            x, gt = resize_erp(x, SCORE_ROWS), resize_erp(gt, SCORE_ROWS)
        progress.advance()
        scores["ssim"] = banded_ssim(x, gt)
        progress.advance()
        scores["lpips"] = float("nan")  # LPIPS needs a minimum size
        if min(x.shape[-2:]) >= MIN_SIZE:
            with torch.no_grad():
                scores["lpips"] = float(load_lpips()(x, gt).mean())
        progress.advance()
    return scores
