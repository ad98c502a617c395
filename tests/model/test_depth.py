"""Depth for every view of a scene (`DepthEstimator`): sizes, modes and degenerate input.

Small randomly initialised networks (seeded): these tests check plumbing, never accuracy.
"""

from __future__ import annotations

import math

import pytest
import torch

from panogrf.model.depth import DepthEstimator
from panogrf.model.erp import rotation_about
from panogrf.model.mono import MonoDepthConfig, MonoDepthNet
from panogrf.model.mvs import PRESETS, MVSNet
from panogrf.model.sweep import SweepConfig

WORKING = 64  # working height of the estimator in these tests (the default is 128)


@pytest.fixture(autouse=True)
def _one_thread():
    # Training jobs share this machine: keep the tests on one core.
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def estimator() -> DepthEstimator:
    torch.manual_seed(0)
    mono = MonoDepthNet(MonoDepthConfig())
    mvs = {name: MVSNet(PRESETS[name]) for name in ("full", "mvs")}
    return DepthEstimator(mono, mvs, working_height=WORKING).eval()


def _images(v: int, h: int, seed: int = 0) -> torch.Tensor:
    return torch.rand(v, 3, h, 2 * h, generator=torch.Generator().manual_seed(seed))


def _poses(*centres: tuple[float, float, float]) -> torch.Tensor:
    c2w = torch.eye(4).repeat(len(centres), 1, 1)
    for i, c in enumerate(centres):
        c2w[i, :3, :3] = rotation_about("y", math.radians(20.0 * i)).float()
        c2w[i, :3, 3] = torch.tensor(c)
    return c2w


def _check_finite(est, v: int, h: int) -> None:
    for t in (est.depth, est.mono, est.out_of_range):
        assert t.shape == (v, 1, h, 2 * h)
    assert est.out_of_range.dtype == torch.bool
    assert bool(torch.isfinite(est.depth).all()) and bool(torch.isfinite(est.mono).all())
    assert float(est.depth.min()) > 0 and float(est.depth.max()) <= 10.0


@pytest.mark.parametrize("h", [64, 96, 50])
@pytest.mark.parametrize("mode", ["mono", "full", "mvs"])
def test_output_at_the_input_size(estimator, mode, h):
    est = estimator(_images(2, h), _poses((0, 0, 0), (1.0, 0, 0)), mode=mode)
    _check_finite(est, 2, h)
    if mode == "mono":
        assert est.sources == [[], []] and est.warnings == []
        torch.testing.assert_close(est.depth, est.mono)
    else:
        assert est.sources == [[1], [0]] and est.warnings == []
        assert not torch.allclose(est.depth, est.mono)  # the MVS network was used


@pytest.mark.parametrize("mode", ["full", "mvs"])
def test_depth_is_the_mvs_networks_output(estimator, mode):
    """At the working size, a view's depth is its MVS output with the other views as sources."""
    images = _images(3, WORKING, seed=1)
    c2w = _poses((0, 0, 0), (0.5, 0, 0), (1.0, 0.1, 0))
    # The network alone, in the world as given.
    est = estimator.configured(sweep=None, canonical=False)(images, c2w, mode=mode)
    assert est.sources == [[1, 2], [0, 2], [0, 1]]
    net = estimator.mvs[mode]
    with torch.no_grad():
        mono = estimator.mono(images[2:3])
        kw = {}
        if net.config.use_mono:
            kw = {"mono_depth": mono.depth, "mono_features": mono.features}
        out = net(images[2:3], images[None, :2], c2w[2:3], c2w[None, :2], **kw)
    torch.testing.assert_close(est.depth[2:3], out.depth, atol=1e-5, rtol=1e-5)


def test_mode_full_sweeps_with_its_own_config(estimator):
    """Mode full's sweep is `fusion_sweep`, mode mvs's is `sweep`: with a fusion sweep of one
    candidate and nothing to fuse, the full depth is the network's, while mode mvs still moves."""
    images = _images(2, WORKING, seed=3)
    c2w = _poses((0, 0, 0), (1.0, 0, 0))
    one = estimator.configured(
        fuse=False, canonical=False, median=1, fusion_sweep=SweepConfig(candidates=1, span=0.0)
    )
    full = one(images, c2w, "full").depth
    unswept = one.configured(sweep=None)
    network = unswept(images, c2w, "full").depth
    mvs_network = unswept(images, c2w, "mvs").depth
    mvs = one(images, c2w, "mvs").depth
    torch.testing.assert_close(full, network)
    assert not torch.allclose(mvs, mvs_network)


