"""The fast renderer against a slow, obviously correct one on random inputs.

The reference projects every point into every source with the formulas of
docs/conventions.md written out (world -> camera by the inverse pose, longitude and latitude,
pixel coordinates), samples the maps by explicit bilinear interpolation (wrapping in width,
clamped in height), and composites each ray sample by sample (`composite_reference`). The fast
path batches all of it (`point_features`, `render_rays`); both must agree to float precision.
"""

from __future__ import annotations

import math

import pytest
import torch
from helpers.nets import random_cache

from panogrf.model.render_net import PointFeatures, visibility
from panogrf.model.sampling import composite_reference, inverse_depth_samples, sample_pdf
from panogrf.renderer.render import Sampling, point_features, render_rays

DOUBLE = torch.float64


def _pixel(d: list[float], height: int, width: int) -> tuple[float, float]:
    """docs/conventions.md inverted: d = (cos lat sin lon, sin lat, -cos lat cos lon)."""
    x, y, z = d
    lon = math.atan2(x, -z)
    lat = math.asin(max(-1.0, min(1.0, y)))
    u = (lon / (2 * math.pi) + 0.5) * width - 0.5
    v = (0.5 - lat / math.pi) * height - 0.5
    return u, v


def _bilinear(image: torch.Tensor, u: float, v: float) -> torch.Tensor:
    """image [C, H, W] at (u, v): columns wrap, rows clamp to the first and last."""
    _, h, w = image.shape
    v = min(max(v, 0.0), h - 1.0)
    u0, v0 = math.floor(u), math.floor(v)
    fu, fv = u - u0, v - v0
    v1 = min(v0 + 1, h - 1)
    out = 0.0
    for du, wu in ((0, 1 - fu), (1, fu)):
        for vv, wv in ((v0, 1 - fv), (v1, fv)):
            out = out + wu * wv * image[:, vv, (u0 + du) % w]
    return out


def reference_features(cache, points: torch.Tensor, ray_dirs: torch.Tensor, t: torch.Tensor):
    """`point_features`, one point and one view at a time."""
    c = cache.feature_channels
    fields = {k: [] for k in ("appearance", "colour", "visibility", "residual", "direction")}
    for view in range(cache.num_views):
        rot, centre = cache.c2w[view, :3, :3], cache.c2w[view, :3, 3]
        rows = {k: [] for k in fields}
        for p, ray, tp in zip(points, ray_dirs, t, strict=True):
            cam = rot.T @ (p - centre)  # world -> camera: the inverse of the pose
            z = torch.linalg.vector_norm(cam)
            d = (cam / z).tolist()
            maps = _bilinear(cache.maps[view], *_pixel(d, *cache.maps.shape[-2:]))
            colour = _bilinear(cache.images[view], *_pixel(d, *cache.images.shape[-2:]))
            src_dir = (p - centre) / z
            depth = maps[c + 6]
            rows["appearance"].append(maps[:c])
            rows["colour"].append(colour)
            rows["visibility"].append(visibility(maps[c : c + 6], depth, z))
            rows["residual"].append(depth / z - 1.0)
            rows["direction"].append(
                torch.stack(
                    (
                        (src_dir * ray).sum(),
                        torch.linalg.vector_norm(src_dir - ray),
                        torch.log(z / tp),
                    )
                )
            )
        for k in fields:
            fields[k].append(torch.stack(rows[k]))
    return PointFeatures(**{k: torch.stack(v) for k, v in fields.items()})


