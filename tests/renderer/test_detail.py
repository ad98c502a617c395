"""Full-resolution detail from the sources on top of a low-resolution render, on the analytic room
with a fine texture: exact depth and the truth's low-pass as the "network" output."""

from __future__ import annotations

import torch
from helpers.room import erp_ray_directions, pose, ray_distance

from panogrf.renderer.cache import SceneCache, resize_erp
from panogrf.renderer.detail import DetailConfig, add_detail, project_sources, proximity_weights
from panogrf.renderer.render import RenderOutput

H = 96


def _fine(points: torch.Tensor) -> torch.Tensor:
    """A fine texture: detail a 48-row render cannot hold."""
    x, y, z = points.unbind(-1)
    return 0.5 + 0.4 * torch.stack(
        (torch.sin(23 * x + 17 * y), torch.sin(19 * z - 13 * x), torch.cos(29 * y + 11 * z)), -1
    )


def _render(c2w: torch.Tensor, height: int = H) -> tuple[torch.Tensor, torch.Tensor]:
    dirs = erp_ray_directions(height, 2 * height) @ c2w[:3, :3].T
    t = ray_distance(c2w[:3, 3], dirs, ball=True)
    image = _fine(c2w[:3, 3] + dirs * t[..., None])
    return image.permute(2, 0, 1).float(), t[None].float()


def _scene():
    eye = torch.eye(3, dtype=torch.float64)
    poses = [pose(eye, (-0.4, 0.0, 0.1)), pose(eye, (0.5, 0.1, -0.1))]
    images, depths = zip(*(_render(p) for p in poses), strict=True)
    c2w = torch.stack(poses).float()
    depth = torch.stack(depths)
    maps = torch.zeros(2, 8, H, 2 * H)
    cache = SceneCache(torch.stack(images), c2w, depth, maps, 1)
    target = pose(eye, (0.05, 0.05, 0.0))
    truth, truth_depth = _render(target)
    return cache, target.float(), truth, truth_depth


def _psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(10 * torch.log10(1 / ((a - b) ** 2).mean()))


def _low_pass(truth: torch.Tensor, truth_depth: torch.Tensor, low_h: int) -> RenderOutput:
    """The truth at ``low_h`` rows as the "network" output (depth averaged in inverse depth)."""
    return RenderOutput(
        rgb=resize_erp(truth[None], low_h)[0],
        depth=1.0 / resize_erp(1.0 / truth_depth[None], low_h)[0],
        opacity=torch.ones(1, low_h, 2 * low_h),
    )


def _detail_psnr(cache, target, low, truth, **config) -> float:
    """PSNR against ``truth`` of ``low`` brought to H rows by `add_detail` with ``config``."""
    low_h = low.rgb.shape[-2]
    out = add_detail(cache, target, low, H, DetailConfig(net_height=low_h, **config))
    return _psnr(out, truth)


def test_projection_at_the_true_depth_reads_the_source_itself():
    cache, _, _, _ = _scene()
    proj = project_sources(cache, cache.c2w[0], cache.depth[0, 0])
    assert _psnr(proj[0], cache.images[0]) > 40


def test_detail_restores_what_the_low_resolution_render_lost():
    cache, target, truth, truth_depth = _scene()
    low_h = H // 2
    low = _low_pass(truth, truth_depth, low_h)
    out = add_detail(cache, target, low, H, DetailConfig(net_height=low_h))
    up = torch.nn.functional.interpolate(low.rgb[None], size=(H, 2 * H), mode="bilinear")[0]
    assert out.shape == truth.shape and torch.isfinite(out).all()
    assert _psnr(out, truth) > _psnr(up, truth) + 3.0
    # Detail only: the low-pass of the output is the network's colour.
    assert _psnr(resize_erp(out[None], low_h)[0], low.rgb) > 30


