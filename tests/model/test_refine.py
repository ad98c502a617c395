"""The photometric sweep and the gradient refinement of depth, on an analytic scene: two cameras
inside a textured sphere, whose depth is known exactly."""

from __future__ import annotations

import math

import pytest
import torch
from helpers.photometric import plain_photometric, pool

from panogrf.model.depth_warp import warp_from
from panogrf.model.erp import erp_directions
from panogrf.model.refine import (
    RefineConfig,
    free_space_violation,
    refine_depth,
)
from panogrf.model.ssim import box_mean, photometric_error, reference_stats
from panogrf.model.sweep import SweepConfig, median_filter, sweep_depth

RADIUS = 3.0


def _texture(p: torch.Tensor) -> torch.Tensor:
    """A smooth, detailed colour pattern of world points [..., 3] -> [..., 3] in [0, 1]."""
    x, y, z = p.unbind(-1)
    a = torch.sin(7 * x + 3 * y) * torch.cos(5 * z - 2 * x)
    b = torch.sin(11 * y + 4 * z) * torch.sin(6 * x)
    c = torch.cos(9 * z + 5 * y + 3 * x)
    return 0.5 + 0.45 * torch.stack((a, b, c), -1).clamp(-1, 1)


def _camera(centre, h):
    """Image [3, h, 2h] and true spherical depth [1, h, 2h] of a camera at ``centre``."""
    d = erp_directions(h, 2 * h, dtype=torch.float64)
    o = torch.tensor(centre, dtype=torch.float64)
    # |o + t d| = R: t^2 + 2 t (o.d) + |o|^2 - R^2 = 0, the positive root.
    b = (d * o).sum(-1)
    t = -b + torch.sqrt(b * b - (o * o).sum() + RADIUS**2)
    colour = _texture(o + t[..., None] * d)
    return colour.permute(2, 0, 1).float(), t[None].float()


@pytest.fixture(scope="module")
def scene():
    torch.set_num_threads(1)
    h = 64
    centres = [(0.0, 0.0, 0.0), (0.8, 0.1, 0.0)]
    imgs, depths = zip(*(_camera(c, h) for c in centres), strict=True)
    c2w = torch.eye(4).repeat(2, 1, 1)
    for i, c in enumerate(centres):
        c2w[i, :3, 3] = torch.tensor(c)
    return torch.stack(imgs), c2w, torch.stack(depths)


def test_true_depth_warps_exactly(scene):
    images, c2w, depth = scene
    dirs = erp_directions(64, 128)
    warped = warp_from(images[1:2], depth[0, 0], c2w[0], c2w[1], dirs)
    err = photometric_error(warped, images[0:1])
    wrong = photometric_error(
        warp_from(images[1:2], 1.3 * depth[0, 0], c2w[0], c2w[1], dirs), images[0:1]
    )
    assert err.mean() < 0.5 * wrong.mean()


@pytest.mark.parametrize("factor", [1.25, 0.8])
def test_sweep_recovers_a_wrong_depth(scene, factor):
    images, c2w, depth = scene
    small = torch.nn.functional.interpolate(depth, size=(32, 64), mode="area")
    wrong = small * factor
    out = sweep_depth(images, c2w, wrong, [[1], [0]], SweepConfig(height=64, window=5))
    assert out.shape == wrong.shape and torch.isfinite(out).all()
    before = (wrong - small).abs().mean()
    after = (out - small).abs().mean()
    assert after < 0.35 * before


def test_sweep_keeps_the_network_depth_where_nothing_is_seen(scene):
    images, c2w, depth = scene
    flat = torch.full_like(images, 0.5)  # no texture: no evidence
    small = torch.nn.functional.interpolate(depth, size=(32, 64), mode="area")
    out = sweep_depth(flat, c2w, small * 1.2, [[1], [0]], SweepConfig(height=64))
    torch.testing.assert_close(out, small * 1.2)


def test_fusion_keeps_the_hypothesis_the_sources_agree_with(scene):
    """A prior far off (3x, beyond the sweep's span) is replaced by a second hypothesis that
    matches; a wrong second hypothesis does not replace a right first one."""
    images, c2w, depth = scene
    small = torch.nn.functional.interpolate(depth, size=(32, 64), mode="area")
    cfg = SweepConfig(height=64, window=5)
    alone = sweep_depth(images, c2w, small * 3.0, [[1], [0]], cfg)
    fused = sweep_depth(images, c2w, small * 3.0, [[1], [0]], cfg, others=(small * 1.05,))
    assert (fused - small).abs().mean() < 0.2 * (alone - small).abs().mean()
    kept = sweep_depth(images, c2w, small, [[1], [0]], cfg, others=(small * 3.0,))
    assert (kept - small).abs().mean() < 0.02 * small.mean()


