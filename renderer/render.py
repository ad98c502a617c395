"""Rendering a target panorama from a `SceneCache`: the one chunked render function.

Spherical ray casting from the target centre; every sample point is projected into every source
view (ERP, wrapping at the seam), where the cached maps give its appearance feature, visibility
and depth residual, and the source panorama its colour; the `Aggregator` turns those into a
density and a colour; volume compositing gives the pixel. Two samplings:

- ``paper``: 64 samples uniform in inverse depth over the scene's range, then 64 importance
  samples from their weights (PanoGRF's 64 + 64);
- ``fast``: depth-guided. The cached depths, splatted into the target (`panogrf.model.splat`),
  give every ray a near and a far proxy; 8 samples around them and a sparse uniform backbone
  of 4 (for the rays whose proxy is wrong) replace the 128, in one pass.

The uniform samples span the scene's depth range seen from the target (`sample_range`: the
cached source depths lifted to the world, their nearest and farthest distance from the target
centre, with a margin), not a fixed near and far: a 3 m room and a 12 m hall get the same
number of samples where their surfaces are. `render_rays` serves training and rendering
alike; `render_panorama` chunks a whole panorama so memory stays bounded at any resolution.
A source's sample that falls in its rig's mask at the nadir (`SceneCache.mask`) counts as not
seen by it (`panogrf.renderer.nadir.mask_factor`): the other sources fill the floor in.
Shapes: R rays, S samples, V views.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from enum import StrEnum
from typing import Any

import torch
from torch import Tensor

from panogrf.model.erp import direction_to_pixel, erp_directions, sample_padded
from panogrf.model.render_net import PointFeatures, RendererNet, visibility
from panogrf.model.sampling import (
    Composite,
    composite,
    guided_samples,
    inverse_depth_samples,
    sample_pdf,
)
from panogrf.model.splat import ProxyDepth, proxy_depth
from panogrf.renderer.cache import SceneCache, source_rows
from panogrf.renderer.nadir import mask_factor


@dataclass(frozen=True)
class Sampling:
    """How rays are sampled."""

    n_coarse: int = 64
    """Samples uniform in inverse depth over [near, far]; with guided samples, a sparse
    backbone composited with them in one pass (no importance pass)."""
    n_fine: int = 64
    """Importance samples from the coarse weights."""
    n_guided: int = 0
    """Samples around the splatted proxy depths (needs a proxy)."""
    near: float | Tensor | None = None
    """Nearest sample of the uniform sampling (metres); None: from the scene's cached depth
    (`sample_range`); a 0-dim tensor in a render replayed from a CUDA graph
    (`panogrf.renderer.graphs`)."""
    far: float | Tensor | None = None
    """Farthest sample of the uniform sampling (metres); None: from the scene's cached depth."""
    band: float = 0.2
    """Half-width of the guided band in relative inverse depth (log scale). Estimated depth
    is off by 10-20 % on many pixels: a band of 0.2 holds the true depth for most of them
    (measured on validation scenes of the train split)."""
    surface: bool = False
    """Colour the pixel with the sources' blend at the composited depth (one more shading
    per ray) instead of compositing the samples' colours: the composite mixes projections
    from several depths, which blurs detail in proportion to the parallax."""


class Quality(StrEnum):
    """A named sampling of the renderer (`QUALITY`: ``paper`` and ``fast`` as the module says,
    ``draft`` the viewer's first pass), or the GL preview instead of the renderer."""

    PAPER = "paper"
    FAST = "fast"
    DRAFT = "draft"
    PREVIEW = "preview"
    """No sampling (none in `QUALITY`): the GL depth-mesh preview (`panogrf.renderer.gl_preview`)
    draws the sources warped by their depth."""