def test_bicubic_reading_keeps_more_of_the_sources_detail_than_bilinear():
    cache, target, truth, truth_depth = _scene()
    low_h = H // 2
    low = _low_pass(truth, truth_depth, low_h)
    scores = {
        mode: _detail_psnr(cache, target, low, truth, sampling=mode)
        for mode in ("bilinear", "bicubic")
    }
    assert scores["bicubic"] > scores["bilinear"] + 0.3, scores


def test_an_output_smaller_than_the_sources_reads_them_bilinearly():
    cache, target, truth, truth_depth = _scene()
    out_h, low_h = H // 2, H // 4
    low = _low_pass(truth, truth_depth, low_h)
    a, b = (
        add_detail(cache, target, low, out_h, DetailConfig(net_height=low_h, sampling=mode))
        for mode in ("bicubic", "bilinear")
    )
    torch.testing.assert_close(a, b)


def test_no_detail_where_no_source_agrees_with_the_network():
    cache, target, _, truth_depth = _scene()
    low_h = H // 2
    grey = torch.full((3, low_h, 2 * low_h), 0.02)  # a colour no source shows anywhere
    low = RenderOutput(
        rgb=grey,
        depth=resize_erp(truth_depth[None], low_h)[0],
        opacity=torch.ones(1, low_h, 2 * low_h),
    )
    out = add_detail(cache, target, low, H, DetailConfig(net_height=low_h))
    up = torch.nn.functional.interpolate(grey[None], size=(H, 2 * H))[0]
    assert (out - up).abs().max() < 0.05


def test_a_cutoff_below_the_networks_rows_replaces_its_soft_band():
    """A volume render is softer than its pixels: here the "network" is the truth at 24 rows
    shown at 48. With the cutoff at 24 rows the sources give the band between 24 and 48 rows
    as well, and the output comes closer to the truth; the low-pass below the cutoff stays the
    network's."""
    cache, target, truth, truth_depth = _scene()
    low_h, soft_h = H // 2, H // 4
    soft = resize_erp(resize_erp(truth[None], soft_h), low_h)[0]
    low = RenderOutput(
        rgb=soft,
        depth=1.0 / resize_erp(1.0 / truth_depth[None], low_h)[0],
        opacity=torch.ones(1, low_h, 2 * low_h),
    )
    plain = add_detail(cache, target, low, H, DetailConfig(net_height=low_h))
    cut = add_detail(cache, target, low, H, DetailConfig(net_height=low_h, cutoff=soft_h))
    assert _psnr(cut, truth) > _psnr(plain, truth) + 1.0
    assert _psnr(resize_erp(cut[None], soft_h)[0], resize_erp(soft[None], soft_h)[0]) > 30


def test_at_the_networks_own_rows_the_cutoff_still_applies():
    """A render at (or below) the network's rows is the plain render without a cutoff; with
    one, the sources' colour replaces its band above the cutoff (its low-pass stays)."""
    from helpers.nets import random_cache

    from panogrf.renderer.detail import render_detailed
    from panogrf.renderer.render import render_panorama

    net, cache = random_cache()
    c2w = cache.c2w[0].clone()
    c2w[0, 3] += 0.5
    plain = render_panorama(net, cache, c2w, 32, "fast")
    same = render_detailed(net, cache, c2w, 32, "fast", DetailConfig(net_height=32))
    cut = render_detailed(net, cache, c2w, 32, "fast", DetailConfig(net_height=32, cutoff=8))
    assert torch.equal(same.rgb, plain.rgb)
    assert (cut.rgb - plain.rgb).abs().max() > 0.05
    assert torch.equal(cut.depth, plain.depth)
    low = [resize_erp(x.rgb[None], 8)[0] for x in (cut, plain)]
    assert (low[0] - low[1]).abs().mean() < 0.25 * (cut.rgb - plain.rgb).abs().mean()