def test_fusion_on_a_blank_scene_keeps_the_first_hypothesis(scene):
    images, c2w, depth = scene
    flat = torch.full_like(images, 0.5)
    small = torch.nn.functional.interpolate(depth, size=(32, 64), mode="area")
    out = sweep_depth(flat, c2w, small, [[1], [0]], SweepConfig(height=64), others=(small * 2,))
    torch.testing.assert_close(out, small)


@pytest.mark.parametrize("span", [0.15, 0.0])
def test_a_short_search_moves_no_pixel_beyond_its_span(scene, span):
    """A prior 25 % too far on a sphere, where the sources say so everywhere: a search of
    +-``span`` in log depth (one candidate for 0: no search) moves the depth towards the truth
    by at most that span and a half step."""
    images, c2w, depth = scene
    small = torch.nn.functional.interpolate(depth, size=(32, 64), mode="area")
    cfg = SweepConfig(height=64, window=5, candidates=7 if span else 1, span=span)
    out = sweep_depth(images, c2w, small * 1.25, [[1], [0]], cfg)
    moved = torch.log(out / (small * 1.25))
    assert float(moved.abs().max()) <= span * (1 + 1 / 6) + 1e-5
    if span:
        assert float(moved.mean()) < -0.8 * span  # most of the way to the end of its range
    else:
        torch.testing.assert_close(out, small * 1.25)


def test_no_sources_no_change(scene):
    images, c2w, depth = scene
    small = torch.nn.functional.interpolate(depth, size=(32, 64), mode="area")
    torch.testing.assert_close(sweep_depth(images, c2w, small, [[], []]), small)
    torch.testing.assert_close(refine_depth(images, c2w, small, [[], []]), small)


def test_gradient_refinement_reduces_the_error(scene):
    images, c2w, depth = scene
    small = torch.nn.functional.interpolate(depth, size=(32, 64), mode="area")
    wrong = small * 1.1
    out = refine_depth(images, c2w, wrong, [[1], [0]], RefineConfig(iterations=40, height=64))
    assert (out - small).abs().mean() < (wrong - small).abs().mean()
    assert math.isfinite(float(out.sum()))


@pytest.mark.parametrize(
    "config",
    [
        RefineConfig(iterations=0, coarse=40, height=128),  # compared at 64 rows
        RefineConfig(iterations=0, fine=40, height=32),  # compared at 64 rows
    ],
    ids=["coarse", "fine"],
)
def test_a_coarse_or_fine_stage_alone_also_reduces_the_error(scene, config):
    images, c2w, depth = scene
    small = torch.nn.functional.interpolate(depth, size=(32, 64), mode="area")
    wrong = small * 1.1
    out = refine_depth(images, c2w, wrong, [[1], [0]], config)
    assert (out - small).abs().mean() < 0.5 * (wrong - small).abs().mean()


def test_the_fine_stage_works_at_no_more_than_the_images_rows(scene):
    """Twice the rows of the images: compared at the images' own rows, as many steps."""
    images, c2w, depth = scene
    wrong = torch.nn.functional.interpolate(depth, size=(32, 64), mode="area") * 1.1
    rows = images.shape[-2]
    capped = RefineConfig(iterations=0, fine=40, height=rows)
    again = RefineConfig(iterations=40, height=rows)
    torch.testing.assert_close(
        refine_depth(images, c2w, wrong, [[1], [0]], capped),
        refine_depth(images, c2w, wrong, [[1], [0]], again),
    )


def test_the_true_depths_do_not_contradict_each_other(scene):
    _, c2w, depth = scene
    assert float(free_space_violation(torch.log(depth), c2w, [[1], [0]])) < 1e-3


