"""360-degree MVS: mono-guided candidates, the cost volume's geometry and the network's shapes.

The geometry test matches raw RGB (identity features) on the bundled demo scene with ground
truth depth: the cost minimum has to sit at the true depth's candidate with the right poses
and must not with a wrong one, so it cannot pass by luck.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from scipy.stats import norm

from panogrf.app.scene.folder import load_scene
from panogrf.app.train.data import downsample_depth
from panogrf.assets import path as asset_path
from panogrf.model.erp import direction_to_pixel, erp_directions, invert_rigid, rotation_about
from panogrf.model.mvs import (
    PRESETS,
    MVSConfig,
    MVSNet,
    cost_volume,
    depth_candidates,
    mono_offsets,
)
from panogrf.model.warp import backward_warp

F64 = torch.float64


@pytest.fixture(autouse=True)
def _one_thread():
    # Training jobs share this machine: keep the tests on one core.
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _gen(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _pose(x: float = 0.0, y: float = 0.0, z: float = 0.0, yaw_deg: float = 0.0) -> torch.Tensor:
    c2w = torch.eye(4)
    c2w[:3, :3] = rotation_about("y", math.radians(yaw_deg)).float()
    c2w[:3, 3] = torch.tensor([x, y, z])
    return c2w


# --- mono-guided offsets ---------------------------------------------------------------------


def test_mono_offsets_paper_values():
    b = mono_offsets(5, 3.0)
    assert b.dtype == F64 and b.shape == (5,)
    expected = torch.tensor([-1.9194, -0.5457, 0.0, 0.5457, 1.9194], dtype=F64)
    torch.testing.assert_close(b, expected, atol=1e-4, rtol=0)


@pytest.mark.parametrize("n", [2, 3, 5, 8])
@pytest.mark.parametrize("beta", [1.5, 3.0])
def test_mono_offsets_symmetric_and_increasing(n, beta):
    b = mono_offsets(n, beta)
    torch.testing.assert_close(b, -b.flip(0), atol=1e-12, rtol=0)
    assert bool((b[1:] > b[:-1]).all())
    assert bool((b.abs() < beta).all())


@pytest.mark.parametrize("n", [3, 5, 7])
@pytest.mark.parametrize("beta", [2.0, 3.0])
def test_mono_offsets_equal_mass_bins(n, beta):
    """Each bin [e_k, e_k+1] around b_k holds P*/n of the standard normal (scipy, not erfinv)."""
    b = mono_offsets(n, beta).numpy()
    p_star = norm.cdf(beta) - norm.cdf(-beta)
    # Bin edges: the probits of the equal-mass cut points, from scipy's ppf.
    edges = norm.ppf(norm.cdf(-beta) + p_star * np.arange(n + 1) / n)
    np.testing.assert_allclose(edges[[0, -1]], [-beta, beta], atol=1e-9)
    np.testing.assert_allclose(np.diff(norm.cdf(edges)), p_star / n, atol=1e-12)
    # b_k is the mid-point of its bin's edges, so it lies inside the bin.
    np.testing.assert_allclose(b, 0.5 * (edges[:-1] + edges[1:]), atol=1e-9)
    assert np.all((edges[:-1] < b) & (b < edges[1:]))


def test_mono_offsets_degenerate_counts():
    assert mono_offsets(0).shape == (0,)
    torch.testing.assert_close(mono_offsets(1, 3.0), torch.zeros(1, dtype=F64))
    assert mono_offsets(5, 3.0, dtype=torch.float32).dtype == torch.float32


# --- depth candidates ------------------------------------------------------------------------


def _mu(b: int = 2, h: int = 4, w: int = 8, seed: int = 0) -> torch.Tensor:
    # Includes depths near both ends of the range, so that clamping happens.
    mu = 0.05 + 10.5 * torch.rand(b, 1, h, w, generator=_gen(seed))
    mu[0, 0, 0, 0], mu[0, 0, 0, 1] = 0.2, 9.9
    return mu


def test_depth_candidates_shape_and_order():
    cfg = MVSConfig()
    mu = _mu()
    c = depth_candidates(mu, cfg)
    assert c.shape == (2, cfg.n_mono + cfg.n_uni, 4, 8)
    assert bool((c[:, 1:] >= c[:, :-1]).all())
    assert float(c.min()) >= cfg.d_min and float(c.max()) <= cfg.d_max


def test_depth_candidates_hold_the_uniform_grid_and_the_mono_offsets():
    cfg = MVSConfig()
    mu = _mu()
    c = depth_candidates(mu, cfg)
    uni = torch.linspace(cfg.d_min, cfg.d_max, cfg.n_uni)
    b = mono_offsets(cfg.n_mono, cfg.beta).float()
    for bi, y, x in [(0, 0, 0), (0, 0, 1), (0, 2, 5), (1, 3, 7)]:
        px = c[bi, :, y, x]
        mono = (mu[bi, 0, y, x] + b * cfg.sigma).clamp(cfg.d_min, cfg.d_max)
        expected = torch.sort(torch.cat((uni, mono))).values
        torch.testing.assert_close(px, expected, atol=0, rtol=0)
        # Every uniform candidate is present exactly (not recomputed with rounding).
        assert all(bool((px == u).any()) for u in uni)


def test_depth_candidates_uniform_only():
    cfg = PRESETS["mvs"]
    c = depth_candidates(None, cfg, (3, 6))
    assert c.shape == (1, 64, 3, 6)
    torch.testing.assert_close(c[0, :, 2, 4], torch.linspace(0.1, 10.0, 64), atol=0, rtol=0)
    # mu is ignored for the batch of a uniform-only config: it sets the batch and dtype.
    c2 = depth_candidates(torch.ones(2, 1, 3, 6, dtype=F64), cfg)
    assert c2.shape == (2, 64, 3, 6) and c2.dtype == F64


def test_depth_candidates_follow_the_requested_dtype():
    c = depth_candidates(None, PRESETS["mvs"], (2, 4), dtype=F64)
    assert c.dtype == F64


def test_depth_candidates_errors():
    with pytest.raises(ValueError, match="mono"):
        depth_candidates(None, MVSConfig(), (4, 8))
    with pytest.raises(ValueError, match="size"):
        depth_candidates(None, PRESETS["mvs"])


# --- cost volume geometry on the demo scene ---------------------------------------------------

FACTOR = 4  # 256 x 512 -> 64 x 128


@pytest.fixture(scope="module")
def demo():
    """Demo scene at 64 x 128: images [3, 3, h, w], GT depth [3, 1, h, w] (0 = unknown), c2w."""
    s = load_scene(asset_path("demo"), load_images=True).images
    images = F.interpolate(s.images, scale_factor=1 / FACTOR, mode="area")
    # Block means over the same 4 x 4 blocks as the area-downsampled pixels: same centres.
    depths = [downsample_depth(d.numpy(), FACTOR) for d in s.depths[:, 0]]
    depths = torch.from_numpy(np.stack(depths))[:, None]
    return images, depths, s.c2w.float()


def _gradient_magnitude(image: torch.Tensor) -> torch.Tensor:
    """Central-difference gradient magnitude of the grey image, [1, 3, h, w] -> [h, w]."""
    g = image.mean(1)[0]
    gx = (g.roll(-1, -1) - g.roll(1, -1)) / 2  # wraps across the seam
    gy = torch.zeros_like(g)
    gy[1:-1] = (g[2:] - g[:-2]) / 2
    return torch.sqrt(gx * gx + gy * gy)


def _parallax_per_step(depth: torch.Tensor, rel: torch.Tensor, step: float) -> torch.Tensor:
    """How far (source pixels) a point moves when its reference depth grows by ``step``: [h, w].

    rel: reference camera -> source camera [4, 4]. Near the epipoles and far away a candidate
    step moves the point by a fraction of a pixel: there no matcher can tell candidates apart.
    """
    h, w = depth.shape
    dirs = erp_directions(h, w)

    def project(d):
        p = d[..., None] * dirs
        return direction_to_pixel(p @ rel[:3, :3].T + rel[:3, 3], h, w)

    du = project(depth + step) - project(depth)
    du[..., 0] = torch.remainder(du[..., 0] + w / 2, w) - w / 2
    return du.norm(dim=-1)


def _box3(cost: torch.Tensor) -> torch.Tensor:
    """3 x 3 mean of a cost [1, D, h, w] (wraps in width): a matching window for raw pixels."""
    padded = F.pad(cost, (1, 1, 0, 0), mode="circular")
    return F.avg_pool2d(padded, 3, stride=1, padding=(1, 0), count_include_pad=False)


def _wrong_poses(c2w: torch.Tensor, ref: int, src: int) -> dict[str, torch.Tensor]:
    """The source pose moved 0.5 m sideways (horizontal, across the baseline) or yawed 10 deg."""
    baseline = c2w[src, :3, 3] - c2w[ref, :3, 3]
    side = torch.linalg.cross(baseline, torch.tensor([0.0, 1.0, 0.0]))
    moved = c2w[src].clone()
    moved[:3, 3] += 0.5 * side / side.norm()
    turned = c2w[src].clone()
    turned[:3, :3] = rotation_about("y", math.radians(10.0)).float() @ turned[:3, :3]
    return {"moved 0.5 m": moved, "yawed 10 deg": turned}


def _hit_rate(demo, ref, src, src_pose, candidates, mask, window):
    """Share of masked pixels whose cost argmin is within one candidate of the GT candidate."""
    images, depths, c2w = demo
    volume = cost_volume(
        images[ref : ref + 1],
        images[src : src + 1, None],
        c2w[ref : ref + 1],
        src_pose[None, None],
        candidates,
        torch.ones(1, 1),
    )
    cost = volume.sum(1)  # [1, D, h, w]
    if window:
        cost = _box3(cost)
    best = cost.argmin(1)[0]
    truth = (candidates - depths[ref : ref + 1]).abs().argmin(1)[0]
    return float(((best - truth).abs() <= 1)[mask].float().mean())


def _matchable(demo, ref, src):
    """Textured pixels with GT in (0.1, 10) m, visible in the source, with parallax."""
    images, depths, c2w = demo
    gt = depths[ref : ref + 1]
    _, visible = backward_warp(
        images[src : src + 1], c2w[src : src + 1], depths[src : src + 1], c2w[ref : ref + 1], gt
    )
    rel = invert_rigid(c2w[src]) @ c2w[ref]
    step = (10.0 - 0.1) / 63
    parallax = _parallax_per_step(gt[0, 0].clamp(min=0.2), rel, step)
    textured = _gradient_magnitude(images[ref : ref + 1]) > 0.02
    inside = (gt[0, 0] > 0.1) & (gt[0, 0] < 10.0)
    return textured & inside & visible[0, 0] & (parallax >= 0.5)


# Measured (pair (0, 2) / (2, 0), 1.0 m apart; 831 / 733 pixels): uniform candidates, 3x3
# window 0.976 / 0.967, single pixel 0.659 / 0.618; mono-guided (mu = GT + N(0, 0.2 m)),
# window 0.761 / 0.827. Wrong source pose, window: moved 0.088 / 0.146, yawed 0.406 / 0.420
# (uniform); moved 0.070 / 0.080, yawed 0.220 / 0.312 (mono-guided).
@pytest.mark.parametrize("ref, src", [(0, 2), (2, 0)])
def test_cost_minimum_at_the_true_depth_uniform(demo, ref, src):
    images, depths, c2w = demo
    mask = _matchable(demo, ref, src)
    assert int(mask.sum()) > 500
    cands = depth_candidates(None, PRESETS["mvs"], images.shape[-2:])
    right = _hit_rate(demo, ref, src, c2w[src], cands, mask, window=True)
    single = _hit_rate(demo, ref, src, c2w[src], cands, mask, window=False)
    assert right >= 0.9
    assert single >= 0.55  # one RGB pixel is an ambiguous descriptor, still far above chance
    for name, pose in _wrong_poses(c2w, ref, src).items():
        wrong = _hit_rate(demo, ref, src, pose, cands, mask, window=True)
        assert wrong <= 0.5 * right, f"{name}: {wrong:.3f} vs {right:.3f} with the true pose"


@pytest.mark.parametrize("ref, src", [(0, 2), (2, 0)])
def test_cost_minimum_at_the_true_depth_mono_guided(demo, ref, src):
    images, depths, c2w = demo
    mask = _matchable(demo, ref, src)
    gt = depths[ref : ref + 1]
    noise = 0.2 * torch.randn(gt.shape, generator=_gen(ref))
    mu = torch.where(gt > 0, gt + noise, torch.full_like(gt, 3.0)).clamp(0.1, 10.0)
    cands = depth_candidates(mu, MVSConfig())
    right = _hit_rate(demo, ref, src, c2w[src], cands, mask, window=True)
    assert right >= 0.7
    for name, pose in _wrong_poses(c2w, ref, src).items():
        wrong = _hit_rate(demo, ref, src, pose, cands, mask, window=True)
        assert wrong <= 0.5 * right, f"{name}: {wrong:.3f} vs {right:.3f} with the true pose"


def test_cost_volume_slice_equals_a_backward_warp_at_that_depth(demo):
    """Candidate k's cost is |warp(src, constant depth) - ref|: an independent warping path."""
    images, _, c2w = demo
    ref, src = images[0:1], images[2:3]
    cands = torch.tensor([0.7, 2.0, 5.5]).view(1, 3, 1, 1).expand(1, 3, 64, 128)
    volume = cost_volume(ref, src[:, None], c2w[0:1], c2w[2:3, None], cands, torch.ones(1, 1))
    assert volume.shape == (1, 3, 3, 64, 128)
    for k in range(3):
        warped, _ = backward_warp(src, c2w[2:3], None, c2w[0:1], cands[:, k : k + 1])
        torch.testing.assert_close(volume[:, :, k], (warped - ref).abs(), atol=1e-4, rtol=0)