def test_the_sources_are_read_at_their_own_depth_not_the_networks():
    """A render whose expected depth is off (here 25 % too far, as a volume render's mean of
    spread samples is) misplaces the detail when the sources are read at it; the default
    reads them at their own depth maps splatted into the target, which the cache has right."""
    from panogrf.renderer.detail import projection_depth

    cache, target, truth, truth_depth = _scene()
    low_h = H // 2
    low = _low_pass(truth, truth_depth, low_h)
    low = RenderOutput(rgb=low.rgb, depth=low.depth * 1.25, opacity=low.opacity)
    splat = projection_depth(cache, target, low, DetailConfig(net_height=low_h))
    true_low = 1.0 / resize_erp(1.0 / truth_depth[None], low_h)[0]
    assert splat.shape == low.depth.shape
    assert float(((splat - true_low).abs() / true_low).median()) < 0.02
    scores = {
        p: _detail_psnr(cache, target, low, truth, projection=p) for p in ("splat", "network")
    }
    assert scores["splat"] > scores["network"] + 3.0, scores


def test_an_unknown_projection_is_refused():
    import pytest

    cache, target, truth, truth_depth = _scene()
    low = _low_pass(truth, truth_depth, H // 2)
    with pytest.raises(ValueError, match="projection"):
        add_detail(cache, target, low, H, DetailConfig(net_height=H // 2, projection="mesh"))


def test_projection_band_by_band_is_the_same_as_whole(monkeypatch):
    """A panorama beyond `BAND_PIXELS` is projected band of rows by band: the same colours and
    masked fractions to the last bit."""
    from panogrf.renderer import detail

    g = torch.Generator().manual_seed(0)
    v, h = 2, 24
    images = torch.rand(v, 3, h, 2 * h, generator=g)
    c2w = torch.eye(4).repeat(v, 1, 1)
    c2w[1, 0, 3] = 0.5
    depth = 1.0 + torch.rand(v, 1, h, 2 * h, generator=g)
    mask = (torch.rand(v, 1, h, 2 * h, generator=g) > 0.8).float()
    cache = SceneCache(images, c2w, depth, torch.zeros(v, 4, h, 2 * h), 4, mask)
    target = torch.eye(4)
    target[:3, 3] = torch.tensor([0.2, 0.1, -0.1])
    d = 0.8 + torch.rand(h, 2 * h, generator=g)
    whole = detail._projected(cache, target, d, "bicubic")
    monkeypatch.setattr(detail, "BAND_PIXELS", 5 * 2 * h)  # bands of 5 rows, the last of 4
    banded = detail._projected(cache, target, d, "bicubic")
    assert torch.equal(whole[0], banded[0]) and torch.equal(whole[1], banded[1])


def test_at_a_photos_pose_the_view_is_that_photo_even_on_wrong_depth():
    """The nearer photo gives the detail: at its own pose its projection is exact at any
    depth, while the other photo's, read at a depth 30 % off, is displaced."""
    cache, _, _, _ = _scene()
    wrong = SceneCache(cache.images, cache.c2w, cache.depth * 1.3, cache.maps, 1)
    photo = cache.images[0]
    low = _low_pass(photo, wrong.depth[0], H // 2)
    scores = {}
    for power in (0.0, 2.0):
        out = add_detail(
            wrong, cache.c2w[0], low, H, DetailConfig(net_height=H // 2, proximity=power)
        )
        scores[power] = _psnr(out, photo)
    assert scores[2.0] > 40 and scores[2.0] > scores[0.0] + 3, scores


def test_halfway_between_two_photos_both_weigh_the_same():
    cache, _, _, _ = _scene()
    halfway = cache.c2w[0].clone()
    halfway[:3, 3] = cache.c2w[:, :3, 3].mean(0)
    assert torch.allclose(proximity_weights(cache, halfway, 2.0), torch.ones(2))
    near = cache.c2w[0].clone()
    near[:3, 3] += 0.1 * (cache.c2w[1, :3, 3] - cache.c2w[0, :3, 3])  # a tenth of the way
    w = proximity_weights(cache, near, 2.0)
    assert w[0] == 1 and 0.01 < float(w[1]) < 1 / 64  # (1/9)^2 less the 1 cm
