"""Training corruptions: real-camera photometrics and a wrong mono prior."""

from __future__ import annotations

import torch

from panogrf.app.train.augment import corrupt_mono, out_of_domain, photometric


def _images(n=4, h=16, w=32):
    return torch.rand(n, 3, h, w, generator=torch.Generator().manual_seed(0))


def test_photometric_shape_range_and_determinism():
    x = _images()
    a = photometric(x, torch.Generator().manual_seed(1))
    b = photometric(x, torch.Generator().manual_seed(1))
    assert a.shape == x.shape and torch.equal(a, b)
    assert a.min() >= 0 and a.max() <= 1 and torch.isfinite(a).all()
    assert not torch.allclose(a, x, atol=1e-3)  # it does change the images
    assert torch.equal(x, _images())  # and leaves its input alone


def test_photometric_changes_views_differently():
    x = _images(1).expand(8, -1, -1, -1).contiguous()
    out = photometric(x, torch.Generator().manual_seed(2))
    means = out.mean((1, 2, 3))
    assert means.std() > 0.02  # exposure differs from view to view


def test_photometric_strength_zero_is_nearly_identity():
    x = _images()
    out = photometric(x, torch.Generator().manual_seed(3), strength=0.0)
    assert torch.allclose(out, x, atol=1e-4)


def test_corrupt_mono():
    depth = torch.full((64, 1, 8, 16), 2.0)
    gen = torch.Generator().manual_seed(4)
    out = corrupt_mono(depth, gen, p=0.5)
    assert out.shape == depth.shape and (out > 0).all()
    changed = (out != depth).flatten(1).any(1)
    assert 10 < int(changed.sum()) < 54  # about half of the batch
    assert out.max() < 2.0 * 1.4 * 1.5 and out.min() > 2.0 * 0.7 / 1.5
    assert torch.equal(corrupt_mono(depth, gen, p=0.0), depth)


def test_out_of_domain_blends_another_panorama():
    x = torch.zeros(3, 3, 8, 16)
    x[1] = 1.0  # the second panorama white, the others black
    out = out_of_domain(x, torch.Generator().manual_seed(5))
    assert out.shape == x.shape and torch.equal(x[0], torch.zeros(3, 8, 16))  # input untouched
    # Each is blended with the one before it in the batch, at weight 0.35-0.55.
    assert 0.35 <= float(out[2].mean()) <= 0.55  # 2 took white from 1
    assert 0.45 <= float(out[1].mean()) <= 0.65  # 1 took black from 0
    assert torch.equal(out[0], torch.zeros(3, 8, 16))  # 0 took black from 2
    # The partner is turned: a single panorama blended with itself is not itself.
    one = _images(1)
    turned = out_of_domain(one, torch.Generator().manual_seed(6))
    assert not torch.allclose(turned, one, atol=1e-3)
    again = out_of_domain(one, torch.Generator().manual_seed(6))
    assert torch.equal(turned, again)