def test_one_view_falls_back_to_mono(estimator):
    est = estimator(_images(1, 64), _poses((0, 0, 0)), mode="full")
    _check_finite(est, 1, 64)
    assert est.sources == [[]]
    assert any("one view" in w for w in est.warnings)
    torch.testing.assert_close(est.depth, est.mono)


@pytest.mark.parametrize("mode", ["full", "mvs"])
def test_a_source_at_the_same_position_is_dropped(estimator, mode):
    est = estimator(_images(2, 64), _poses((0, 0, 0), (0.01, 0, 0)), mode=mode)
    _check_finite(est, 2, 64)
    assert est.sources == [[], []]
    assert any("views [1]" in w and "not used" in w for w in est.warnings)
    assert any("view 1: no usable source" in w for w in est.warnings)
    torch.testing.assert_close(est.depth, est.mono)


def test_a_duplicate_position_leaves_only_the_far_source(estimator):
    c2w = _poses((0, 0, 0), (0, 0, 0), (1.0, 0, 0.2))
    est = estimator(_images(3, 64), c2w, mode="full")
    _check_finite(est, 3, 64)
    assert est.sources == [[2], [2], [0, 1]]
    assert any(w.startswith("view 0: views [1]") for w in est.warnings)
    assert any(w.startswith("view 1: views [0]") for w in est.warnings)
    assert not any("no usable source" in w for w in est.warnings)


def test_out_of_range_flags_the_clamped_pixels():
    torch.manual_seed(0)
    mono = MonoDepthNet(MonoDepthConfig())
    est_net = DepthEstimator(mono, {"mvs": MVSNet(PRESETS["mvs"])}, working_height=WORKING).eval()
    images, c2w = _images(2, 64), _poses((0, 0, 0), (1.0, 0, 0))
    # Whatever the depth, the mask is "at the top of the range".
    for mode in ("mono", "mvs"):
        est = est_net(images, c2w, mode=mode)
        torch.testing.assert_close(est.out_of_range, est.depth >= 0.98 * est_net.d_max)
    # A saturated monocular head: every pixel at d_max, all flagged; the opposite, none.
    with torch.no_grad():
        mono.head.bias.fill_(50.0)
    est = est_net(images, c2w, mode="mono")
    assert bool(est.out_of_range.all())
    torch.testing.assert_close(est.depth, torch.full_like(est.depth, 10.0))
    with torch.no_grad():
        mono.head.bias.fill_(-50.0)
    est = est_net(images, c2w, mode="mono")
    assert not bool(est.out_of_range.any())
    assert float(est.depth.min()) >= 0.05  # clamped away from zero, no NaN
    assert bool(torch.isfinite(est.depth).all())


def test_bad_input(estimator):
    images, c2w = _images(2, 64), _poses((0, 0, 0), (1.0, 0, 0))
    with pytest.raises(ValueError, match="mode"):
        estimator(images, c2w, mode="stereo")
    with pytest.raises(ValueError, match="2:1"):
        estimator(torch.rand(2, 3, 64, 64), c2w)
    mono_only = DepthEstimator(estimator.mono, {}, working_height=WORKING).eval()
    with pytest.raises(ValueError, match="no weights"):
        mono_only(images, c2w, mode="full")
    assert mono_only(images, c2w, mode="mono").depth.shape == (2, 1, 64, 128)


def test_settings_are_fixed_at_construction_and_configured_shares_the_networks(estimator):
    """No setting or part is set after construction (training and benchmarks used to, on the
    cached estimator): `configured` gives another estimator of the same networks instead, and
    one configured otherwise is not cached under the weights files' key."""
    for name, value in (("median", 1), ("sweep", None), ("selector", None), ("config", None)):
        with pytest.raises(AttributeError):
            setattr(estimator, name, value)
    assert estimator.median == estimator.config.median == 7
    loaded = DepthEstimator(estimator.mono, dict(estimator.mvs), weight_files=("a",))
    other = loaded.configured(median=1, canonical=False)
    assert other.median == 1 and not other.canonical and loaded.median == 7 and loaded.canonical
    assert other.mono is loaded.mono and other.mvs["full"] is loaded.mvs["full"]
    assert other.training == loaded.training and other.weight_files == ()
    assert loaded.configured().weight_files == ("a",)
    with pytest.raises(TypeError):
        loaded.configured(guide="mvs")  # not a setting


def test_world_scale_is_the_median_ratio_of_mono_to_mvs_where_both_are_in_range(estimator):
    mono = torch.full((2, 1, 4, 8), 3.0)
    mvs = torch.full((2, 1, 4, 8), 2.0)
    mvs[0, 0, 0, :3] = 10.0  # at the top of the range: not counted
    mono[1] = 30.0  # a view without sources: not counted either
    assert estimator._world_scale(mono, mvs, [[1], []]) == pytest.approx(1.5)
    # Clamped to 0.25-4; nothing to measure: 1.
    assert estimator._world_scale(mono, mvs * 0.1, [[1], []]) == pytest.approx(4.0)
    assert estimator._world_scale(mono, mvs, [[], []]) == 1.0