def _random_points(n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    origins = torch.rand(n, 3, generator=g, dtype=torch.float64) - 0.5
    dirs = torch.nn.functional.normalize(
        torch.randn(n, 3, generator=g, dtype=torch.float64), dim=-1
    )
    t = 0.3 + 3.0 * torch.rand(n, generator=g, dtype=torch.float64)
    return origins + t[:, None] * dirs, dirs, t


def _cache():
    net, cache = random_cache(views=3)
    net = net.double()
    cache = type(cache)(
        cache.images.double(),
        cache.c2w.double(),
        cache.depth.double(),
        cache.maps.double(),
        cache.feature_channels,
    )
    # Rotated sources too, not only translated ones.
    turn = torch.tensor(
        [
            [math.cos(0.7), 0.0, math.sin(0.7)],
            [0.0, 1.0, 0.0],
            [-math.sin(0.7), 0.0, math.cos(0.7)],
        ],
        dtype=torch.float64,
    )
    cache.c2w[2, :3, :3] = turn
    cache.c2w[2, :3, 3] = torch.tensor([0.3, 0.2, -0.4], dtype=torch.float64)
    # A new cache: its padded maps and inverse poses are derived on construction.
    cache = type(cache)(cache.images, cache.c2w, cache.depth, cache.maps, cache.feature_channels)
    return net, cache


def test_point_features_match_the_reference_projection():
    _, cache = _cache()
    points, dirs, t = _random_points(40, seed=1)
    fast = point_features(cache, points, dirs, t)
    slow = reference_features(cache, points, dirs, t)
    for name in ("appearance", "colour", "visibility", "residual", "direction"):
        torch.testing.assert_close(getattr(fast, name), getattr(slow, name), msg=name)


def test_points_across_the_seam_and_near_the_poles_match_too():
    _, cache = _cache()
    # Straight behind the first source (the seam, lon = +-pi) and nearly straight up / down.
    points = torch.tensor(
        [[1e-4, 0.1, 2.0], [-1e-4, -0.1, 2.0], [0.01, 3.0, 0.02], [0.02, -2.0, -0.01]],
        dtype=torch.float64,
    )
    dirs = torch.nn.functional.normalize(points, dim=-1)
    t = torch.linalg.vector_norm(points, dim=-1)
    fast = point_features(cache, points, dirs, t)
    slow = reference_features(cache, points, dirs, t)
    torch.testing.assert_close(fast.appearance, slow.appearance)
    torch.testing.assert_close(fast.colour, slow.colour)


def _shade_reference(net, cache, origins, dirs, t):
    """Density and colour at samples t [R, S]: reference projection, the aggregator per ray."""
    sigmas, rgbs = [], []
    for o, d, tr in zip(origins, dirs, t, strict=True):
        points = o[None] + tr[:, None] * d[None]
        feats = reference_features(cache, points, d[None].expand_as(points), tr)
        sigma, rgb = net.aggregator(feats)
        sigmas.append(sigma)
        rgbs.append(rgb)
    return torch.stack(sigmas), torch.stack(rgbs)


@pytest.mark.parametrize("n_fine", [0, 4])
def test_rendered_rays_match_projection_aggregation_and_compositing_by_hand(n_fine):
    net, cache = _cache()
    g = torch.Generator().manual_seed(2)
    origins = 0.2 * torch.rand(3, 3, generator=g, dtype=torch.float64)
    dirs = torch.nn.functional.normalize(
        torch.randn(3, 3, generator=g, dtype=torch.float64), dim=-1
    )
    sampling = Sampling(n_coarse=6, n_fine=n_fine, near=0.3, far=4.0)
    with torch.no_grad():
        out = render_rays(net, cache, origins, dirs, sampling)
        t_c = inverse_depth_samples(3, 6, 0.3, 4.0, dtype=torch.float64)
        coarse = composite_reference(*_shade_reference(net, cache, origins, dirs, t_c), t_c)
        ref = coarse
        if n_fine:
            t_f = sample_pdf(t_c, coarse.weights, n_fine)
            t_all = torch.sort(torch.cat((t_c, t_f), -1), -1).values
            ref = composite_reference(*_shade_reference(net, cache, origins, dirs, t_all), t_all)
            torch.testing.assert_close(out.coarse.rgb, coarse.rgb)
    torch.testing.assert_close(out.final.rgb, ref.rgb)
    torch.testing.assert_close(out.final.weights, ref.weights)
    torch.testing.assert_close(out.final.depth, ref.depth)
