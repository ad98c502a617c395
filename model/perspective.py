"""Perspective views cut out of equirectangular panoramas (pure torch).

A pinhole camera with the panorama's orientation (OpenGL frame: x right, y up, looking down -z)
and a vertical field of view; each output pixel's ray is looked up in the panorama with
bilinear sampling and horizontal wrap-around (`sample_erp_directions`).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from panogrf.model.erp import sample_erp_directions


def perspective_directions(
    width: int,
    height: int,
    fov_deg: float,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """Unit ray directions [h, w, 3] of a pinhole camera's pixel centres (camera frame)."""
    if not 0 < fov_deg < 180:
        raise ValueError(f"fov must be in (0, 180) degrees, got {fov_deg}")
    f = 0.5 * height / math.tan(math.radians(fov_deg) / 2)
    y, x = torch.meshgrid(
        torch.arange(height, device=device, dtype=dtype) + 0.5,
        torch.arange(width, device=device, dtype=dtype) + 0.5,
        indexing="ij",
    )
    d = torch.stack(((x - width / 2) / f, -(y - height / 2) / f, -torch.ones_like(x)), -1)
    unit: Tensor = d / torch.linalg.vector_norm(d, dim=-1, keepdim=True)
    return unit


def erp_to_perspective(erp: Tensor, width: int, height: int, fov_deg: float) -> Tensor:
    """Panorama [C, H, W] -> the pinhole view [C, height, width] looking along its -z."""
    d = perspective_directions(width, height, fov_deg, device=erp.device, dtype=erp.dtype)
    out = sample_erp_directions(erp[None], d.reshape(1, -1, 3))
    return out.reshape(erp.shape[0], height, width)