#: ``fast``: 8 samples around the proxies plus a backbone of 4 uniform ones, 12 per ray. Chosen
#: on validation scenes of the train split (6 scenes, 128 rows, WS-PSNR): guided 8 alone 29.34,
#: 8 + 4 backbone 30.00, 12 guided 29.40, 64 + 64 30.26 dB.
#: ``draft`` (3 guided + 1 uniform) is the viewer's first refinement, chosen on the renderer's
#: 24 validation scenes of the train split at 256 rows (`benchmarks/draft_sampling.py`),
#: WS-PSNR / median seconds, 2 sources: fast 26.99 / 1.49, 4 + 2: 26.62 / 0.84, 4 + 1: 26.52 /
#: 0.75, 3 + 2: 26.42 / 0.71, 3 + 1: 26.30 / 0.59, 2 + 2: 26.30 / 0.59; the GL preview it
#: replaces: 23.98 dB.
QUALITY: dict[Quality, Sampling] = {
    Quality.PAPER: Sampling(n_coarse=64, n_fine=64),
    Quality.FAST: Sampling(n_coarse=4, n_fine=0, n_guided=8),
    Quality.DRAFT: Sampling(n_coarse=1, n_fine=0, n_guided=3),
}


#: `sample_range`: the nearest sample at `NEAR_MARGIN` times the 2nd percentile of the cached
#: surfaces' distances from the target, the farthest at `FAR_MARGIN` times the 98th, never
#: nearer than `MIN_NEAR`. Percentiles, not the extremes: one stray depth pixel (a few
#: centimetres from a source) would pull the sparse uniform backbone of draft and fast into
#: empty space by the camera. Chosen on the first 8 test triplets at 128 rows among min / max
#: with margins 0.6 / 1.5, these, 5th / 95th, 10th / 90th percentiles (`fast` WS-PSNR 26.12,
#: 27.06, 26.44, 26.35; the fixed [0.5, 15] m it replaces: 26.83), then checked on 8 scenes
#: of data/val_fusion_classic (train split) at 128 rows against the fixed range
#: (`benchmarks/sample_range.py`): draft 26.11 -> 26.53, fast 27.34 -> 27.90, paper 28.38 ->
#: 28.39 dB.
NEAR_QUANTILE, FAR_QUANTILE = 0.02, 0.98
NEAR_MARGIN, FAR_MARGIN, MIN_NEAR = 0.8, 1.2, 0.05


def sample_range(cache: SceneCache, centre: Tensor) -> tuple[float, float]:
    """Near and far (metres) of the uniform samples of rays from ``centre`` [3] (world): the
    cached source depths [V, 1, h, w] lifted to world points, the 2nd and 98th percentile of
    their distances from the centre, widened by `NEAR_MARGIN` and `FAR_MARGIN`."""
    points, known = cache.surface_points()
    dist = torch.linalg.vector_norm(points - centre.to(points.dtype), dim=-1)
    dist = torch.where(known & torch.isfinite(dist), dist, torch.nan)
    # torch.quantile takes < 2^24 values; NaN (no depth) is left out, without a boolean
    # selection that would wait for a GPU.
    dist = dist[:: max(1, dist.numel() >> 20)].float()
    lo, hi = torch.nanquantile(dist, _quantiles(dist.device)).tolist()
    if math.isnan(lo):  # no usable depth: the range the renderer was trained with
        return 0.5, 15.0
    near = max(MIN_NEAR, NEAR_MARGIN * lo)
    return near, max(2.0 * near, FAR_MARGIN * hi)


@functools.lru_cache(maxsize=8)
def _quantiles(device: torch.device) -> Tensor:
    """`NEAR_QUANTILE` and `FAR_QUANTILE` on ``device``, copied there once."""
    return torch.tensor([NEAR_QUANTILE, FAR_QUANTILE], device=device)


def with_range(sampling: Sampling, cache: SceneCache, centre: Tensor) -> Sampling:
    """``sampling`` with its unset near / far taken from `sample_range`."""
    if sampling.near is not None and sampling.far is not None:
        return sampling
    near, far = sample_range(cache, centre)
    return replace(
        sampling,
        near=near if sampling.near is None else sampling.near,
        far=far if sampling.far is None else sampling.far,
    )