def test_the_canonical_world_makes_the_depth_follow_the_worlds_scale(estimator):
    """Two worlds that differ only in scale s (the same images) land in the same canonical
    world when their scales k differ by 1 / s: the depth of the scaled one is s times the
    other's, whatever the networks do (their weights here are random)."""
    images = _images(2, 64, seed=5)
    c2w = _poses((0, 0, 0), (1.0, 0.1, 0))
    s, k = 0.7, 1.3
    scaled = c2w.clone()
    scaled[:, :3, 3] *= s
    try:
        estimator._world_scale = lambda *args: k
        base = estimator(images, c2w, "full").depth
        estimator._world_scale = lambda *args: k / s
        other = estimator(images, scaled, "full").depth
        plain = estimator.configured(canonical=False)(images, scaled, "full").depth
    finally:
        del estimator._world_scale
    torch.testing.assert_close(other, s * base, rtol=1e-4, atol=1e-5)
    assert not torch.allclose(plain, other, rtol=1e-3)


@pytest.mark.parametrize("mode", ["full", "mvs"])
def test_the_median_follows_the_sweep(estimator, mode):
    """After the sweep the depth goes through `median_filter` (``median``), in the canonical
    world or not: the median of the unfiltered depth, at working resolution."""
    from panogrf.model.sweep import median_filter

    images = _images(2, WORKING, seed=5)
    c2w = _poses((0, 0, 0), (1.0, 0, 0))
    raw = estimator.configured(median=1)(images, c2w, mode).depth
    filtered = estimator.configured(median=7)(images, c2w, mode).depth
    assert estimator.median == 7
    torch.testing.assert_close(filtered, median_filter(raw, 7))
    assert not torch.equal(filtered, raw)


def test_the_selector_chooses_and_the_record_holds_its_input(estimator):
    """Mode full fused: with ``record`` a list, every reference view's selector input and search
    ends are appended (with the world's scale); without a selector the photometric rule still
    chooses (the depth is unchanged); a selector that always says "unguided" changes it."""
    from panogrf.model.select import CONSISTENCY, FEATURES, HypothesisSelector, SelectorConfig

    images = _images(2, WORKING, seed=7)
    c2w = _poses((0, 0, 0), (1.0, 0, 0))
    plain = estimator(images, c2w, "full").depth
    record: list[dict] = []
    recorded = estimator(images, c2w, "full", record=record).depth
    torch.testing.assert_close(recorded, plain)
    assert [e["view"] for e in record] == [0, 1]
    rows = SelectorConfig().rows
    for e in record:
        # The selection features, then the cross-view consistency of both search ends.
        assert e["features"].shape == (FEATURES + CONSISTENCY, rows, 2 * rows)
        assert e["ends"].shape == (2, rows, 2 * rows) and e["rule"].shape == (rows, 2 * rows)
        assert e["scale"] > 0
    unguided = HypothesisSelector().eval()
    torch.nn.init.zeros_(unguided.net[-1].weight)
    torch.nn.init.constant_(unguided.net[-1].bias, 5.0)
    chosen = estimator.configured(selector=unguided)(images, c2w, "full").depth
    assert torch.isfinite(chosen).all()
    assert not torch.allclose(chosen, plain)


def test_the_blend_records_its_input_and_moves_the_depth_towards_mono(estimator):
    """Mode full fused: with ``blend_record`` a list, every reference view's blend input and the
    two depths are appended (the depth unchanged); a blend saturated towards the monocular depth
    returns it, brought to the poses' metric scale (the blend works in the canonical world, see
    ``canonical``); mode mvs never blends."""
    from panogrf.model.blend import FEATURES, BlendConfig, DepthBlend

    images = _images(2, WORKING, seed=9)
    c2w = _poses((0, 0, 0), (1.2, 0, 0.3))
    plain = estimator(images, c2w, "full")
    record: list[dict] = []
    recorded = estimator(images, c2w, "full", blend_record=record).depth
    torch.testing.assert_close(recorded, plain.depth)
    assert [e["view"] for e in record] == [0, 1]
    for e in record:
        assert e["features"].shape == (FEATURES, WORKING, 2 * WORKING)
        assert bool(torch.isfinite(e["features"]).all())
        assert e["logs"].shape == (2, WORKING, 2 * WORKING) and e["scale"] > 0
    blend = DepthBlend(BlendConfig(channels=8, rows=WORKING)).eval()
    torch.nn.init.zeros_(blend.net[-1].weight)
    torch.nn.init.constant_(blend.net[-1].bias, 30.0)
    blended = estimator.configured(blend=blend)
    towards_mono = blended(images, c2w, "full")
    mvs = blended(images, c2w, "mvs").depth
    _check_finite(towards_mono, 2, WORKING)
    metric_mono = (plain.mono / record[0]["scale"]).clamp(0.05, estimator.d_max)
    torch.testing.assert_close(towards_mono.depth, metric_mono, atol=1e-3, rtol=1e-3)
    torch.testing.assert_close(mvs, estimator(images, c2w, "mvs").depth)


