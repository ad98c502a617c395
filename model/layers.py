"""Layers for panoramas: convolutions that wrap around in width (longitude), zero-pad in height."""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn


def circular_pad(x: Tensor, pad_w: int, pad_h: int) -> Tensor:
    """Pad [B, C, H, W] by ``pad_w`` columns wrapping around and ``pad_h`` zero rows."""
    if pad_w:  # one concatenation: F.pad's circular mode is several copies
        x = torch.cat((x[..., -pad_w:], x, x[..., :pad_w]), -1)
    if pad_h:
        x = F.pad(x, (0, 0, pad_h, pad_h), mode="constant", value=0.0)
    return x


class CircularConv2d(nn.Conv2d):
    """Conv2d whose padding wraps in width and is zero in height (an ERP's topology).

    Takes the same arguments as `nn.Conv2d`, positionally or by name; ``padding`` must be an
    int or an (h, w) pair of ints, and ``padding_mode`` is not accepted (the mode is fixed).
    """

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        kernel_size: int | tuple[int, int],
        stride: int | tuple[int, int] = 1,
        padding: int | tuple[int, int] = 0,
        *args: Any,
        **kwargs: Any,
    ) -> None:
        if "padding_mode" in kwargs:
            raise TypeError("CircularConv2d pads circularly in width and with zeros in height")
        pad_hw = (padding, padding) if isinstance(padding, int) else padding
        if (
            not isinstance(pad_hw, (tuple, list))
            or len(pad_hw) != 2
            or not all(isinstance(p, int) and p >= 0 for p in pad_hw)
        ):
            raise ValueError(
                f"padding must be an int or an (h, w) pair of ints >= 0, got {padding!r}"
            )
        super().__init__(in_channels, out_channels, kernel_size, stride, 0, *args, **kwargs)
        self.pad_hw = tuple(pad_hw)

    def forward(self, x: Tensor) -> Tensor:
        return super().forward(circular_pad(x, self.pad_hw[1], self.pad_hw[0]))

    def extra_repr(self) -> str:
        # mypy's untyped_calls_exclude (torch) does not reach calls through super().
        base = super().extra_repr()  # type: ignore[no-untyped-call]
        return f"{base}, circular_padding(h, w)={self.pad_hw}"