@dataclass
class RayOutput:
    """What `render_rays` returns: the final composite and, with two passes, the first; with
    ``Sampling.surface`` the final colour is the surface colour and ``blended`` keeps the
    composite of the samples' colours."""

    final: Composite
    coarse: Composite | None = None
    blended: Composite | None = None


def surface_colour(
    net: RendererNet, cache: SceneCache, origins: Tensor, dirs: Tensor, comp: Composite
) -> Composite:
    """``comp`` with its colour replaced by the aggregator's blend of the source colours at the
    composited depth (times the opacity, as compositing leaves the rest black)."""
    _, rgb = _shade(net, cache, origins, dirs, comp.depth[:, None])
    return Composite(rgb[:, 0] * comp.opacity[:, None], comp.depth, comp.opacity, comp.weights)


def _finish(
    net: RendererNet,
    cache: SceneCache,
    origins: Tensor,
    dirs: Tensor,
    sampling: Sampling,
    final: Composite,
    coarse: Composite | None = None,
) -> RayOutput:
    if not sampling.surface:
        return RayOutput(final, coarse)
    return RayOutput(surface_colour(net, cache, origins, dirs, final), coarse, final)


def point_features(cache: SceneCache, points: Tensor, ray_dirs: Tensor, t: Tensor) -> PointFeatures:
    """What each source view says about world points [N, 3] on target rays [N, 3] at t [N]."""
    w2c = cache.w2c
    cam = points[None] @ w2c[:, :3, :3].transpose(1, 2) + w2c[:, None, :3, 3]  # [V, N, 3]
    z = torch.linalg.vector_norm(cam, dim=-1).clamp(min=1e-6)  # [V, N]
    h, w = cache.maps.shape[-2:]
    uv = direction_to_pixel(cam, h, w)  # [V, N, 2]
    sampled = sample_padded(cache.maps_padded, uv).transpose(1, 2)  # [V, N, C + 7]
    masked = cache.masked_at(uv, h, w)  # [V, N]: in the source's rig at the nadir
    hi, wi = cache.images.shape[-2:]
    if (hi, wi) != (h, w):
        uv = uv * (wi / w) + 0.5 * (wi / w - 1.0)  # same directions on the finer grid
    colour = sample_padded(cache.images_padded_by(1), uv).transpose(1, 2)  # [V, N, 3]
    c = cache.feature_channels
    params, depth = sampled[..., c : c + 6], sampled[..., c + 6]
    src_dirs = (points[None] - cache.centres[:, None]) / z[..., None]
    cos = (src_dirs * ray_dirs[None]).sum(-1)
    gap = torch.linalg.vector_norm(src_dirs - ray_dirs[None], dim=-1)
    ratio = torch.log(z / t.clamp(min=1e-6)[None])
    vis = visibility(params, depth, z)
    if masked is not None:  # a source does not see what its rig hides (`mask_factor`)
        vis = vis * mask_factor(masked)
    return PointFeatures(
        appearance=sampled[..., :c],
        colour=colour,
        visibility=vis,
        residual=depth / z - 1.0,
        direction=torch.stack((cos, gap, ratio), -1),
    )


def _shade(
    net: RendererNet, cache: SceneCache, origins: Tensor, dirs: Tensor, t: Tensor
) -> tuple[Tensor, Tensor]:
    """Density [R, S] and colour [R, S, 3] at samples t [R, S] of rays (origins, dirs) [R, 3]."""
    r, s = t.shape
    pts = origins[:, None] + t[..., None] * dirs[:, None]  # [R, S, 3]
    feats = point_features(
        cache, pts.reshape(-1, 3), dirs[:, None].expand(r, s, 3).reshape(-1, 3), t.reshape(-1)
    )
    sigma, rgb = net.aggregator(feats)
    return sigma.reshape(r, s), rgb.reshape(r, s, 3)


