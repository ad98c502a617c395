"""The renderer's mechanics with untrained networks: shapes, chunking, views, seam and poles."""

from __future__ import annotations

import pytest
import torch

from panogrf.model.render_net import PRESETS, PointFeatures, RendererNet, visibility
from panogrf.model.sampling import composite
from panogrf.renderer.cache import SceneCache, build_cache
from panogrf.renderer.render import (
    QUALITY,
    Sampling,
    point_features,
    render_panorama,
    render_rays,
    target_rays,
)


def _scene(views: int = 2, seed: int = 0) -> tuple[RendererNet, SceneCache]:
    gen = torch.Generator().manual_seed(seed)
    net = RendererNet(PRESETS["panogrf"]).eval()
    # Give the untrained geometry head non-zero outputs, so visibility varies.
    with torch.no_grad():
        for p in net.geometry.net[-1].parameters():
            p.copy_(torch.randn(p.shape, generator=gen) * 0.1)
    images = torch.rand(views, 3, 32, 64, generator=gen)
    c2w = torch.eye(4).repeat(views, 1, 1)
    c2w[:, 0, 3] = torch.linspace(-0.5, 0.5, views)
    depth = 1.0 + 3.0 * torch.rand(views, 1, 16, 32, generator=gen)
    with torch.no_grad():
        cache = build_cache(net, images, c2w, depth)
    return net, cache


def test_visibility_is_one_in_front_and_zero_far_behind():
    params = torch.zeros(5, 6)
    depth = torch.full((5,), 2.0)
    z = torch.tensor([0.5, 1.5, 2.0, 3.0, 10.0])
    v = visibility(params, depth, z)
    assert v[0] > 0.99 and v[-1] < 0.01
    assert (v.diff() <= 0).all()  # never more visible further along the ray


def test_cache_shapes_and_subset():
    net, cache = _scene(3)
    c = net.config.feature_channels
    assert cache.maps.shape == (3, c + 7, 16, 32)
    assert cache.num_views == 3 and cache.select([0, 2]).num_views == 2
    tgt = torch.eye(4)
    tgt[0, 3] = 0.4  # the views stand at x = -0.5, 0, 0.5
    near = cache.nearest(tgt, 2)
    torch.testing.assert_close(near.c2w, cache.c2w[[1, 2]])
    assert cache.nearest(tgt, 2) is near  # made once
    assert cache.nearest(tgt, None) is cache and cache.nearest(tgt, 3) is cache
    with pytest.raises(ValueError, match="c2w"):
        build_cache(net, cache.images, cache.c2w[:2], cache.depth)


@pytest.mark.parametrize("quality", ["fast", "paper"])
def test_render_panorama_is_finite_and_independent_of_the_chunk_size(quality):
    net, cache = _scene()
    tgt = torch.eye(4)
    tgt[2, 3] = 0.2
    sampling = QUALITY[quality] if quality == "fast" else Sampling(n_coarse=8, n_fine=8)
    a = render_panorama(net, cache, tgt, 8, sampling, chunk=100_000)
    b = render_panorama(net, cache, tgt, 8, sampling, chunk=64)
    assert a.rgb.shape == (3, 8, 16) and a.depth.shape == a.opacity.shape == (1, 8, 16)
    for t in (a.rgb, a.depth, a.opacity):
        assert torch.isfinite(t).all()
    assert torch.allclose(a.rgb, b.rgb, atol=1e-5)


def test_render_can_be_stopped_and_reports_progress():
    net, cache = _scene()
    seen = []
    out = render_panorama(net, cache, torch.eye(4), 8, "fast", chunk=64, progress=seen.append)
    assert out is not None and seen and seen[-1] == 1.0 and seen == sorted(seen)
    assert render_panorama(net, cache, torch.eye(4), 8, "fast", should_stop=lambda: True) is None


