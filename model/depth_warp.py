"""A source panorama seen from a reference camera at a given spherical depth, with its gradient in
the depth written out: the warp the sweep scores its candidates by and the refinement steps
through.

The reference's rays in the source's frame and its centre there do not depend on the depth
(`warp_rays`); per pixel the point is q = d r + s, its source pixel
(u, v) = ERP(q), and d(u, v)/dd has a closed form in q and r (`_pixel_rate`). The backward pass
is then the resampling's gradient in its grid (one call of torch's own kernel, not the image's
gradient) times that rate, in place of autograd's record of the two dozen passes of the
projection. The same arithmetic as ``sample_padded(padded, direction_to_pixel(q))`` in the
forward pass; the gradient agrees with autograd's to rounding (tests/model/test_depth_warp.py).
"""

from __future__ import annotations

import math
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from panogrf.model.erp import direction_to_pixel, pad_seam, padded_grid


def warp_from(
    source: Tensor, depth: Tensor, ref_c2w: Tensor, src_c2w: Tensor, dirs: Tensor
) -> Tensor:
    """The source panorama [1, 3, H, W] seen from the reference camera with its spherical depth
    [H, W] (metres): [1, 3, H, W]. dirs: [H, W, 3] reference camera-frame ray directions."""
    return warp_batch(source, depth[None], ref_c2w[None], src_c2w[None], dirs)


def warp_rays(ref_c2w: Tensor, src_c2w: Tensor, dirs: Tensor) -> tuple[Tensor, Tensor]:
    """What a warp from sources ``src_c2w`` into references ``ref_c2w`` [P, 4, 4] does not take
    from the depth: the reference's rays in each source's frame [P, H, W, 3] and the reference
    centre there [P, 3] (x_src = R_s^T (R_r x + t_r - t_s); dirs [H, W, 3])."""
    rot_s = src_c2w[:, :3, :3].transpose(1, 2)  # [P, 3, 3] world -> source camera
    rot = rot_s @ ref_c2w[:, :3, :3]
    shift = (rot_s @ (ref_c2w[:, :3, 3] - src_c2w[:, :3, 3])[..., None])[..., 0]  # [P, 3]
    return dirs[None] @ rot.transpose(1, 2)[:, None], shift


def warp_batch(
    sources: Tensor, depth: Tensor, ref_c2w: Tensor, src_c2w: Tensor, dirs: Tensor
) -> Tensor:
    """Source panoramas [P, 3, H, W] seen from their reference cameras ``ref_c2w`` [P, 4, 4]
    with spherical depths [P, H, W] -> [P, 3, H, W], one batched resampling (on a GPU one launch
    per operation instead of one per warp). The rotated rays do not depend on the depth, so its
    gradient skips the matrix products (`warp_rays`, `warp_along`)."""
    return warp_along(pad_seam(sources), depth, *warp_rays(ref_c2w, src_c2w, dirs))


def warp_along(padded: Tensor, depth: Tensor, rays: Tensor, shift: Tensor) -> Tensor:
    """Sources padded by `pad_seam` (one column) [P, C, H, W + 2] seen along rays [P, H, W, 3]
    from a centre ``shift`` [P, 3] (their frame) at spherical depths [P, H, W] -> [P, C, H, W]
    (rays and centres may be one [1, ...] for every depth). Differentiable in ``depth`` only."""
    out: Tensor = _DepthWarp.apply(padded, depth, rays, shift)  # type: ignore[no-untyped-call]
    return out


def _grid(padded: Tensor, q: Tensor) -> Tensor:
    """Points [P, N, 3] in the sources' frames -> grid_sample's grid [P, 1, N, 2] on the padded
    sources (as `panogrf.model.erp.sample_padded` with one padded column)."""
    height, width = padded.shape[-2], padded.shape[-1] - 2
    return padded_grid(direction_to_pixel(q, height, width), height, width)


def _pixel_rate(q: Tensor, rays: Tensor, height: int, width: int) -> tuple[Tensor, Tensor]:
    """d(grid x, grid y)/d(depth) [P, N] each, of points q = d r + s [P, N, 3] along rays r.

    lon = atan2(x, -z): dlon = (x r_z - z r_x) / (x^2 + z^2); lat = atan2(y, h) with
    h = sqrt(x^2 + z^2): dlat = (h^2 r_y - y (x r_x + z r_z)) / (h |q|^2). Zero on the vertical
    axis (as the projection's own gradient there)."""
    x, y, z = q.unbind(-1)
    rx, ry, rz = rays.unbind(-1)
    r2 = x * x + z * z
    off_axis = r2 > torch.finfo(q.dtype).tiny
    safe = torch.where(off_axis, r2, 1.0)
    dlon = (x * rz - z * rx).div_(safe)
    radial = x * rx + z * rz
    dlat = (safe * ry - y * radial).div_(torch.sqrt(safe) * (safe + y * y))
    # u = (lon / 2 pi + 1/2) W - 1/2, grid x = (u + 3/2) 2 / (W + 2); v = (1/2 - lat / pi) H -
    # 1/2, grid y = (v + 1/2) 2 / H.
    gx = torch.where(off_axis, dlon, 0.0).mul_(width / (math.pi * (width + 2)))
    gy = torch.where(off_axis, dlat, 0.0).mul_(-2.0 / math.pi)
    return gx, gy


class _DepthWarp(torch.autograd.Function):
    """`warp_along` with its depth gradient written out (module docstring)."""

    @staticmethod
    def forward(ctx: Any, padded: Tensor, depth: Tensor, rays: Tensor, shift: Tensor) -> Tensor:
        p, h, w = depth.shape
        flat = rays.reshape(rays.shape[0], -1, 3)  # one set of rays may serve every depth
        q = depth.reshape(p, -1, 1) * flat + shift[:, None]
        grid = _grid(padded, q)
        out = F.grid_sample(
            padded, grid, mode="bilinear", padding_mode="border", align_corners=False
        )
        if ctx.needs_input_grad[1]:
            rate = _pixel_rate(q, flat, h, w)
            ctx.save_for_backward(padded, grid, *rate)
        return out[:, :, 0].reshape(p, -1, h, w)

    @staticmethod
    def backward(ctx: Any, *grads: Tensor) -> tuple[Tensor | None, ...]:
        padded, grid, gx, gy = ctx.saved_tensors
        g = grads[0]
        p, c, h, w = g.shape
        # aten's own backward of grid_sample (bilinear, border, align_corners False), the grid
        # only: the sources take no gradient.
        _, g_grid = torch.ops.aten.grid_sampler_2d_backward(
            g.reshape(p, c, 1, -1), padded, grid, 0, 1, False, [False, True]
        )
        g_depth = g_grid[:, 0, :, 0].mul_(gx).add_(g_grid[:, 0, :, 1].mul_(gy))
        return None, g_depth.reshape(p, h, w), None, None
