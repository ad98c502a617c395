"""The photometric error as written, with average pooling on the ERP padding (seam wrapped,
rows repeated): the reference that `panogrf.model.ssim` is tested against."""

from __future__ import annotations

import torch
import torch.nn.functional as F


def pool(x: torch.Tensor, k: int = 3) -> torch.Tensor:
    """k x k window mean of [B, C, H, W], wrapping at the seam and repeating the edge rows."""
    p = k // 2
    x = torch.cat((x[..., -p:], x, x[..., :p]), -1)
    return F.avg_pool2d(F.pad(x, (0, 0, p, p), mode="replicate"), k, 1)


def plain_photometric(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """0.85 clamp((1 - SSIM) / 2) + 0.15 |a - b|, the channel mean, of [B, 3, H, W] against
    ``b`` ([1 or B, 3, H, W]): [B, H, W] (autograd's gradient)."""
    b = b.expand_as(a)
    mu_a, mu_b = pool(a), pool(b)
    var_a, var_b = pool(a * a) - mu_a**2, pool(b * b) - mu_b**2
    cov = pool(a * b) - mu_a * mu_b
    c1, c2 = 0.01**2, 0.03**2
    ssim = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / (
        (mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2)
    )
    return (0.85 * ((1 - ssim) / 2).clamp(0, 1) + 0.15 * (a - b).abs()).mean(1)