@pytest.mark.parametrize("factor", [0.8, 1.25])
def test_one_view_wrong_either_way_is_a_violation(scene, factor):
    """Too near: its points lie in front of the other view's surface. Too far: the other
    view's points lie in front of it. Both are seen, whichever view reads."""
    _, c2w, depth = scene
    log_d = torch.log(depth).clone()
    log_d[0] += math.log(factor)
    violation = float(free_space_violation(log_d, c2w, [[1], [0]]))
    assert violation > 0.5 * abs(math.log(factor)) / 2 - 0.02
    # Only the pairs asked for are checked: view 1 reading view 0 sees nothing when 0 is too far.
    alone = float(free_space_violation(log_d, c2w, [[], [0]]))
    assert (alone > 0.05) == (factor > 1)


def test_a_view_without_sources_keeps_its_depth_with_free_space_on(scene):
    """View 1 is view 0's source but has none of its own: only view 0 moves."""
    images, c2w, depth = scene
    wrong = torch.nn.functional.interpolate(depth, size=(32, 64), mode="area") * 1.1
    config = RefineConfig(iterations=10, height=64, free_space=1.0)
    out = refine_depth(images, c2w, wrong, [[1], []], config)
    torch.testing.assert_close(out[1], wrong[1])
    assert not torch.equal(out[0], wrong[0])


@pytest.mark.parametrize("shrink", [1, 2])
def test_free_space_brings_the_views_together_where_the_photometry_is_blank(scene, shrink):
    """On a blank sphere the photometric term says nothing and the views keep their depths;
    with the free-space term they come to agree, the wrong view moving towards the truth. It
    cannot tell which view was right, so the right one gives ground too."""
    images, c2w, depth = scene
    blank = torch.full_like(images, 0.5)
    small = torch.nn.functional.interpolate(depth, size=(32, 64), mode="area")
    wrong = small.clone()
    wrong[0] *= 1.2
    off = refine_depth(blank, c2w, wrong, [[1], [0]], RefineConfig(iterations=40, height=64))
    torch.testing.assert_close(off, wrong, atol=1e-3, rtol=1e-3)
    config = RefineConfig(iterations=40, height=64, free_space=1.0, free_space_shrink=shrink)
    out = refine_depth(blank, c2w, wrong, [[1], [0]], config)
    error = (wrong[0] - small[0]).abs().mean()
    assert (out[0] - small[0]).abs().mean() < 0.8 * error
    before = free_space_violation(torch.log(wrong), c2w, [[1], [0]])
    after = free_space_violation(torch.log(out), c2w, [[1], [0]])
    assert after < 0.5 * before


def test_fast_window_means_match_average_pooling():
    """The separable slice sums of `photometric_error` and `box_mean` against
    ``F.avg_pool2d`` on the same seam-wrapped, pole-repeated padding."""
    gen = torch.Generator().manual_seed(0)
    a = torch.rand(2, 3, 24, 48, generator=gen)
    b = (a + 0.2 * torch.rand(1, 3, 24, 48, generator=gen)).clamp(0, 1)
    want = plain_photometric(a, b)
    torch.testing.assert_close(photometric_error(a, b), want, atol=1e-5, rtol=0)
    torch.testing.assert_close(box_mean(a, 7), pool(a, 7), atol=1e-6, rtol=0)


