"""Exposure and white balance made consistent across the source panoramas of one scene.

Real captures change exposure and white balance from shot to shot; a renderer that blends a
dark and a bright photograph paints a grey average. Panoramas of one place see nearly the same
content (every view sees the whole room), so each view's solid-angle-weighted mean log colour
estimates its exposure: every view is scaled, per channel, towards the scene's common mean.
Differences below ``deadband`` (log of linear light; 0.3 ~ 35 %, about half a stop) are what
moving the camera changes in the content itself, and are left alone.
"""

from __future__ import annotations

import torch
from torch import Tensor

from panogrf.model.erp import latitude_weights


def exposure_gains(images: Tensor, deadband: float = 0.3, max_gain: float = 4.0) -> Tensor:
    """Per-view, per-channel gains [V, 3] that bring images [V, 3, H, W] in [0, 1] to a common
    exposure (1 where a view is within ``deadband`` of the common mean)."""
    v, _, h, w = images.shape
    if v < 2:
        return images.new_ones(v, 3)
    lin = images.clamp(0, 1) ** 2.2
    # Clipped highlights and black pixels carry no exposure information.
    usable = ((lin > 1e-3) & (images < 0.98)).to(images.dtype)
    weight = latitude_weights(h, w, device=images.device, dtype=images.dtype)[None, None]
    weight = weight * usable
    log_mean = (torch.log(lin.clamp(min=1e-3)) * weight).sum((2, 3)) / weight.sum((2, 3)).clamp(
        min=1e-6
    )  # [V, 3]
    offset = log_mean.mean(0, keepdim=True) - log_mean  # log gain towards the common mean
    size = offset.abs().amax(1, keepdim=True)
    shrink = (size - deadband).clamp(min=0) / size.clamp(min=1e-9)
    lin_gain = torch.exp(offset * shrink).clamp(1 / max_gain, max_gain)
    return lin_gain ** (1 / 2.2)  # gains in display space, applied to the stored colours


def balance_exposure(images: Tensor, deadband: float = 0.3) -> tuple[Tensor, Tensor]:
    """images [V, 3, H, W] in [0, 1] -> (balanced images, gains [V, 3])."""
    gains = exposure_gains(images, deadband)
    if bool((gains == 1).all()):
        return images, gains
    return (images * gains[..., None, None]).clamp(0, 1), gains
