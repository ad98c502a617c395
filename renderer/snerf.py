"""The S-NeRF baseline: a spherical radiance field fitted to one scene's source panoramas.

No learned prior: a density and colour grid over spherical coordinates around the sources'
centroid (longitude, latitude, inverse radius, so resolution follows the panoramas' own and the
grid wraps in longitude), fitted by volume rendering to the source views' rays (photometric MSE
with a small total-variation prior), then rendered from the target. It sees only the two
sources, so it reproduces them and degrades away from them: the paper's per-scene S-NeRF row.
A voxel grid instead of an MLP keeps the fit to tens of seconds per scene on a CPU.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import cast

import torch
import torch.nn.functional as F
from torch import Tensor

from panogrf.model.erp import direction_to_lonlat, erp_directions
from panogrf.model.sampling import composite, inverse_depth_samples


@dataclass(frozen=True)
class SNeRFConfig:
    """Grid size and fitting schedule."""

    grid: tuple[int, int, int] = (48, 64, 128)
    """Cells in inverse radius, latitude, longitude."""
    r_min: float = 0.3
    """Smallest radius of the grid from its centre (metres)."""
    r_max: float = 20.0
    """Largest radius of the grid (metres)."""
    samples: int = 48
    """Samples per ray, uniform in inverse depth from the camera over [near, far]."""
    near: float = 0.3
    far: float = 15.0
    steps: int = 300
    """Optimiser steps of the fit."""
    rays: int = 4096
    """Rays per step."""
    lr: float = 0.1
    fit_height: int = 128
    """The sources are fitted at this height."""
    tv: float = 1e-4
    """Weight of the total-variation prior."""
    seed: int = 0


@dataclass
class SNeRF:
    """A fitted scene: grid [1, 4, D, H, W] (density logit, colour logits) and its centre."""

    grid: Tensor
    centre: Tensor  # [3] world
    config: SNeRFConfig


def _query(grid: Tensor, centre: Tensor, points: Tensor, cfg: SNeRFConfig) -> tuple[Tensor, Tensor]:
    """Density [N] and colour [N, 3] at world points [N, 3]."""
    rel = points - centre
    r = torch.linalg.vector_norm(rel, dim=-1).clamp(min=1e-6)
    lon, lat = direction_to_lonlat(rel)
    w = grid.shape[-1]
    # One wrapped cell on each side makes longitude continuous across +-pi.
    padded = torch.cat((grid[..., -1:], grid, grid[..., :1]), -1)
    x = ((lon / math.pi + 1.0) * w + 2.0) / (w + 2) - 1.0  # cell centres, on the padded width
    y = -lat / (math.pi / 2)
    inv = (1.0 / r - 1.0 / cfg.r_max) / (1.0 / cfg.r_min - 1.0 / cfg.r_max)
    z = inv.clamp(0, 1) * 2 - 1
    coords = torch.stack((x, y, z), -1).view(1, 1, 1, -1, 3)
    out = F.grid_sample(padded, coords, mode="bilinear", align_corners=False, padding_mode="border")
    out = out.view(4, -1).T
    return F.softplus(out[:, 0]), torch.sigmoid(out[:, 1:])


def _render_rays(
    model: SNeRF, origins: Tensor, dirs: Tensor, generator: torch.Generator | None = None
) -> Tensor:
    cfg = model.config
    r = origins.shape[0]
    t = inverse_depth_samples(r, cfg.samples, cfg.near, cfg.far, generator=generator)
    pts = origins[:, None] + t[..., None] * dirs[:, None]
    sigma, rgb = _query(model.grid, model.centre, pts.reshape(-1, 3), cfg)
    return composite(sigma.view(r, -1), rgb.view(r, -1, 3), t).rgb


def _tv(grid: Tensor) -> Tensor:
    # smoothness along every axis (a sum of tensors: a tensor, never sum's start, 0)
    return cast(Tensor, sum((grid.diff(dim=d) ** 2).mean() for d in (2, 3, 4)))


def fit_snerf(images: Tensor, c2w: Tensor, config: SNeRFConfig = SNeRFConfig()) -> SNeRF:
    """Fit the grid to source panoramas [V, 3, H, W] with poses [V, 4, 4]."""
    from panogrf.renderer.cache import resize_erp

    cfg = config
    small = resize_erp(images, cfg.fit_height)
    v, _, h, w = small.shape
    dirs = erp_directions(h, w, dtype=images.dtype).reshape(-1, 3)
    world_dirs = torch.einsum("vij,nj->vni", c2w[:, :3, :3].to(images.dtype), dirs)  # [V, N, 3]
    colours = small.flatten(2).transpose(1, 2)  # [V, N, 3]
    centre = c2w[:, :3, 3].mean(0).to(images.dtype)
    grid = torch.zeros(1, 4, *cfg.grid, dtype=images.dtype)
    grid[:, 0] = -3.0
    grid.requires_grad_(True)
    opt = torch.optim.Adam([grid], lr=cfg.lr)
    gen = torch.Generator().manual_seed(cfg.seed)
    weights = torch.cos(torch.linspace(-math.pi / 2, math.pi / 2, h + 2)[1:-1])
    probs = weights[:, None].expand(h, w).reshape(-1).repeat(v)
    model = SNeRF(grid, centre, cfg)
    with torch.enable_grad():
        for _ in range(cfg.steps):
            idx = torch.multinomial(probs, cfg.rays, replacement=True, generator=gen)
            view, pix = idx // (h * w), idx % (h * w)
            origins = c2w[view, :3, 3].to(images.dtype)
            pred = _render_rays(model, origins, world_dirs[view, pix], gen)
            loss = ((pred - colours[view, pix]) ** 2).mean() + cfg.tv * _tv(grid)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
    return SNeRF(grid.detach(), centre, cfg)


@torch.no_grad()
def render_snerf(model: SNeRF, tgt_c2w: Tensor, height: int, chunk: int = 8192) -> Tensor:
    """The fitted field seen from ``tgt_c2w`` [4, 4]: [3, H, 2H]."""
    width = 2 * height
    d = erp_directions(height, width, dtype=model.grid.dtype).reshape(-1, 3)
    d = d @ tgt_c2w[:3, :3].to(d.dtype).T
    o = tgt_c2w[:3, 3].to(d.dtype).expand_as(d)
    out = torch.cat(
        [_render_rays(model, o[i : i + chunk], d[i : i + chunk]) for i in range(0, len(d), chunk)]
    )
    return out.T.reshape(3, height, width).clamp(0, 1)
