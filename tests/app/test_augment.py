"""Training corruptions: real-camera photometrics and a wrong mono prior."""

from __future__ import annotations

import functools
import math

import torch

from panogrf.app.train.augment import (
    corrupt_mono,
    mono_out_of_domain,
    mono_warped_room,
    mono_wrong_heights,
    out_of_domain,
    photometric,
    room_factors,
    room_warp,
    wrong_heights,
)


def _echo_estimator():
    """An estimator whose monocular network reports its input: depth = first channel + 1,
    features = the input doubled."""
    from panogrf.model.mono import MonoOutput

    class Mono(torch.nn.Module):
        def forward(self, images):
            return MonoOutput(images[:, :1] + 1.0, images * 2.0)

    class Estimator:
        mono = Mono()

    return Estimator()


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


def test_wrong_heights_moves_ceiling_and_floor_not_the_walls():
    """Rows looking up are scaled by one factor, rows looking down by another, within
    exp(+-strength); the rows near the horizon keep their depth."""
    h = 64
    depth = torch.rand(6, 1, h, 2 * h, generator=torch.Generator().manual_seed(0)) + 1.0
    out = wrong_heights(depth, torch.Generator().manual_seed(3), strength=0.4)
    again = wrong_heights(depth, torch.Generator().manual_seed(3), strength=0.4)
    assert torch.equal(out, again)
    ratio = torch.log(out / depth)  # [6, 1, h, w]
    lat = 90 - (torch.arange(h) + 0.5) / h * 180
    horizon = lat.abs() < 11
    assert ratio[:, :, horizon].abs().max() < 1e-6
    top, bottom = ratio[:, 0, 0], ratio[:, 0, -1]  # [6, w]: constant along each row
    assert torch.allclose(top, top[:, :1].expand_as(top), atol=1e-6)
    assert top.abs().max() <= 0.4 + 1e-6 and bottom.abs().max() <= 0.4 + 1e-6
    assert top[:, 0].std() > 0.05 and not torch.allclose(top[:, 0], bottom[:, 0])
    # Smooth: no jump between neighbouring rows larger than the ramp allows.
    assert (ratio[:, :, 1:] - ratio[:, :, :-1]).abs().max() < 0.4 * 3 * math.pi / h


def test_mono_wrong_heights_changes_the_depth_not_the_features():
    from panogrf.model.mono import MonoOutput

    class Mono(torch.nn.Module):
        def forward(self, images):
            return MonoOutput(images[:, :1] + 1.0, images)

    class Estimator:
        mono = Mono()

    est, images = Estimator(), _images(2, 32, 64)
    plain = est.mono(images)
    wrong = mono_wrong_heights(torch.Generator().manual_seed(0))(est.mono, images)
    assert torch.equal(wrong.features, plain.features)
    assert not torch.allclose(wrong.depth, plain.depth)
    # Around another stage (a view also out of its domain): both apply.
    inner = functools.partial(mono_wrong_heights(torch.Generator().manual_seed(1)), est.mono)
    twice = mono_wrong_heights(torch.Generator().manual_seed(0))(inner, images)
    assert not torch.allclose(twice.depth, wrong.depth)


def test_mono_wrong_heights_shared_is_one_room_for_every_view_and_call():
    """``shared``: one draw on entry, the same factors for both views and for every call of
    the network (the views agree); per view (the default), the views' factors differ."""
    from panogrf.model.mono import MonoOutput

    class Mono(torch.nn.Module):
        def forward(self, images):
            return MonoOutput(torch.ones_like(images[:, :1]) * 2.0, images)

    class Estimator:
        mono = Mono()

    est, images = Estimator(), _images(2, 32, 64)
    room = mono_wrong_heights(torch.Generator().manual_seed(4), shared=True)
    first, second = room(est.mono, images).depth, room(est.mono, images[:1]).depth
    assert torch.equal(first[0], first[1]) and torch.equal(first[0], second[0])
    assert not torch.allclose(first, torch.full_like(first, 2.0))  # the room did change
    apart = mono_wrong_heights(torch.Generator().manual_seed(4))(est.mono, images).depth
    assert not torch.allclose(apart[0], apart[1])


def _box_room_labels(h: int, up: float, down: float) -> torch.Tensor:
    """[1, 1, h, 2h] which surface a level camera sees in a box room (x in -2..3, z in
    -1.5..2.5 around it; the ceiling ``up`` m above, the floor ``down`` below): 1 ceiling,
    0.5 walls, 0 floor."""
    lat = math.pi * (0.5 - (torch.arange(h, dtype=torch.float64) + 0.5) / h)
    lon = math.pi * (2 * (torch.arange(2 * h, dtype=torch.float64) + 0.5) / (2 * h) - 1)
    dx, dz = torch.cos(lon), torch.sin(lon)
    tx = torch.where(dx > 0, 3.0 / dx.clamp(min=1e-9), 2.0 / (-dx).clamp(min=1e-9))
    tz = torch.where(dz > 0, 2.5 / dz.clamp(min=1e-9), 1.5 / (-dz).clamp(min=1e-9))
    reach = torch.minimum(tx, tz)[None]  # horizontal distance to the walls per column
    tan = torch.tan(lat)[:, None]
    labels = torch.full((h, 2 * h), 0.5, dtype=torch.float64)
    labels[tan * reach > up] = 1.0
    labels[tan * reach < -down] = 0.0
    return labels[None, None].float()