def test_warp_matches_the_world_round_trip(scene):
    """The combined rotation of `warp_from` against going through world coordinates, with
    turned cameras."""
    images, c2w, depth = scene
    turned = c2w.clone()
    for i, angle in enumerate((0.4, -1.1)):
        c, s = math.cos(angle), math.sin(angle)
        turned[i, :3, :3] = torch.tensor([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    dirs = erp_directions(64, 128)
    pts = depth[0, 0][..., None] * dirs
    world = pts @ turned[0, :3, :3].T + turned[0, :3, 3]
    cam = (world - turned[1, :3, 3]) @ turned[1, :3, :3]
    from panogrf.model.erp import direction_to_pixel, sample_erp

    uv = direction_to_pixel(cam.reshape(1, -1, 3), 64, 128)
    want = sample_erp(images[1:2], uv).reshape(1, 3, 64, 128)
    got = warp_from(images[1:2], depth[0, 0], turned[0], turned[1], dirs)
    torch.testing.assert_close(got, want, atol=1e-4, rtol=0)


def test_the_median_takes_out_speckle_and_keeps_steps():
    """Single wrong pixels vanish, also across the seam; a step between two surfaces stays
    where it is with nothing in between; window 1 changes nothing."""
    depth = torch.full((1, 1, 32, 64), 3.0)
    depth[..., 20:44] = 1.0  # a near box, columns 20-43
    noisy = depth.clone()
    noisy[0, 0, 10, 0] = 9.0  # on the seam
    noisy[0, 0, 16, 30] = 0.2  # on the box
    noisy[0, 0, 5, 50] = 7.0
    out = median_filter(noisy, 5)
    torch.testing.assert_close(out, depth)
    assert torch.equal(median_filter(noisy, 1), noisy)
    # The seam is like any other column: turning the panorama turns the result.
    x = torch.rand(2, 1, 16, 32, generator=torch.Generator().manual_seed(0))
    turned = median_filter(torch.roll(x, 5, -1), 5)
    assert torch.equal(turned, torch.roll(median_filter(x, 5), 5, -1))


def test_a_chooser_overrides_the_photometric_choice(scene):
    """``chooser`` decides each pixel's hypothesis: always the second gives the search from the
    second alone; it is handed the cost curves [K, D, H, W], the hypotheses and the search ends
    [K, H, W] and the offsets; `photometric_choice` is the rule it replaces."""
    from panogrf.model.sweep import photometric_choice

    images, c2w, depth = scene
    small = torch.nn.functional.interpolate(depth, size=(32, 64), mode="area")
    cfg = SweepConfig(height=64, window=5)
    seen = []

    def second(r, cost, log_hyp, ends, offsets):
        seen.append((cost.shape, log_hyp.shape, ends.shape, offsets.shape))
        return torch.ones(cost.shape[-2:], dtype=torch.long)

    fused = sweep_depth(images, c2w, small, [[1], [0]], cfg, others=(small * 2.0,), chooser=second)
    alone = sweep_depth(images, c2w, small * 2.0, [[1], [0]], cfg)  # within the depth range
    torch.testing.assert_close(fused, alone)
    assert seen[0] == ((2, 24, 64, 128), (2, 64, 128), (2, 64, 128), (24,))

    def rule(r, cost, log_hyp, ends, offsets):
        return photometric_choice(cost, offsets)

    ruled = sweep_depth(images, c2w, small, [[1], [0]], cfg, others=(small * 3.0,), chooser=rule)
    plain = sweep_depth(images, c2w, small, [[1], [0]], cfg, others=(small * 3.0,))
    torch.testing.assert_close(ruled, plain)


def test_photometric_choice_keeps_the_first_on_ties_and_within_the_gain():
    from panogrf.model.sweep import photometric_choice

    offsets = torch.linspace(-0.5, 0.5, 5)
    cost = torch.zeros(2, 5, 1, 3)
    cost[1, 2, 0, 1] = -0.05  # the second clearly better at its own depth
    cost[1, 2, 0, 2] = -0.01  # better, but within a gain of 0.02
    assert photometric_choice(cost, offsets).tolist() == [[0, 1, 1]]
    assert photometric_choice(cost, offsets, switch_gain=0.02).tolist() == [[0, 1, 0]]


def test_the_steps_run_each_once_and_stop_when_told():
    from panogrf.model.steps import OptimisationSteps

    x = torch.zeros(3, requires_grad=True)
    opt = torch.optim.SGD([x], lr=0.25)
    calls, advanced = [], []

    def step():
        calls.append(1)
        (x - 1).square().sum().backward()  # gradients start from None every step
        opt.step()

    assert OptimisationSteps(step, opt, graph=False).run(4, None, lambda: advanced.append(1))
    assert len(calls) == len(advanced) == 4
    # Each step halves the distance to 1 (a gradient accumulated over steps would overshoot).
    torch.testing.assert_close(x.detach(), torch.full((3,), 1 - 0.5**4))
    stop_after = iter([False, False, True])
    assert not OptimisationSteps(step, opt, graph=False).run(5, lambda: next(stop_after), list)
    assert len(calls) == 6


PREP = RefineConfig(smooth=1.0, coarse=10, iterations=10, free_space=1.0, free_space_shrink=2)


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_graphs_give_the_launches_refinement(scene, monkeypatch):
    """The steps replayed from CUDA graphs do the arithmetic of the steps launched one
    operation at a time: they differ from them no more than two launched runs differ from each
    other (a GPU's resampling gradients add up in any order); a stop is heard between
    replays."""
    from panogrf.model import refine

    images, c2w, depth = (t.cuda() for t in scene)
    wrong = torch.nn.functional.interpolate(depth, size=(32, 64), mode="area") * 1.1
    config = PREP
    graphs = refine_depth(images, c2w, wrong, [[1], [0]], config)
    monkeypatch.setattr(refine, "CUDA_GRAPHS", False)
    launches = [refine_depth(images, c2w, wrong, [[1], [0]], config) for _ in range(2)]
    assert graphs is not None and launches[0] is not None and launches[1] is not None
    assert graphs.is_cuda
    between = float((launches[0] - launches[1]).abs().mean())
    assert float((graphs - launches[0]).abs().mean()) <= 3 * between + 1e-4
    assert float((graphs - wrong).abs().mean()) > 1e-3  # it moved
    monkeypatch.setattr(refine, "CUDA_GRAPHS", True)
    asked = []
    stop = lambda: asked.append(1) or len(asked) > 8  # noqa: E731  (inside the first graph)
    assert refine_depth(images, c2w, wrong, [[1], [0]], PREP, should_stop=stop) is None
    assert len(asked) == 9


def test_the_sweep_scores_its_candidates_alike_one_at_a_time_and_all_at_once(scene):
    """The GPU's batched sweep (`GPU_BATCH`) does the CPU's arithmetic, candidate by candidate,
    here run on the CPU."""
    from panogrf.model import sweep

    images, c2w, depth = scene
    offsets = torch.linspace(-0.3, 0.3, 24)
    dirs = erp_directions(64, 128)
    args = (images, c2w, 0, [1], torch.log(depth[0, 0] * 1.05), offsets, dirs, SweepConfig())
    one = sweep._sweep_costs(*args, (0.1, 10.0))
    batched = sweep._sweep_costs(*args, (0.1, 10.0), batched=True)
    assert one.shape == batched.shape == (24, 64, 128)
    torch.testing.assert_close(batched, one, rtol=0, atol=1e-6)


def test_a_reference_compared_many_times_gives_the_same_error_from_its_windows_once():
    g = torch.Generator().manual_seed(3)
    a, b = torch.rand(4, 3, 16, 32, generator=g), torch.rand(1, 3, 16, 32, generator=g)
    stats = reference_stats(b)
    assert torch.equal(photometric_error(a, b, stats), photometric_error(a, b))
    assert torch.equal(photometric_error(b, b, stats), torch.zeros(1, 16, 32))


@pytest.mark.parametrize("eps", [1e-8, 3e-3])
def test_the_plain_adam_steps_as_torchs_adam_to_the_last_bit(eps):
    from panogrf.model.steps import PlainAdam

    g = torch.Generator().manual_seed(5)
    start = torch.randn(3, 1, 8, 16, generator=g)
    targets = [torch.randn(3, 1, 8, 16, generator=g) for _ in range(6)]
    results = []
    for make in (
        lambda p: torch.optim.Adam([p], lr=0.02, eps=eps),
        lambda p: PlainAdam([p], 0.02, eps=eps),
    ):
        p = start.clone().requires_grad_(True)
        opt = make(p)
        for i, target in enumerate(targets):
            opt.param_groups[0]["lr"] = 0.02 * (1 - i / 6)  # a settling rate, as the steps set it
            opt.zero_grad(set_to_none=True)
            ((p - target).abs().mean() + 0.3 * (p * p).mean()).backward()
            opt.step()
        results.append(p.detach())
    assert torch.equal(results[0], results[1])


def test_the_damping_keeps_pixels_with_almost_no_gradient_still():
    """Adam moves a pixel by about the rate however small its gradient; damped, a pixel whose
    gradient is far under the damping barely moves, one far over it as before."""
    from panogrf.model.steps import adam

    pull = torch.tensor([1.0, 1e-7])  # a strong and a nearly flat slope
    moved = {}
    for eps in (1e-8, 1e-4):
        p = torch.zeros(2, requires_grad=True)
        opt = adam([p], 0.02, eps)
        for _ in range(5):
            opt.zero_grad()
            (pull * p).sum().backward()
            opt.step()
        moved[eps] = p.detach().abs()
    assert moved[1e-8][1] > 0.09 and moved[1e-4][1] < 1e-3  # 5 steps of 0.02 undamped
    torch.testing.assert_close(moved[1e-4][0], moved[1e-8][0], rtol=1e-3, atol=0)
    with pytest.raises(ValueError, match="damping"):
        RefineConfig(damping=-1.0)