def render_rays(
    net: RendererNet,
    cache: SceneCache,
    origins: Tensor,  # [R, 3] world
    dirs: Tensor,  # [R, 3] unit, world
    sampling: Sampling,
    proxy: tuple[Tensor, Tensor] | None = None,  # near, far [R] metres
    generator: torch.Generator | None = None,
) -> RayOutput:
    """Render R rays with one sampling strategy (see `Sampling`); an unset near / far comes
    from the cached depth seen from the first ray's origin (the rays of one panorama share it)."""
    r = origins.shape[0]
    if sampling.n_coarse and (sampling.near is None or sampling.far is None):
        sampling = with_range(sampling, cache, origins[0])

    def uniform() -> Tensor:
        assert sampling.near is not None and sampling.far is not None  # set above (with_range)
        return inverse_depth_samples(
            r,
            sampling.n_coarse,
            sampling.near,
            sampling.far,
            generator=generator,
            device=origins.device,
            dtype=origins.dtype,
        )

    if sampling.n_guided:
        if proxy is None:
            raise ValueError("guided sampling needs proxy depths")
        t = guided_samples(proxy[0], proxy[1], sampling.n_guided, sampling.band)
        if sampling.n_coarse:
            # A sparse uniform backbone catches surfaces the proxies miss (wrong depth).
            t = torch.sort(torch.cat((t, uniform()), -1), -1).values
        sigma, rgb = _shade(net, cache, origins, dirs, t)
        return _finish(net, cache, origins, dirs, sampling, composite(sigma, rgb, t))
    t_c = uniform()
    sigma_c, rgb_c = _shade(net, cache, origins, dirs, t_c)
    coarse = composite(sigma_c, rgb_c, t_c)
    if not sampling.n_fine:
        return _finish(net, cache, origins, dirs, sampling, coarse)
    t_f = sample_pdf(t_c, coarse.weights, sampling.n_fine, generator=generator)
    sigma_f, rgb_f = _shade(net, cache, origins, dirs, t_f)
    # One network for both passes: the coarse samples' values are reused, merged in order.
    t_all, order = torch.sort(torch.cat((t_c, t_f), -1), -1)
    sigma = torch.cat((sigma_c, sigma_f), -1).gather(-1, order)
    rgb = torch.cat((rgb_c, rgb_f), 1).gather(1, order[..., None].expand(-1, -1, 3))
    return _finish(net, cache, origins, dirs, sampling, composite(sigma, rgb, t_all), coarse)


@dataclass
class RenderOutput:
    """A rendered panorama."""

    rgb: Tensor  # [3, H, W] in [0, 1]
    depth: Tensor  # [1, H, W] expected spherical depth (metres)
    opacity: Tensor  # [1, H, W]


def target_rays(c2w: Tensor, height: int, width: int) -> tuple[Tensor, Tensor]:
    """Origins and unit directions [H*W, 3] (world) of every pixel of an ERP camera c2w [4, 4]."""
    d = erp_directions(height, width, device=c2w.device, dtype=c2w.dtype).reshape(-1, 3)
    d = d @ c2w[:3, :3].T
    return c2w[:3, 3].expand_as(d), d


def proxy_for(cache: SceneCache, c2w: Tensor, height: int, width: int) -> ProxyDepth:
    """Proxy depths of a target panorama from the cached source depths."""
    return proxy_depth(cache.depth, cache.c2w, c2w, height, width)


