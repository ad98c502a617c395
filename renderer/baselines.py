"""Baselines rendered through the same inputs and metrics as PanoGRF.

- `render_nearest`: the source panorama closest to the target, turned to the target's
  orientation (no parallax at all: the floor every method must beat).
- `render_meshwarp`: the sources' depth maps splatted into the target (z-buffer, depth edges
  dropped: the depth mesh without its stretched triangles), then every source's colour fetched
  through that depth and blended by visibility (the source's own depth must agree) and
  closeness of the source. OmniSyn's warping without its inpainting network.

Shapes: V views, H W the target panorama.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from panogrf.model.erp import erp_to_world, sample_erp, world_to_erp
from panogrf.model.splat import proxy_depth
from panogrf.model.warp import rotate_panorama


def nearest_source(c2w: Tensor, tgt_c2w: Tensor) -> int:
    """Index of the source [V, 4, 4] whose centre is closest to the target's [4, 4]."""
    return int(torch.linalg.vector_norm(c2w[:, :3, 3] - tgt_c2w[:3, 3], dim=-1).argmin())


def _resize(image: Tensor, height: int) -> Tensor:
    if image.shape[-2] == height:
        return image
    mode = "area" if image.shape[-2] > height else "bilinear"
    kw = {} if mode == "area" else {"align_corners": False}
    return F.interpolate(image, size=(height, 2 * height), mode=mode, **kw)


@torch.no_grad()
def render_nearest(images: Tensor, c2w: Tensor, tgt_c2w: Tensor, height: int) -> Tensor:
    """[V, 3, H', W'], [V, 4, 4], [4, 4] -> the nearest source rotated, [3, H, 2H]."""
    j = nearest_source(c2w, tgt_c2w)
    src = _resize(images[j : j + 1], height)
    return rotate_panorama(src, c2w[j : j + 1], tgt_c2w[None].to(c2w.dtype))[0].clamp(0, 1)


@torch.no_grad()
def render_meshwarp(
    images: Tensor,  # [V, 3, H', W'] sources
    c2w: Tensor,  # [V, 4, 4]
    depth: Tensor,  # [V, 1, h, w] estimated source depth (metres)
    tgt_c2w: Tensor,  # [4, 4]
    height: int,
    occlusion_tol: float = 0.08,
) -> tuple[Tensor, Tensor]:
    """Depth-warped blend of the sources: colour [3, H, 2H] and target depth [1, H, 2H]."""
    width = 2 * height
    tgt_c2w = tgt_c2w.to(c2w.dtype)
    proxy = proxy_depth(depth, c2w, tgt_c2w, height, width)
    points = erp_to_world(proxy.near[None], tgt_c2w[None])  # [1, H*W, 3]
    v = images.shape[0]
    h, w = depth.shape[-2:]
    uv, dist = world_to_erp(points.expand(v, -1, -1), c2w, h, w)  # [V, N, 2], [V, N]
    hi, wi = images.shape[-2:]
    uv_img = uv * (wi / w) + 0.5 * (wi / w - 1.0)
    colours = sample_erp(images, uv_img)  # [V, 3, N]
    seen = sample_erp(depth, uv, mode="nearest")[:, 0]  # [V, N]
    visible = ((seen - dist).abs() <= occlusion_tol * dist).to(images.dtype)
    closeness = 1.0 / (torch.linalg.vector_norm(c2w[:, :3, 3] - tgt_c2w[:3, 3], dim=-1) + 1e-2)
    weight = (visible + 1e-3) * closeness[:, None]  # hidden everywhere: still some colour
    rgb = (colours * weight[:, None]).sum(0) / weight.sum(0)[None]
    return rgb.reshape(3, height, width).clamp(0, 1), proxy.near[None]