def test_aggregation_does_not_depend_on_the_order_of_the_views():
    net, cache = _scene(3)
    o, d = target_rays(torch.eye(4), 4, 8)
    t = torch.linspace(1.0, 4.0, 5).expand(32, 5)
    pts = (o[:, None] + t[..., None] * d[:, None]).reshape(-1, 3)
    dirs = d[:, None].expand(32, 5, 3).reshape(-1, 3)
    f = point_features(cache, pts, dirs, t.reshape(-1))
    perm = [2, 0, 1]
    g = PointFeatures(*(getattr(f, k)[perm] for k in f.__dataclass_fields__))
    with torch.no_grad():
        s1, c1 = net.aggregator(f)
        s2, c2 = net.aggregator(g)
    assert torch.allclose(s1, s2, atol=1e-5) and torch.allclose(c1, c2, atol=1e-5)


def test_any_number_of_views_and_gradients_reach_every_part():
    for views in (1, 2, 4):
        net, cache = _scene(views)
        assert render_panorama(net, cache, torch.eye(4), 4, "fast").rgb.shape == (3, 4, 8)
    net = RendererNet().train()
    gen = torch.Generator().manual_seed(1)
    images = torch.rand(2, 3, 32, 64, generator=gen)
    c2w = torch.eye(4).repeat(2, 1, 1)
    c2w[1, 0, 3] = 1.0
    cache = build_cache(net, images, c2w, torch.full((2, 1, 16, 32), 2.0))
    o, d = target_rays(torch.eye(4), 4, 8)
    out = render_rays(net, cache, o, d, Sampling(n_coarse=8, n_fine=4), generator=gen)
    out.final.rgb.sum().backward()
    for name, p in net.named_parameters():
        assert p.grad is not None, name


def test_feature_sampling_wraps_at_the_seam():
    # Points just left and right of the target's seam land on neighbouring source columns.
    net, cache = _scene(1)
    eps = 1e-3
    pts = torch.tensor([[-eps, 0.0, 2.0], [eps, 0.0, 2.0]])  # behind the camera (+z), at the seam
    f = point_features(cache, pts, pts / pts.norm(dim=-1, keepdim=True), pts.norm(dim=-1))
    assert torch.allclose(
        f.appearance[0, 0], f.appearance[0, 1], atol=0.05 * f.appearance.abs().max()
    )


def test_composite_of_an_opaque_first_sample():
    sigma = torch.tensor([[1e4, 0.0, 0.0]])
    rgb = torch.tensor([[[0.2, 0.4, 0.6], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]]])
    out = composite(sigma, rgb, torch.tensor([[1.0, 2.0, 3.0]]))
    assert torch.allclose(out.rgb, torch.tensor([[0.2, 0.4, 0.6]]), atol=1e-4)


def test_sources_finer_than_twice_the_render_are_read_area_averaged(monkeypatch):
    """A render at H rows reads sources of more than 2H rows averaged down to 2H (one read per
    pixel of far finer sources aliases); sources of at most 2H rows as they are."""
    from panogrf.renderer import cache as cache_module

    net, cache = _scene()  # 32-row sources
    assert cache.at_most(32) is cache and cache.at_most(64) is cache
    level = cache.at_most(16)
    assert level is cache.at_most(16)  # made once
    assert level.images.shape[-2:] == (16, 32) and level.maps is cache.maps
    want = torch.nn.functional.interpolate(cache.images, size=(16, 32), mode="area")
    assert torch.equal(level.images, want)
    tgt = torch.eye(4)
    tgt[2, 3] = 0.2
    averaged = SceneCache(want, cache.c2w, cache.depth, cache.maps, cache.feature_channels)
    at_8 = render_panorama(net, cache, tgt, 8, "fast")
    assert torch.equal(at_8.rgb, render_panorama(net, averaged, tgt, 8, "fast").rgb)
    at_16 = render_panorama(net, cache, tgt, 16, "fast")  # 32 rows = 2 x 16: as they are
    monkeypatch.setattr(cache_module, "SOURCE_ROWS_PER_ROW", None)
    assert torch.equal(at_16.rgb, render_panorama(net, cache, tgt, 16, "fast").rgb)
    assert not torch.equal(at_8.rgb, render_panorama(net, cache, tgt, 8, "fast").rgb)
