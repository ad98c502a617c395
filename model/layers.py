"""Layers for panoramas: convolutions that wrap around in width (longitude) and zero-pad in height."""

from __future__ import annotations

import torch.nn.functional as F
from torch import Tensor, nn


def circular_pad(x: Tensor, pad_w: int, pad_h: int) -> Tensor:
    """Pad [B, C, H, W] by ``pad_w`` columns wrapping around and ``pad_h`` zero rows."""
    if pad_w:
        x = F.pad(x, (pad_w, pad_w, 0, 0), mode="circular")
    if pad_h:
        x = F.pad(x, (0, 0, pad_h, pad_h), mode="constant", value=0.0)
    return x


class CircularConv2d(nn.Conv2d):
    """Conv2d whose padding wraps in width and is zero in height (an ERP's topology).

    Takes the same arguments as `nn.Conv2d`; ``padding`` must be an int or an (h, w) pair.
    """

    def __init__(self, *args, padding: int | tuple[int, int] = 0, **kwargs) -> None:
        super().__init__(*args, padding=0, **kwargs)
        self.pad_hw = (padding, padding) if isinstance(padding, int) else tuple(padding)

    def forward(self, x: Tensor) -> Tensor:
        return super().forward(circular_pad(x, self.pad_hw[1], self.pad_hw[0]))
