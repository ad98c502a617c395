"""A synthetic capture rig painted at the nadir of panoramas: a hub and three tripod legs."""

from __future__ import annotations

import math

import torch

DARK = (0.05, 0.05, 0.06)


def rig_mask(height: int, width: int, hub_deg: float = 8.0, leg_deg: float = 15.0) -> torch.Tensor:
    """[H, W] bool: a hub within ``hub_deg`` of the nadir and three legs 0.3 rad wide reaching
    ``leg_deg`` from it (the ERP's bottom rows)."""
    lat = 90.0 - 180.0 * (torch.arange(height, dtype=torch.float64) + 0.5) / height
    lon = 2 * math.pi * ((torch.arange(width, dtype=torch.float64) + 0.5) / width - 0.5)
    rho = (lat + 90.0).view(height, 1).expand(height, width)
    mask = rho < hub_deg
    for a in (0.3, 2.4, 4.5):
        d = torch.remainder(lon - a + math.pi, 2 * math.pi) - math.pi
        mask = mask | ((d.abs().view(1, width) < 0.15) & (rho < leg_deg))
    return mask


def paint_rig(images: torch.Tensor, colour=DARK, **kw) -> tuple[torch.Tensor, torch.Tensor]:
    """Panoramas [V, 3, H, W] with the rig painted in ``colour`` at every nadir, and its mask
    [H, W] bool."""
    mask = rig_mask(*images.shape[-2:], **kw)
    out = images.clone()
    out[:, :, mask] = torch.tensor(colour, dtype=images.dtype).view(1, 3, 1)
    return out, mask
