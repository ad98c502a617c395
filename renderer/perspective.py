"""Rendering a pinhole camera's own rays from a `SceneCache` (no panorama in between)."""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from panogrf.model.erp import direction_to_pixel, pad_seam, sample_padded
from panogrf.model.perspective import perspective_directions
from panogrf.model.render_net import RendererNet
from panogrf.renderer.cache import SceneCache
from panogrf.renderer.render import (
    Quality,
    RenderOutput,
    Sampling,
    proxy_for,
    render_chunks,
    sampling_for,
)

#: Rows of the proxy panorama a perspective frame's rays look their near and far up in.
PERSPECTIVE_PROXY_ROWS = 512


@torch.no_grad()
def render_perspective(
    net: RendererNet,
    cache: SceneCache,
    c2w: Tensor,  # [4, 4] camera pose (OpenGL: looking down -z)
    width: int,
    height: int,
    fov_deg: float,
    quality: Quality | Sampling = Quality.FAST,
    chunk: int | None = None,
    progress: Callable[[float], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> RenderOutput | None:
    """Render exactly the rays of a pinhole camera (vertical field of view ``fov_deg``):
    [3, height, width], with no panorama in between. The guided samplings read their near and
    far proxies from the target's proxy panorama (`PERSPECTIVE_PROXY_ROWS` rows) along each
    ray's direction."""
    c2w = c2w.to(cache.images.dtype)
    cam = perspective_directions(width, height, fov_deg, device=c2w.device, dtype=c2w.dtype)
    cam = cam.reshape(-1, 3)
    dirs = cam @ c2w[:3, :3].T
    origins = c2w[:3, 3].expand_as(dirs)
    sampling = sampling_for(quality, cache, c2w)
    proxy = None
    if sampling.n_guided:
        rows = PERSPECTIVE_PROXY_ROWS
        p = proxy_for(cache, c2w, rows, 2 * rows)
        uv = direction_to_pixel(cam, rows, 2 * rows)[None]
        near_far = sample_padded(pad_seam(torch.stack((p.near, p.far))[None]), uv, "nearest")
        proxy = (near_far[0, 0], near_far[0, 1])
    out = render_chunks(net, cache, origins, dirs, sampling, proxy, chunk, progress, should_stop)
    return None if out is None else out.reshaped(height, width)