@torch.no_grad()
def render_panorama(
    net: RendererNet,
    cache: SceneCache,
    c2w: Tensor,  # [4, 4] target pose
    height: int,
    quality: Quality | Sampling = Quality.FAST,
    chunk: int | None = None,
    progress: Callable[[float], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> RenderOutput | None:
    """Render the H x 2H panorama seen from ``c2w``; None if ``should_stop`` said so midway.

    ``quality``: a `Quality` or a `Sampling`. Rays go through the network ``chunk`` sample
    points per view at a time (None: `default_chunk` of the cache's device), so memory stays
    bounded at any resolution; ``progress`` gets the fraction done.
    """
    width = 2 * height
    c2w = c2w.to(cache.images.dtype)
    cache = cache.at_most(source_rows(height))
    origins, dirs = target_rays(c2w, height, width)
    sampling = sampling_for(quality, cache, c2w)
    proxy = None
    if sampling.n_guided:
        p = proxy_for(cache, c2w, height, width)
        proxy = (p.near.reshape(-1), p.far.reshape(-1))
    out = render_chunks(net, cache, origins, dirs, sampling, proxy, chunk, progress, should_stop)
    return None if out is None else out.reshaped(height, width)


#: Sample points per view in one pass of the network on a CPU: a few tens of megabytes at a
#: time, which the CPU's caches and allocator handle best.
CPU_CHUNK = 16384
#: The same on a GPU: about half a gigabyte at a time (in ``fast``, the rays of a whole
#: panorama at the network's rows in one pass). Small chunks leave a GPU waiting for Python to
#: launch each chunk's few hundred operations (`benchmarks/gpu.py`: the chunk's times and
#: peak memory).
GPU_CHUNK = 1 << 21


def default_chunk(device: torch.device) -> int:
    """Sample points per view in one pass of the network on ``device``."""
    return CPU_CHUNK if device.type == "cpu" else GPU_CHUNK


def sampling_for(quality: Quality | Sampling, cache: SceneCache, c2w: Tensor) -> Sampling:
    """``quality``'s `Sampling` (a `Quality` or its value: a ValueError for another name and
    for the preview, which samples nothing) with its range seen from ``c2w`` [4, 4]."""
    sampling = quality if isinstance(quality, Sampling) else QUALITY.get(Quality(quality))
    if sampling is None:
        raise ValueError(f"quality {quality}: the GL preview, not a sampling of the renderer")
    if sampling.n_coarse:  # once per frame, not per chunk
        sampling = with_range(sampling, cache, c2w[:3, 3])
    return sampling


@dataclass
class _Rays:
    rgb: Tensor  # [N, 3]
    depth: Tensor  # [N]
    opacity: Tensor  # [N]

    def reshaped(self, height: int, width: int) -> RenderOutput:
        return RenderOutput(
            rgb=self.rgb.clamp(0, 1).T.reshape(3, height, width),
            depth=self.depth.reshape(1, height, width),
            opacity=self.opacity.reshape(1, height, width),
        )


def render_chunks(
    net: RendererNet,
    cache: SceneCache,
    origins: Tensor,
    dirs: Tensor,
    sampling: Sampling,
    proxy: tuple[Tensor, Tensor] | None,
    chunk: int | None,
    progress: Callable[[float], None] | None,
    should_stop: Callable[[], bool] | None,
) -> _Rays | None:
    """`render_rays` over N rays, ``chunk`` sample points per view at a time."""
    n = origins.shape[0]
    per_ray = max(sampling.n_guided, sampling.n_coarse, sampling.n_fine)
    chunk = max(64, (chunk or default_chunk(origins.device)) // per_ray)
    kw: dict[str, Any] = {"dtype": origins.dtype, "device": origins.device}
    rgb, depth, opacity = torch.empty(n, 3, **kw), torch.empty(n, **kw), torch.empty(n, **kw)
    for start in range(0, n, chunk):
        if should_stop is not None and should_stop():
            return None
        sl = slice(start, start + chunk)
        px = None if proxy is None else (proxy[0][sl], proxy[1][sl])
        out = render_rays(net, cache, origins[sl], dirs[sl], sampling, px).final
        rgb[sl], depth[sl], opacity[sl] = out.rgb, out.depth, out.opacity
        if progress is not None:
            progress(min(1.0, (start + chunk) / n))
    return _Rays(rgb, depth, opacity)
