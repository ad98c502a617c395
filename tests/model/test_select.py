"""The fusion's learned hypothesis choice (`panogrf.model.select`): its input and its output.

Seeded random weights: these tests check shapes, the seam and plumbing, never accuracy."""

from __future__ import annotations

import pytest
import torch

from panogrf.model.select import FEATURES, HypothesisSelector, SelectorConfig, selection_features


def _inputs(h: int = 64, d: int = 24, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    image = torch.rand(3, h, 2 * h, generator=g)
    cost = torch.rand(2, d, h, 2 * h, generator=g)
    log_hyp = torch.rand(2, h, 2 * h, generator=g)
    ends = log_hyp + 0.1 * torch.randn(2, h, 2 * h, generator=g)
    log_mono = torch.rand(h, 2 * h, generator=g)
    conf = torch.rand(2, h, 2 * h, generator=g)
    return image, cost, log_hyp, ends, log_mono, conf, torch.linspace(-0.5, 0.5, d)


def test_features_are_pooled_to_the_selectors_rows():
    feats = selection_features(*_inputs(64), rows=32)
    assert feats.shape == (FEATURES, 32, 64)
    assert torch.isfinite(feats).all()
    # At its own resolution nothing is pooled: the first channels are the costs at the
    # hypotheses' own depth (offset 0) and the best costs.
    image, cost, *rest, offsets = _inputs(32)
    own = selection_features(image, cost, *rest, offsets, rows=32)
    torch.testing.assert_close(own[:2], cost[:, int(torch.argmin(offsets.abs()))])
    torch.testing.assert_close(own[2:4], cost.amin(1))


def test_the_features_turn_with_the_panorama():
    """A turn by whole columns turns every feature with it (the texture channel wraps)."""
    image, cost, log_hyp, ends, log_mono, conf, offsets = _inputs(32)
    turn = lambda x: x.roll(8, -1)  # noqa: E731
    a = selection_features(image, cost, log_hyp, ends, log_mono, conf, offsets, rows=32)
    b = selection_features(
        turn(image), turn(cost), turn(log_hyp), turn(ends), turn(log_mono), turn(conf), offsets, 32
    )
    torch.testing.assert_close(turn(a), b)


@pytest.mark.parametrize("size", [(32, 64), (64, 128)])
def test_the_choice_is_an_index_per_pixel_at_the_sweeps_size(size):
    torch.manual_seed(0)
    net = HypothesisSelector(SelectorConfig(rows=32)).eval()
    feats = selection_features(*_inputs(64), rows=32)
    with torch.no_grad():
        logit = net(feats[None])
        choice = net.choose(feats, size)
    assert logit.shape == (1, 1, 32, 64)
    assert choice.shape == size and choice.dtype == torch.long
    assert set(choice.unique().tolist()) <= {0, 1}
    if size == (32, 64):
        assert torch.equal(choice, (logit[0, 0] > 0).long())
    # Wraps at the seam: a turned input gives the turned logit.
    with torch.no_grad():
        turned = net(feats.roll(16, -1)[None])
    torch.testing.assert_close(turned, logit.roll(16, -1), atol=1e-5, rtol=1e-4)


def test_the_scene_context_reaches_every_pixel_and_turns_with_the_panorama():
    """With the scene-wide summary, a change in one corner of the panorama moves the logit on
    the far side (a local selector's receptive field ends 15 pixels away); a turn still gives
    the turned logit."""
    feats = selection_features(*_inputs(32), rows=32)[None]
    changed = feats.clone()
    changed[..., :4, :4] += 3.0
    for context in (False, True):
        torch.manual_seed(0)
        net = HypothesisSelector(SelectorConfig(rows=32, context=context)).eval()
        with torch.no_grad():
            a, b = net(feats), net(changed)
            turned = net(feats.roll(16, -1))
        far = (a - b)[..., 16:, 32:].abs().max()
        assert (far > 1e-4) if context else (far == 0)
        torch.testing.assert_close(turned, a.roll(16, -1), atol=1e-5, rtol=1e-4)


@pytest.mark.parametrize("bias", [0.0, 0.3, 5.0, -5.0])
def test_unsure_pixels_keep_the_fallbacks_choice(bias):
    """With a constant logit, every pixel is unsure (probability within the margin of one half:
    the fallback's choice) or none is (the selector's)."""
    net = HypothesisSelector(SelectorConfig(rows=32)).eval()
    last = net.net[-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.fill_(bias)
    feats = selection_features(*_inputs(32), rows=32)
    fallback = torch.randint(2, (32, 64), generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        choice = net.choose(feats, (32, 64), fallback, margin=0.1)
        plain = net.choose(feats, (32, 64))
    unsure = abs(torch.sigmoid(torch.tensor(bias)) - 0.5) < 0.1
    assert torch.equal(choice, fallback if unsure else plain)
    assert torch.equal(plain, torch.full((32, 64), int(bias > 0)))


def _sphere_depth(centre: torch.Tensor, radius: float, h: int) -> torch.Tensor:
    """Spherical depth [h, 2h] of a camera at ``centre`` (identity rotation) inside a sphere of
    ``radius`` around the origin: |c + t d| = radius solved for t."""
    from panogrf.model.erp import erp_directions

    d = erp_directions(h, 2 * h)
    b = (d * centre).sum(-1)
    return -b + torch.sqrt(b * b - (centre @ centre - radius**2))


def test_cross_view_consistency_finds_the_end_that_reappears_in_the_other_view():
    """Two views inside a sphere: the true depth's points land on the other view's true depth
    (near zero); a wrong end (30 % too far in one view, 30 % too near in the other) lands on
    neither of the other view's ends; a view whose source has no search ends gets the cap."""
    from panogrf.model.select import CONSISTENCY_CAP, cross_view_consistency

    h = 48
    centres = torch.tensor([[0.0, 0.0, 0.0], [0.8, 0.0, 0.3]])
    c2w = torch.eye(4).repeat(2, 1, 1)
    c2w[:, :3, 3] = centres
    ends = {}
    for v, wrong in enumerate((1.3, 0.7)):
        true = torch.log(_sphere_depth(centres[v], 3.0, h))
        ends[v] = torch.stack((true, true + torch.log(torch.tensor(wrong))))
    out = cross_view_consistency(ends, c2w, [[1], [0]])
    for v in range(2):
        assert out[v].shape == (2, h, 2 * h)
        assert float(out[v][0].median()) < 0.02  # the right end reappears
        assert float(out[v][1].median()) > 0.1  # the wrong one does not
        assert float(out[v].max()) <= CONSISTENCY_CAP
    alone = cross_view_consistency({0: ends[0]}, c2w, [[1], [0]])
    torch.testing.assert_close(alone[0], torch.full_like(ends[0], CONSISTENCY_CAP))


def test_a_selector_without_consistency_reads_only_the_selection_features():
    """Records hold the consistency channels after the features; a selector trained without
    them (round 15's) reads the first `FEATURES` and gives the same logit either way."""
    from panogrf.model.select import CONSISTENCY

    torch.manual_seed(0)
    plain = HypothesisSelector(SelectorConfig(context=True)).eval()
    feats = torch.rand(1, FEATURES + CONSISTENCY, 16, 32)
    torch.testing.assert_close(plain(feats), plain(feats[:, :FEATURES]))
    with_it = HypothesisSelector(SelectorConfig(context=True, consistency=True)).eval()
    assert with_it.net[0].in_channels == FEATURES + CONSISTENCY
    changed = feats.clone()
    changed[:, FEATURES:] += 0.3
    assert not torch.allclose(with_it(feats), with_it(changed))
