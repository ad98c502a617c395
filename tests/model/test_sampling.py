"""Samples along rays and volume compositing: against a plain loop and hand-computed values."""

from __future__ import annotations

import math

import pytest
import torch

from panogrf.model.sampling import (
    LAST_DELTA,
    composite,
    composite_reference,
    guided_samples,
    inverse_depth_samples,
    sample_pdf,
)


def test_inverse_depth_samples_are_sorted_inside_the_range_and_uniform_in_inverse_depth():
    t = inverse_depth_samples(5, 16, 0.5, 15.0)
    assert t.shape == (5, 16)
    assert (t.diff(dim=-1) > 0).all()
    assert t.min() > 0.5 and t.max() < 15.0
    steps = (1.0 / t).diff(dim=-1)
    assert torch.allclose(steps, steps[:, :1].expand_as(steps), atol=1e-5)
    gen = torch.Generator().manual_seed(0)
    j = inverse_depth_samples(1000, 8, 0.5, 15.0, generator=gen)
    assert (j.diff(dim=-1) > 0).all() and j.min() >= 0.5 and j.max() <= 15.0
    # Stratified: each bin's samples average to the bin centre (in inverse depth).
    centres = inverse_depth_samples(1, 8, 0.5, 15.0)[0]
    assert torch.allclose((1 / j).mean(0), 1 / centres, atol=0.02)
    with pytest.raises(ValueError, match="near < far"):
        inverse_depth_samples(1, 4, 2.0, 1.0)


def test_composite_matches_the_plain_loop_on_random_input():
    gen = torch.Generator().manual_seed(1)
    r, s = 7, 12
    t = torch.sort(torch.rand(r, s, generator=gen, dtype=torch.float64) * 10 + 0.5, -1).values
    sigma = torch.rand(r, s, generator=gen, dtype=torch.float64) * 3
    sigma[0] = 0.0  # an empty ray
    rgb = torch.rand(r, s, 3, generator=gen, dtype=torch.float64)
    fast, slow = composite(sigma, rgb, t), composite_reference(sigma, rgb, t)
    for a, b in ((fast.rgb, slow.rgb), (fast.weights, slow.weights), (fast.opacity, slow.opacity)):
        assert torch.allclose(a, b, atol=1e-10)
    assert torch.allclose(fast.depth[1:], slow.depth[1:], atol=1e-8)
    assert fast.opacity[0] == 0 and torch.isfinite(fast.depth).all()


def test_composite_hand_computed_two_samples():
    # sigma 1/m over 1 m then an opaque last sample: alpha_0 = 1 - e^-1, w_1 = e^-1.
    t = torch.tensor([[1.0, 2.0]], dtype=torch.float64)
    sigma = torch.tensor([[1.0, 5.0]], dtype=torch.float64)
    rgb = torch.tensor([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]], dtype=torch.float64)
    out = composite(sigma, rgb, t)
    a0 = 1 - math.exp(-1)
    a1 = 1 - math.exp(-5 * LAST_DELTA)
    assert out.weights[0].tolist() == pytest.approx([a0, (1 - a0) * a1])
    assert out.rgb[0].tolist() == pytest.approx([a0, (1 - a0) * a1, 0.0])
    assert out.depth[0].item() == pytest.approx((a0 * 1 + (1 - a0) * a1 * 2) / (a0 + (1 - a0) * a1))


def test_composite_gradients():
    gen = torch.Generator().manual_seed(2)
    t = torch.sort(torch.rand(3, 5, generator=gen, dtype=torch.float64) * 4 + 0.5, -1).values
    sigma = (torch.rand(3, 5, generator=gen, dtype=torch.float64) + 0.1).requires_grad_()
    rgb = torch.rand(3, 5, 3, generator=gen, dtype=torch.float64).requires_grad_()
    assert torch.autograd.gradcheck(lambda s, c: composite(s, c, t).rgb, (sigma, rgb))


def test_sample_pdf_concentrates_where_the_weight_is():
    t = inverse_depth_samples(2, 32, 0.5, 15.0)
    weights = torch.zeros(2, 32)
    weights[0, 10] = 1.0
    weights[1, 25] = 1.0
    fine = sample_pdf(t, weights, 16)
    assert fine.shape == (2, 16) and (fine.diff(dim=-1) >= 0).all()
    for i, k in ((0, 10), (1, 25)):
        lo, hi = t[i, k - 1], t[i, k + 1]
        assert ((fine[i] > lo) & (fine[i] < hi)).float().mean() > 0.9
    gen = torch.Generator().manual_seed(3)
    jittered = sample_pdf(t, weights, 16, generator=gen)
    assert torch.isfinite(jittered).all()


def test_guided_samples_lie_in_the_bands_around_both_proxies():
    near = torch.tensor([2.0, 3.0])
    far = torch.tensor([2.0, 6.0])
    t = guided_samples(near, far, 8, band=0.1)
    assert t.shape == (2, 8) and (t.diff(dim=-1) >= 0).all()
    ratio = 1.0 / t  # inverse depths
    assert ((ratio[0] * 2.0 - 1).abs() <= 0.11).all()
    lower, upper = ratio[1, :4] * 3.0, ratio[1, 4:] * 6.0
    assert ((lower - 1).abs() <= 0.11).all() and ((upper - 1).abs() <= 0.11).all()
    with pytest.raises(ValueError):
        guided_samples(near, far, 1)