def _on_a_line(*xs: float) -> torch.Tensor:
    c2w = torch.eye(4).repeat(len(xs), 1, 1)
    c2w[:, 0, 3] = torch.tensor(xs)
    return c2w


def test_the_far_source_is_compared_only_where_the_near_one_gives_little_parallax():
    from panogrf.model.depth_config import DepthConfig, compared_sources

    every = [[1, 2], [0, 2], [0, 1]]
    wide = _on_a_line(0.0, 2.0, 4.0)  # a tour's spacing: the outer views keep the middle one
    assert compared_sources(DepthConfig(), wide, every) == [[1], [0, 2], [1]]
    narrow = _on_a_line(0.0, 0.4, 0.8)  # the far photo's doubled baseline is kept
    assert compared_sources(DepthConfig(), narrow, every) == [[1, 2], [0, 2], [1, 0]]
    # The threshold is in metres: 1.6 m apart in a world of 4 units a metre is narrow.
    scaled = compared_sources(DepthConfig(), _on_a_line(0.0, 1.6, 3.2), every, scale=4.0)
    assert scaled == [[1, 2], [0, 2], [1, 0]]
    assert compared_sources(DepthConfig(far_from=math.inf), wide, every) == [
        [1, 2],
        [0, 2],
        [1, 0],
    ]
    assert compared_sources(DepthConfig(sweep_sources=1, far_from=math.inf), wide, every) == [
        [1],
        [0],  # a tie: the first of the equally near
        [1],
    ]


def test_each_view_reads_its_nearest_sources_and_three_photos_keep_every_source():
    from panogrf.model.depth_config import view_sources

    line = _on_a_line(0.0, 1.0, 3.0, 3.5, 8.0)
    every, _ = view_sources(line, 0.05)
    assert every[0] == [1, 2, 3, 4]
    nearest, warnings = view_sources(line, 0.05, count=2)
    assert nearest == [[1, 2], [0, 2], [1, 3], [1, 2], [2, 3]] and warnings == []
    # Three photos: each view has two others, so a count of 2 changes nothing.
    three = _on_a_line(0.0, 2.0, 4.0)
    assert view_sources(three, 0.05, count=2) == view_sources(three, 0.05)
    # Too close to give parallax: left out before the nearest are counted.
    close, warnings = view_sources(_on_a_line(0.0, 0.01, 1.0, 2.0), 0.05, count=2)
    assert close[0] == [2, 3] and "not used as sources" in warnings[0]


def test_an_estimator_reading_two_sources_estimates_three_photos_as_before(estimator):
    images, c2w = _images(3, 64), _poses((0, 0, 0), (0.5, 0, 0), (1.0, 0.1, 0))
    before = estimator(images, c2w, "full")
    after = estimator.configured(mvs_sources=2)(images, c2w, "full")
    torch.testing.assert_close(after.depth, before.depth, rtol=0, atol=0)


def test_mono_stages_wrap_the_monocular_network_for_one_call_only(estimator):
    """Training perturbations are a call's argument: each stage gets the network (or the stage
    inside it) and the images; the next call without them is as before."""
    from panogrf.model.mono import MonoOutput

    images, c2w = _images(2, 64), _poses((0, 0, 0), (0.5, 0, 0))
    plain = estimator(images, c2w, "mono")
    seen: list[int] = []

    def halved(forward, small):
        out = forward(small)
        seen.append(len(small))
        return MonoOutput(out.depth * 0.5, out.features)

    def doubled(forward, small):  # around `halved`: both apply, the outer one last
        out = forward(small)
        seen.append(-len(small))
        return MonoOutput(out.depth * 2.0, out.features)

    once = estimator(images, c2w, "mono", mono_stages=[halved])
    torch.testing.assert_close(once.depth, (plain.depth * 0.5).clamp(0.05, estimator.d_max))
    both = estimator(images, c2w, "mono", mono_stages=[halved, doubled])
    torch.testing.assert_close(both.depth, plain.depth)
    assert seen == [2, 2, -2]
    assert torch.equal(estimator(images, c2w, "mono").depth, plain.depth)