def test_room_warp_shows_the_room_at_other_heights():
    """A box room's panorama warped by factors (1.4 above, 0.75 below the camera) is the
    panorama of the same room with its ceiling 1.4 times as high and its floor 0.75 times as
    low, up to the rows a boundary crosses; the inverse warp takes it back."""
    h = 128
    room = _box_room_labels(h, 1.2, 1.5)
    up, down = torch.tensor([math.log(1.4)]), torch.tensor([math.log(0.75)])
    warped = room_warp(room, up, down)
    other = _box_room_labels(h, 1.2 * 1.4, 1.5 * 0.75)
    assert float(((warped - other).abs() > 0.25).float().mean()) < 0.02
    assert float(((room - other).abs() > 0.25).float().mean()) > 0.08  # the rooms do differ
    back = room_warp(warped, up, down, inverse=True)
    assert float(((back - room).abs() > 0.25).float().mean()) < 0.02
    zero = torch.zeros(1)
    torch.testing.assert_close(room_warp(room, zero, zero), room, atol=1e-4, rtol=0)


def test_mono_warped_room_changes_depth_and_features_the_same_for_both_views():
    """The monocular network sees a room of other heights: what it returns (depth and
    features alike) is read back at the panorama's rows, so a network that reports its input
    returns the input's rows moved; one draw for both views and every call."""
    from panogrf.model.mono import MonoOutput

    est = _echo_estimator()
    room = _box_room_labels(64, 1.2, 1.5).expand(2, 3, -1, -1).contiguous()
    plain = est.mono(room)
    warp = mono_warped_room(torch.Generator().manual_seed(3))
    seen, again = warp(est.mono, room), warp(est.mono, room[:1])
    # A network that returns its input sees the warped room and its output is warped back:
    # the round trip loses only the rows a boundary crosses.
    assert float(((seen.depth - plain.depth).abs() > 0.25).float().mean()) < 0.03
    torch.testing.assert_close(seen.depth[0], seen.depth[1])
    torch.testing.assert_close(seen.depth[0], again.depth[0])

    class Fixed(torch.nn.Module):
        """A network that always sees the same room, whatever it is shown."""

        def forward(self, images):
            labels = _box_room_labels(images.shape[-2], 1.2, 1.5).expand(len(images), 1, -1, -1)
            return MonoOutput(labels + 1.0, labels.expand(-1, 4, -1, -1))

    est.mono = Fixed()
    fixed = est.mono(room)
    moved = mono_warped_room(torch.Generator().manual_seed(3))(est.mono, room)
    # Its answer, read back at the panorama's rows, is a room of other heights: depth and
    # features moved alike.
    changed = (moved.depth - fixed.depth).abs() > 0.25
    assert float(changed.float().mean()) > 0.02
    assert torch.equal(changed[:, 0], ((moved.features - fixed.features).abs() > 0.25)[:, 0])


def test_room_factors_leave_the_rest_of_the_batch_as_it_is():
    up, down = room_factors(torch.Generator().manual_seed(0), 64, p=0.5, strength=0.3)
    hit = (up != 0) | (down != 0)
    assert 10 < int(hit.sum()) < 54
    assert float(up.abs().max()) <= 0.3 and float(down.abs().max()) <= 0.3
    none = room_factors(torch.Generator().manual_seed(0), 8, p=0.0)
    assert not none[0].any() and not none[1].any()
    every = room_factors(torch.Generator().manual_seed(0), 8)
    assert every[0].all() and every[1].all()


def test_mono_out_of_domain_features_only_keeps_the_depth_of_the_view_as_it_is():
    """``features_only``: the features are those of the view blended with the partner (as
    without it), the depth that of the view itself."""
    est = _echo_estimator()
    views, partner = _images(2), _images(2).flip(-1)
    plain = est.mono(views)
    both = mono_out_of_domain(partner, torch.Generator().manual_seed(5))(est.mono, views)
    feats = mono_out_of_domain(partner, torch.Generator().manual_seed(5), features_only=True)(
        est.mono, views
    )
    assert not torch.allclose(both.features, plain.features)
    torch.testing.assert_close(feats.features, both.features)
    torch.testing.assert_close(feats.depth, plain.depth)
    assert not torch.allclose(both.depth, plain.depth)
