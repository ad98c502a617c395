"""Full-resolution panoramas from a network pass at the renderer's own resolution.

The renderer's networks saw 256-row panoramas in training and their features live at that scale;
running them on every pixel of a 512-row output costs four times as much and, on real captures,
blurs: each pixel composites projections from several depths. Here the network renders at
``net_height`` rows (colour and depth) and the full-resolution sources give the detail:

1. every output pixel's point is projected into every source and its full-resolution colour
   read. The point lies at the sources' own depth seen from the target (`projection_depth`:
   their depth maps splatted into the target at the network's rows, the nearest surface
   kept, through a median; upsampled in inverse depth), not at the network's expected depth,
   which a volume render smears across depth edges and pulls towards its spread samples;
2. each source is weighted by how well it agrees with the network's colour at the network's
   resolution (the network has already decided which sources see the point: occluded or
   disoccluded ones disagree with it);
3. the output is the network's colour below ``cutoff`` rows (a low-pass) plus the blend's
   colour above it: detail only, so a projection that is slightly off moves edges by a
   pixel, never the colour of a region. The cutoff sits below the network's own rows: a
   volume render is softer than its pixels, and the sources that agree with it know the
   band between better. Where no source agrees with the network (a disocclusion it filled
   in) the network's colour stays.

Shapes: V views, H x 2H the output, h x 2h the network's pass.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import torch
import torch.nn.functional as F
from torch import Tensor

from panogrf.model.erp import (
    direction_to_pixel,
    erp_direction_rows,
    erp_directions,
    sample_padded,
)
from panogrf.model.layers import circular_pad
from panogrf.model.render_net import RendererNet
from panogrf.model.splat import proxy_depth
from panogrf.model.steps import apart_from_captures
from panogrf.model.sweep import median_filter
from panogrf.renderer.cache import SceneCache, resize_erp, source_rows
from panogrf.renderer.graphs import replayed
from panogrf.renderer.nadir import mask_factor
from panogrf.renderer.render import Quality, RenderOutput, Sampling, render_panorama


@dataclass(frozen=True)
class DetailConfig:
    """How the full-resolution detail is transferred."""

    net_height: int = 256
    """Rows of the network's pass (the renderer's training resolution)."""
    agreement: float = 0.1
    """Scale (mean absolute colour difference) of a source's agreement with the network: its
    weight is exp(-difference / agreement)."""
    cutoff: int | None = None
    """Rows of the low-pass below which the network's colour is kept (None: ``net_height``):
    above it the sources that agree give the colour's detail, also the network's own band
    between the cutoff and its resolution (a volume render is softer than its pixels)."""
    sampling: str = "bilinear"
    """How the full-resolution sources are read: "bilinear" or "bicubic" (keeps more of the
    band near the sources' own resolution). Bicubic applies to outputs of at least the
    sources' rows; a smaller output reads them bilinearly (validation, 256-row output from
    512-row sources, fast at 256 + detail above 32: bilinear 27.97 / 0.094, bicubic 27.55 /
    0.096; sources area-averaged to 256 rows first: 27.12 / 0.110 bilinear, 27.57 / 0.098
    bicubic)."""
    projection: str = "splat"
    """The depth at which the sources are read (`projection_depth`): "splat" (the sources'
    own depth maps splatted into the target) or "network" (the render's expected depth)."""
    median: int = 7
    """Side of the median over the splatted depth, in pixels of the network's rows."""
    proximity: float = 2.0
    """Each source's agreement weight in the blend is multiplied by (1 / (d + 1 cm)) to this
    power, d its distance from the target's centre (0: agreement alone): the nearer photo's
    projection, less displaced by an error in depth, gives the detail, and at a photo's own
    pose that photo is the view. Halfway between two photos the weights are as before."""


#: Chosen on 12 validation scenes at 512 rows generated from the train split's generator with
#: unused seeds (`benchmarks/detail.py`, 6 classic + 6 home, fast sampling), WS-PSNR / SSIM /
#: LPIPS / median s: network at 512 rows 26.11 / 0.890 / 0.175 / 7.03; network at 256 with
#: bilinear upsampling 25.10 / 0.872 / 0.226 / 1.70; + detail with agreement 0.03: 26.23 /
#: 0.896 / 0.157 / 1.84, 0.1: 26.34 / 0.895 / 0.147 / 1.79, 0.3: 26.29 / 0.893 / 0.147 / 1.87.
#: The cutoff, on the same scenes (`--ladder`, WS-PSNR / LPIPS; detail_cutoff_val.json): the
#: network at 192 rows with detail above 192 (no cutoff) 26.26 / 0.140, above 128 26.21 /
#: 0.135, 96 26.40 / 0.128, 64 26.51 / 0.125, 48 26.56 / 0.124, 32 26.59 / 0.124; at 256 rows
#: 26.48 / 0.146 -> 26.61 / 0.126 with 32; at 128 rows with 32 26.52 / 0.121 (48: 26.42 /
#: 0.122); the draft at 128 rows 25.15 / 0.162 -> 25.61 / 0.152.
#: Bicubic reading of the sources (`--ladder fast@128@32:bicubic`, detail_bicubic_val.json): at
#: 128 rows 26.52 / 0.121 -> 26.61 / 0.110, at 256 rows 26.61 / 0.126 -> 26.72 / 0.115, the
#: draft 25.61 / 0.152 -> 25.68 / 0.141, at the same cost. Measured and dropped: a softmax that
#: picks the best-agreeing source (scale 0.03: 26.36 / 0.120, 0.01: 26.07 / 0.120) and a gain
#: on the transferred band (1.25: 26.19 / 0.108, 1.5: 25.41 / 0.114).
#: The projection depth (`--ladder ...:network` / `...:splat`, detail_projection_val.json,
#: the same 12 scenes, WS-PSNR / LPIPS / median s): fast at 256 26.82 / 0.106 / 1.03 with the
#: network's depth, 27.21 / 0.095 / 1.13 splatted (median 5: 27.21 / 0.097, 9: 27.19 / 0.094);
#: the viewer's draft at 128 25.61 / 0.143 -> 26.43 / 0.109, its fast level at 128 26.66 /
#: 0.103 -> 26.87 / 0.094; at 256 rows out (detail_projection_val256.json) 28.18 / 0.084 ->
#: 28.46 / 0.074.
DEFAULT_DETAIL = DetailConfig(cutoff=32, sampling="bicubic", projection="splat", median=7)


PROJECTIONS = ("splat", "network")


def projection_depth(
    cache: SceneCache, c2w: Tensor, low: RenderOutput, config: DetailConfig
) -> Tensor:
    """The target's depth [1, h, 2h] (metres) at the rows of the network's pass ``low``, at
    which `add_detail` reads the sources. "network": the render's expected depth. "splat": the
    sources' depth maps (bilinearly resized to those rows) splatted into the target, the
    nearest surface kept and holes filled from the farther side (`panogrf.model.splat`), then
    a median of ``config.median`` pixels that takes out single splatted pixels and cracks."""
    if config.projection not in PROJECTIONS:
        raise ValueError(f"projection must be one of {PROJECTIONS}, got {config.projection!r}")
    if config.projection == "network":
        return low.depth
    h, w = low.depth.shape[-2:]
    src = F.interpolate(cache.depth, size=(h, w), mode="bilinear", align_corners=False)
    near = proxy_depth(src, cache.c2w, c2w.to(src.dtype), h, w).near
    return median_filter(near[None, None], config.median)[0]


def upsample_erp(x: Tensor, size: tuple[int, int]) -> Tensor:
    """Bilinear upsampling of [C, h, w] panoramas to ``size``, wrapping at the seam (``x``
    itself when it has that size already)."""
    if tuple(x.shape[-2:]) == tuple(size):
        return x
    h, w = size
    scale = w / x.shape[-1]
    p = round(scale)
    up = F.interpolate(circular_pad(x[None], 1, 0), size=(h, w + 2 * p), mode="bilinear")[0]
    return up[..., p : p + w]


def _upsample_depth(depth: Tensor, size: tuple[int, int]) -> Tensor:
    """Depth [1, h, w] upsampled in inverse depth (edges stay between their two sides)."""
    return 1.0 / upsample_erp(1.0 / depth.clamp(min=1e-3), size).clamp(min=1e-4)


def _smooth(x: Tensor) -> Tensor:
    """3x3 box filter of [C, h, w], wrapping in width."""
    pad = F.pad(circular_pad(x[None], 1, 0), (0, 0, 1, 1), mode="replicate")
    return F.avg_pool2d(pad, 3, 1)[0]


def project_sources(
    cache: SceneCache, c2w: Tensor, depth: Tensor, sampling: str = "bilinear"
) -> Tensor:
    """Colours [V, 3, H, W] of the sources at the points of the target panorama's pixels at
    spherical depth ``depth`` [H, W] (metres), read from the full-resolution sources
    (``sampling``: "bilinear" or "bicubic")."""
    return _projected(cache, c2w, depth, sampling)[0]


#: Pixels of a band of rows in `project_sources` (larger panoramas are read band by band: an 8K
#: output's intermediates are a few hundred MB each).
BAND_PIXELS = 1 << 21


def _projected(
    cache: SceneCache, c2w: Tensor, depth: Tensor, sampling: str = "bilinear"
) -> tuple[Tensor, Tensor | None]:
    """`project_sources` and the sources' masked fraction there [V, 1, H, W] (None without
    a nadir mask), band of rows by band of rows beyond `BAND_PIXELS`."""
    h, w = depth.shape
    if h * w <= BAND_PIXELS:
        dirs = erp_directions(h, w, device=depth.device, dtype=depth.dtype)
        return _projected_rows(cache, c2w, depth, dirs, sampling)
    v, rows = cache.num_views, max(1, BAND_PIXELS // w)
    colour = depth.new_empty(v, 3, h, w)
    masked = None if cache.mask is None else depth.new_empty(v, 1, h, w)
    for first in range(0, h, rows):
        last = min(h, first + rows)
        dirs = erp_direction_rows(h, w, first, last, device=depth.device, dtype=depth.dtype)
        c, m = _projected_rows(cache, c2w, depth[first:last], dirs, sampling)
        colour[..., first:last, :] = c
        if masked is not None and m is not None:
            masked[..., first:last, :] = m
    return colour, masked


def _projected_rows(
    cache: SceneCache, c2w: Tensor, depth: Tensor, dirs: Tensor, sampling: str
) -> tuple[Tensor, Tensor | None]:
    """`_projected` of rows whose camera-frame directions are ``dirs`` [h, W, 3] at depth
    ``depth`` [h, W]."""
    h, w = depth.shape
    dirs = dirs @ c2w[:3, :3].T
    points = c2w[:3, 3] + dirs * depth[..., None]  # [h, W, 3] world
    w2c = cache.w2c
    cam = points.reshape(1, -1, 3) @ w2c[:, :3, :3].transpose(1, 2) + w2c[:, None, :3, 3]
    hi, wi = cache.images.shape[-2:]
    uv = direction_to_pixel(cam, hi, wi)  # [V, N, 2]
    pad = 2 if sampling == "bicubic" else 1
    colour = sample_padded(cache.images_padded_by(pad), uv, sampling, pad=pad)  # [V, 3, N]
    masked = cache.masked_at(uv, hi, wi)
    return colour.reshape(-1, 3, h, w), None if masked is None else masked.reshape(-1, 1, h, w)


def proximity_weights(cache: SceneCache, c2w: Tensor, power: float) -> Tensor:
    """[V] (1 / (d + 1 cm)) ** ``power``, d each source's distance from the target's centre
    (`DetailConfig.proximity`), scaled to a largest weight of 1."""
    centres = cache.c2w[:, :3, 3]
    d = torch.linalg.vector_norm(centres - c2w[:3, 3].to(centres.dtype), dim=-1)
    w: Tensor = (0.01 / (d + 0.01)).pow(power)
    return w / w.amax()


def add_detail(
    cache: SceneCache,
    c2w: Tensor,
    low: RenderOutput,
    height: int,
    config: DetailConfig,
) -> Tensor:
    """The network's low-resolution render ``low`` brought to ``height`` rows with the sources'
    detail: [3, H, 2H] in [0, 1]. The sources are read at `projection_depth`, upsampled."""
    size = (height, 2 * height)
    h = low.rgb.shape[-2]
    cache = cache.at_most(source_rows(height))
    depth = _upsample_depth(projection_depth(cache, c2w, low, config), size)
    sampling = config.sampling if height >= cache.images.shape[-2] else "bilinear"
    proj, masked = _projected(cache, c2w.to(depth.dtype), depth[0], sampling)
    proj_low = resize_erp(proj, h)  # [V, 3, h, 2h]
    diff = _smooth((proj_low - low.rgb[None]).abs().mean(1))  # [V, h, 2h]
    weight = torch.exp(-diff / config.agreement)
    if masked is not None:  # a source gives no detail where its rig hides the point
        weight = weight * mask_factor(resize_erp(masked, h)[:, 0])
    total = weight.sum(0, keepdim=True)
    near = weight * proximity_weights(cache, c2w, config.proximity)[:, None, None]
    blend_w = near / near.sum(0, keepdim=True).clamp(min=1e-12)
    gate = total.clamp(max=1.0)  # no source agrees: no detail
    # One upsampling for the network's colour, the gate and the sources' weights.
    up = upsample_erp(torch.cat((low.rgb, gate, blend_w)), size)
    up_rgb, up_gate, up_w = up[:3], up[3:4], up[4:]
    # In place from here: at an 8K output each full-resolution copy is 350 MB.
    blend = proj.mul_(up_w[:, None]).sum(0)  # [3, H, W]
    del proj
    cut = min(config.cutoff or h, h)
    # Above the cutoff the blend replaces the network's colour: (blend - low-pass of blend) -
    # (rgb - low-pass of rgb), one low-pass of the difference. At the network's own rows its
    # colour has nothing above the cutoff to replace.
    diff = blend.sub_(up_rgb) if cut < h else blend
    detail = diff.sub_(upsample_erp(resize_erp(diff[None], cut)[0], size))
    return detail.mul_(up_gate).add_(up_rgb).clamp_(0, 1)


@torch.no_grad()
def render_detailed(
    net: RendererNet,
    cache: SceneCache,
    c2w: Tensor,
    height: int,
    quality: Quality | Sampling = Quality.FAST,
    config: DetailConfig = DEFAULT_DETAIL,
    progress: Callable[[float], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> RenderOutput | None:
    """`render_panorama` at ``height`` rows with the network at ``config.net_height`` (when
    ``height`` is larger; otherwise at ``height``), the sources giving the colour above
    ``config.cutoff`` rows; None if ``should_stop`` said so. On a GPU the same render asked for
    again is replayed from a CUDA graph (`panogrf.renderer.graphs`)."""
    if should_stop is not None and should_stop():
        return None
    # On a GPU not while another thread captures a graph (`CAPTURE_LOCK`).
    with apart_from_captures(cache.images):
        out = replayed(_render_detailed, net, cache, c2w, height, quality, config)
        if out is not None:
            if progress is not None:
                progress(1.0)
            return out
        return _render_detailed(net, cache, c2w, height, quality, config, progress, should_stop)


def _render_detailed(
    net: RendererNet,
    cache: SceneCache,
    c2w: Tensor,
    height: int,
    quality: Quality | Sampling,
    config: DetailConfig,
    progress: Callable[[float], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> RenderOutput | None:
    if height <= config.net_height:
        out = render_panorama(
            net, cache, c2w, height, quality, progress=progress, should_stop=should_stop
        )
        if out is None or not config.cutoff or config.cutoff >= height:
            return out
        # The network's own resolution: the sources replace its soft band above the cutoff
        # (validation, 24 scenes at 256 rows, fast, WS-PSNR / LPIPS: plain 25.41 / 0.155,
        # above 32 rows 25.44 / 0.124, above 64 25.45 / 0.128).
        return replace(out, rgb=add_detail(cache, c2w, out, height, config))
    low = render_panorama(
        net, cache, c2w, config.net_height, quality, progress=progress, should_stop=should_stop
    )
    if low is None:
        return None
    size = (height, 2 * height)
    return RenderOutput(
        rgb=add_detail(cache, c2w, low, height, config),
        depth=_upsample_depth(low.depth, size),
        opacity=upsample_erp(low.opacity, size).clamp(0, 1),
    )
