"""The blend of the fused depth with the monocular depth (`panogrf.model.blend`): its inputs and
its output's range. Randomly initialised networks: plumbing and geometry, never accuracy."""

from __future__ import annotations

import math

import pytest
import torch

from panogrf.model.blend import (
    FEATURES,
    PARALLAX_CAP,
    BlendConfig,
    DepthBlend,
    blend_features,
    parallax,
)
from panogrf.model.erp import erp_directions


def _two_cameras(baseline: float) -> torch.Tensor:
    c2w = torch.eye(4).repeat(2, 1, 1)
    c2w[1, 0, 3] = baseline
    return c2w


def test_parallax_is_the_angle_between_the_two_rays_and_vanishes_along_the_baseline():
    """Cameras 1 m apart on x, every pixel at 2 m from the first: a point seen at right angles
    to the baseline makes atan(1 / 2) between the rays; the points on the baseline's line
    (towards either epipole) make none; nearer points make more."""
    h = 32
    dirs = erp_directions(h, 2 * h)
    log_d = torch.full((h, 2 * h), math.log(2.0))
    angle = parallax(log_d, _two_cameras(1.0), 0, [1])
    assert angle.shape == (h, 2 * h)
    across = dirs[..., 0].abs() < 0.02  # perpendicular to x
    expected = min(math.atan(1 / 2), PARALLAX_CAP)
    torch.testing.assert_close(
        angle[across], torch.full_like(angle[across], expected), atol=0.03, rtol=0
    )
    along = dirs[..., 0].abs() > 0.995
    assert float(angle[along].max()) < 0.1  # rays within 0.1 rad of the baseline
    nearer = parallax(log_d - math.log(2.0), _two_cameras(1.0), 0, [1])
    assert bool((nearer >= angle - 1e-5).all())
    assert float(nearer.max()) == pytest.approx(PARALLAX_CAP)


def test_features_are_pooled_to_the_blends_rows_and_wrap_with_the_panorama():
    gen = torch.Generator().manual_seed(0)
    h = 32
    image = torch.rand(3, 2 * h, 4 * h, generator=gen)
    cost = torch.rand(2, 2 * h, 4 * h, generator=gen)
    log_f, log_m = torch.rand(2, h, 2 * h, generator=gen)
    cons = torch.rand(2, h, 2 * h, generator=gen) * 0.5
    par = torch.rand(h, 2 * h, generator=gen) * 0.5
    feats = blend_features(image, cost, log_f, log_m, cons, par, rows=16)
    assert feats.shape == (FEATURES, 16, 32) and bool(torch.isfinite(feats).all())
    # Turning the panorama by a multiple of the pooling turns the features with it.
    k = 8
    turned = blend_features(
        image.roll(2 * k, -1),
        cost.roll(2 * k, -1),
        log_f.roll(k, -1),
        log_m.roll(k, -1),
        cons.roll(k, -1),
        par.roll(k, -1),
        rows=16,
    )
    torch.testing.assert_close(turned, feats.roll(k // 2, -1), atol=1e-5, rtol=1e-5)


def test_the_blend_lies_between_the_two_depths_and_starts_near_the_fused_one():
    gen = torch.Generator().manual_seed(1)
    net = DepthBlend(BlendConfig(channels=8, rows=16)).eval()
    feats = torch.randn(2, FEATURES, 16, 32, generator=gen)
    log_f = torch.randn(2, 32, 64, generator=gen) * 0.3 + 1.0
    log_m = torch.randn(2, 32, 64, generator=gen) * 0.3 + 1.0
    with torch.no_grad():
        out = net.blend(feats, log_f, log_m)
    assert out.shape == log_f.shape
    lo, hi = torch.minimum(log_f, log_m), torch.maximum(log_f, log_m)
    assert bool(((out >= lo - 1e-6) & (out <= hi + 1e-6)).all())
    # Untrained, the monocular depth's weight is small everywhere (sigmoid(-3) + noise).
    weight = (out - log_f) / (log_m - log_f).where((log_m - log_f).abs() > 0.05, torch.ones(()))
    far = (log_m - log_f).abs() > 0.05
    assert float(weight[far].median()) < 0.2
    # Saturated towards the monocular depth, it returns it.
    torch.nn.init.zeros_(net.net[-1].weight)
    torch.nn.init.constant_(net.net[-1].bias, 30.0)
    with torch.no_grad():
        torch.testing.assert_close(net.blend(feats, log_f, log_m), log_m)
