"""Exposure balance across source panoramas."""

from __future__ import annotations

import torch

from panogrf.model.photometric import balance_exposure, exposure_gains


def _scene(v=3, h=32, w=64):
    gen = torch.Generator().manual_seed(0)
    base = torch.rand(1, 3, h, w, generator=gen) * 0.8 + 0.1
    return base.expand(v, -1, -1, -1).contiguous()


def _expose(img, linear_gain):
    return ((img**2.2) * linear_gain).clamp(0, 1) ** (1 / 2.2)


def test_consistent_views_are_left_alone():
    x = _scene()
    out, gains = balance_exposure(x)
    assert torch.equal(out, x) and torch.equal(gains, torch.ones(3, 3))


def test_small_differences_inside_the_deadband_stay():
    x = _scene()
    x[0] = _expose(x[0], 1.15)
    assert torch.equal(exposure_gains(x), torch.ones(3, 3))


def test_a_dark_view_is_brightened_towards_the_others():
    x = _scene()
    dark = x.clone()
    dark[0] = _expose(x[0], 0.25)  # two stops under
    out, gains = balance_exposure(dark)
    assert gains[0].min() > 1.2 and (gains[1:] < 1).all()
    before = (dark[0] - dark[1]).abs().mean()
    after = (out[0] - out[1]).abs().mean()
    assert after < 0.5 * before


def test_one_view_and_blank_views():
    one = _scene(1)
    assert torch.equal(balance_exposure(one)[0], one)
    black = torch.zeros(2, 3, 16, 32)
    out, gains = balance_exposure(black)
    assert torch.isfinite(gains).all() and torch.equal(out, black)