# --- cost volume: groups and sources ----------------------------------------------------------


def _random_volume_inputs(s: int = 2, c: int = 8, h: int = 8, w: int = 16, seed: int = 0):
    g = _gen(seed)
    ref = torch.rand(2, c, h, w, generator=g)
    src = torch.rand(2, s, c, h, w, generator=g)
    ref_c2w = torch.stack([_pose(0.1, 0.0, 0.2, 5.0), _pose(-0.3, 0.1, 0.0, -20.0)])
    src_c2w = torch.stack([_pose(0.5 * (j + 1), 0.05, -0.2, 10.0 * j) for j in range(s)])
    src_c2w = src_c2w[None].expand(2, -1, -1, -1)
    cands = depth_candidates(None, MVSConfig(n_mono=0, n_uni=6), (h, w)).expand(2, -1, -1, -1)
    return ref, src, ref_c2w, src_c2w, cands


@pytest.mark.parametrize("groups", [1, 2, 4])
def test_cost_volume_groups_are_channel_means(groups):
    ref, src, ref_c2w, src_c2w, cands = _random_volume_inputs()
    weight = torch.ones(2, 2)
    full = cost_volume(ref, src, ref_c2w, src_c2w, cands, weight)
    grouped = cost_volume(ref, src, ref_c2w, src_c2w, cands, weight, groups)
    assert full.shape == (2, 8, 6, 8, 16) and grouped.shape == (2, groups, 6, 8, 16)
    expected = full.reshape(2, groups, 8 // groups, 6, 8, 16).mean(2)
    torch.testing.assert_close(grouped, expected, atol=1e-6, rtol=1e-6)
    assert bool((full >= 0).all())


def test_cost_volume_zero_weight_removes_a_source():
    ref, src, ref_c2w, src_c2w, cands = _random_volume_inputs()
    both = cost_volume(ref, src, ref_c2w, src_c2w, cands, torch.tensor([[1.0, 0.0], [0.0, 1.0]]))
    first = cost_volume(ref, src[:, :1], ref_c2w, src_c2w[:, :1], cands, torch.ones(2, 1))
    second = cost_volume(ref, src[:, 1:], ref_c2w, src_c2w[:, 1:], cands, torch.ones(2, 1))
    torch.testing.assert_close(both[0], first[0], atol=1e-6, rtol=0)
    torch.testing.assert_close(both[1], second[1], atol=1e-6, rtol=0)
    # With both sources the volume is their mean.
    mean = cost_volume(ref, src, ref_c2w, src_c2w, cands, torch.ones(2, 2))
    torch.testing.assert_close(mean, 0.5 * (first + second), atol=1e-6, rtol=0)


def test_cost_volume_two_identical_sources_average_to_one():
    ref, src, ref_c2w, src_c2w, cands = _random_volume_inputs(s=1)
    one = cost_volume(ref, src, ref_c2w, src_c2w, cands, torch.ones(2, 1), 4)
    twice = cost_volume(
        ref,
        src.repeat(1, 2, 1, 1, 1),
        ref_c2w,
        src_c2w.repeat(1, 2, 1, 1),
        cands,
        torch.ones(2, 2),
        4,
    )
    torch.testing.assert_close(twice, one, atol=1e-6, rtol=0)


# --- MVSNet -----------------------------------------------------------------------------------

H, W = 64, 128


def _net_inputs(preset: str, b: int, s: int, seed: int = 0):
    g = _gen(seed)
    ref = torch.rand(b, 3, H, W, generator=g)
    src = torch.rand(b, s, 3, H, W, generator=g)
    ref_c2w = _pose()[None].expand(b, -1, -1)
    src_c2w = torch.stack([_pose(0.5 * (j + 1), 0.0, 0.1 * j, 15.0 * j) for j in range(s)])
    src_c2w = src_c2w[None].expand(b, -1, -1, -1)
    kw = {}
    if PRESETS[preset].use_mono:
        cm = PRESETS[preset].mono_feature_channels
        kw = {
            "mono_depth": 0.5 + 5.0 * torch.rand(b, 1, H, W, generator=g),
            "mono_features": torch.randn(b, cm, H // 2, W // 2, generator=g),
        }
    return (ref, src, ref_c2w, src_c2w), kw


@pytest.mark.parametrize("preset", ["full", "mvs"])
@pytest.mark.parametrize("b, s", [(1, 1), (2, 2)])
def test_mvsnet_shapes_and_range(preset, b, s):
    torch.manual_seed(0)
    cfg = PRESETS[preset]
    net = MVSNet(cfg).eval()
    args, kw = _net_inputs(preset, b, s)
    with torch.no_grad():
        out = net(*args, **kw)
    d = cfg.num_candidates
    assert out.depth.shape == (b, 1, H, W) and out.expected.shape == (b, 1, H, W)
    assert out.probability.shape == (b, d, H // 4, W // 4)
    assert out.candidates.shape == (b, d, H // 4, W // 4)
    for t in (out.depth, out.expected, out.probability):
        assert bool(torch.isfinite(t).all())
    assert float(out.depth.min()) >= cfg.d_min and float(out.depth.max()) <= cfg.d_max
    assert float(out.expected.min()) >= cfg.d_min - 1e-5
    assert float(out.expected.max()) <= cfg.d_max + 1e-5
    torch.testing.assert_close(out.probability.sum(1), torch.ones(b, H // 4, W // 4))


def test_mvsnet_source_weight_zero_equals_dropping_the_source():
    torch.manual_seed(0)
    net = MVSNet(PRESETS["mvs"]).eval()
    (ref, src, ref_c2w, src_c2w), _ = _net_inputs("mvs", 1, 2)
    with torch.no_grad():
        both = net(ref, src, ref_c2w, src_c2w, src_weight=torch.tensor([[1.0, 0.0]]))
        first = net(ref, src[:, :1], ref_c2w, src_c2w[:, :1])
    torch.testing.assert_close(both.depth, first.depth, atol=1e-5, rtol=1e-5)


def test_mvsnet_full_preset_needs_mono_input():
    net = MVSNet(PRESETS["full"]).eval()
    args, kw = _net_inputs("full", 1, 1)
    with pytest.raises(ValueError, match="monocular"):
        net(*args)
    with pytest.raises(ValueError, match="monocular"):
        net(*args, mono_depth=kw["mono_depth"])


def test_mvsnet_candidates_follow_the_input_dtype():
    torch.manual_seed(0)
    net = MVSNet(PRESETS["mvs"]).double().eval()
    args, _ = _net_inputs("mvs", 1, 1)
    with torch.no_grad():
        out = net(*(a.double() for a in args))
    assert out.candidates.dtype == F64 and out.depth.dtype == F64


@pytest.mark.parametrize("preset", ["full", "mvs"])
def test_mvsnet_gradients_reach_the_regularizer(preset):
    torch.manual_seed(0)
    net = MVSNet(PRESETS[preset]).train()
    args, kw = _net_inputs(preset, 1, 1)
    out = net(*args, **kw)
    loss = out.depth.mean() + out.expected.mean()
    loss.backward()
    params = list(net.regularizer.parameters())
    assert params and all(p.grad is not None for p in params)
    assert all(bool(torch.isfinite(p.grad).all()) for p in net.parameters() if p.grad is not None)
    assert any(float(p.grad.abs().sum()) > 0 for p in params)
    assert net.feat_half[0][0].weight.grad is not None  # through the cost volume to the features


@pytest.mark.gpu
def test_mvsnet_runs_on_cuda():
    if not torch.cuda.is_available():
        pytest.skip("needs CUDA")
    net = MVSNet(PRESETS["mvs"]).cuda().eval()
    args, _ = _net_inputs("mvs", 1, 1)
    with torch.no_grad():
        out = net(*(a.cuda() for a in args))
    assert out.depth.is_cuda and bool(torch.isfinite(out.depth).all())


def test_a_zero_trunk_projection_leaves_the_mvs_as_it_was():
    """`MVSConfig.trunk`: frozen pretrained features added to the matching features through
    zero-initialised projections; wired in (a non-zero projection changes the depth)."""
    from dataclasses import replace

    torch.manual_seed(0)
    plain = MVSNet(PRESETS["mvs"]).eval()
    with_trunk = MVSNet(replace(PRESETS["mvs"], trunk=2)).eval()
    missing, unexpected = with_trunk.load_state_dict(plain.state_dict(), strict=False)
    assert not unexpected and all(k.startswith(("trunk.", "from_trunk.")) for k in missing)
    ref, src = torch.rand(1, 3, 64, 128), torch.rand(1, 1, 3, 64, 128)
    ref_c2w, src_c2w = torch.eye(4)[None], torch.eye(4)[None, None].clone()
    src_c2w[..., 0, 3] = 1.0
    assert torch.equal(
        plain(ref, src, ref_c2w, src_c2w).depth, with_trunk(ref, src, ref_c2w, src_c2w).depth
    )
    torch.nn.init.normal_(with_trunk.from_trunk[1].weight, std=0.5)
    out = with_trunk(ref, src, ref_c2w, src_c2w).depth
    assert not torch.allclose(plain(ref, src, ref_c2w, src_c2w).depth, out)
    assert all(not p.requires_grad for p in with_trunk.trunk.parameters())
