"""The capture rig at the nadir: detected per source, masked, never painted into another view.

The bundled demo scene (no rig of its own) gets a dark tripod painted at the nadir of its two
outer sources (`helpers.rig`); its middle view is rendered from them with the shipped renderer
and the true depth. Where the painted rig lands in that view (the view's surface points that
project into a source's rig), a render with the masks must match the render of the clean
sources, and one without them must not (it paints the tripod onto the floor).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from helpers.rig import DARK, paint_rig, rig_mask

from panogrf.app.errors import UserError
from panogrf.app.scene.folder import load_scene
from panogrf.assets import path as asset_path
from panogrf.model.erp import erp_directions, sample_erp, world_to_erp
from panogrf.renderer import nadir
from panogrf.renderer.nadir import (
    cap_mask,
    detect_nadir,
    fill_floor_depth,
    inpaint_masked,
    mask_factor,
    nadir_masks,
    nadir_setting,
    parse_nadir,
)

SOURCES = [0, 2]


@pytest.fixture(scope="module")
def demo():
    return load_scene(asset_path("demo"), load_images=True).images


def where_rig_lands(data, mask: torch.Tensor, height: int) -> torch.Tensor:
    """[H, 2H] bool: the middle view's pixels whose true surface point projects into the rig
    ``mask`` [h, w] of a source."""
    depth = F.interpolate(data.depths[1:2], size=(height, 2 * height), mode="nearest")[0, 0]
    c2w = data.c2w[1].double()
    dirs = erp_directions(height, 2 * height, dtype=torch.float64) @ c2w[:3, :3].T
    points = (c2w[:3, 3] + dirs * depth.double()[..., None]).reshape(1, -1, 3)
    hit = torch.zeros(height, 2 * height, dtype=torch.bool)
    for k in SOURCES:
        uv, _ = world_to_erp(points, data.c2w[k].double(), *mask.shape)
        m = sample_erp(mask[None, None].double(), uv, "nearest")[0, 0]
        hit |= m.reshape(height, 2 * height) > 0.5
    return hit


# --- the detector and the settings -----------------------------------------------------------


def test_detector_finds_a_painted_rig_and_leaves_plain_floors_alone(demo):
    for k in range(3):
        plain, how, _ = detect_nadir(demo.images[k])
        assert how == "none" and not plain.any()  # the demo's floor: patterned, no rig
    rigged, mask = paint_rig(demo.images)
    for k in range(3):
        found, how, radius = detect_nadir(rigged[k])
        assert how == "detected" and 15.0 <= radius <= 25.0
        assert found[0][mask].all()  # all of the rig, plus a margin
        outside = found[0] & ~cap_mask(*mask.shape, radius + 1.0)[0]
        assert not outside.any()  # nothing far from the nadir


def test_detector_ignores_a_smoothly_varying_and_a_noisy_floor():
    from helpers import room

    gen = torch.Generator().manual_seed(0)
    for pos in ([0.0, 0.0, 0.0], [0.7, 0.2, -0.5], [-1.5, -0.5, 1.0]):
        image, _ = room.render(room.pose(torch.eye(3, dtype=room.F64), pos), True, 128, 256)
        image = image[0].float()
        assert detect_nadir(image)[1] == "none"
        noisy = (image + 0.05 * torch.randn(image.shape, generator=gen)).clamp(0, 1)
        assert detect_nadir(noisy)[1] == "none"
        rigged, mask = paint_rig(image[None])
        found, how, _ = detect_nadir(rigged[0])
        assert how == "detected" and found[0][mask].all()


def test_a_nadir_unlike_the_whole_ring_falls_back_to_the_cap(demo):
    image = demo.images[0].clone()
    image[:, cap_mask(256, 512, 33.0)[0]] = torch.tensor(DARK).view(3, 1)
    found, how, radius = detect_nadir(image)
    assert how == "fallback" and radius == nadir.FALLBACK_DEG
    assert torch.equal(found, cap_mask(256, 512, nadir.FALLBACK_DEG))


def test_settings_from_the_command_line_and_the_scene():
    assert parse_nadir(None) is None and parse_nadir("off") is None and parse_nadir(0) is None
    assert parse_nadir("auto") == "auto" and parse_nadir("12.5") == 12.5 and parse_nadir(20) == 20.0
    for bad in ("deep", -1, 90, float("nan"), True):
        with pytest.raises(ValueError):
            parse_nadir(bad)
    assert nadir_setting({}) == "auto"  # the default: detection
    assert nadir_setting({"nadir_mask_deg": 18}) == 18.0
    assert nadir_setting({"nadir_mask_deg": 18}, "off") is None  # the flag wins
    with pytest.raises(UserError, match="nadir_mask_deg"):
        nadir_setting({"nadir_mask_deg": "lots"})
    with pytest.raises(UserError, match="--nadir-cap"):
        nadir_setting({}, "-3")
    masks, notes = nadir_masks(torch.rand(2, 3, 32, 64), 20.0)
    assert masks.shape == (2, 1, 32, 64) and notes == ["cap 20", "cap 20"]
    assert torch.equal(masks[0, 0, :, 0], torch.arange(32) >= 28)  # rows within 20 deg
    assert nadir_masks(torch.rand(2, 3, 32, 64), None) == (None, ["off", "off"])


def test_mask_factor_drops_masked_samples_only_where_another_source_sees_the_point():
    masked = torch.tensor([[1.0, 1.0, 0.0, 0.5], [0.0, 1.0, 0.0, 0.0]])
    f = mask_factor(masked)
    assert torch.allclose(f, torch.tensor([[0.0, 1.0, 1.0, 0.5], [1.0, 1.0, 1.0, 1.0]]))


def test_inpainting_fills_the_rig_with_the_floor_and_floor_depth_replaces_its_depth(demo):
    rigged, mask = paint_rig(demo.images)
    masks, _ = nadir_masks(rigged, "auto")
    filled = inpaint_masked(rigged, masks)
    for k in range(3):  # only the mask changes
        assert torch.equal(filled[k][:, ~masks[k, 0]], rigged[k][:, ~masks[k, 0]])
    floor = demo.images[:, :, mask].mean(-1)  # the clean floor where the rig was
    assert (filled[:, :, mask].mean(-1) - floor).abs().max() < 0.08
    assert (rigged[:, :, mask].mean(-1) - floor).abs().max() > 0.25
    # The true depth with the rig's pixels wrong (as a network would see a tripod: near).
    true = F.interpolate(demo.depths, size=(64, 128), mode="nearest")
    small = F.interpolate(masks.float(), size=(64, 128), mode="area") > 0
    wrong = torch.where(small, torch.full_like(true, 0.4), true)
    fixed = fill_floor_depth(wrong, masks)
    assert ((fixed - true).abs() / true)[small].max() < 0.03
    assert torch.equal(fixed[~small], true[~small])


# --- the renderers ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def models():
    from panogrf.app.scene.session import default_models

    return default_models()


_RENDERS: dict = {}


def _render(data, models, images, setting, quality, height, name):
    """The middle view [3, H, 2H] from the outer sources ``images`` (``name``: what they are,
    for the memo: each render is made once per module) with the true depth."""
    from panogrf.renderer.methods import SourceViews, render_view

    key = (name, setting, quality, height)
    if key not in _RENDERS:
        views = SourceViews(images[SOURCES], data.c2w[SOURCES], nadir=setting)
        views.depth["full"] = F.interpolate(data.depths[SOURCES], size=(128, 256), mode="nearest")
        _RENDERS[key] = render_view("panogrf", views, data.c2w[1], height, models, quality), views
    return _RENDERS[key]


@pytest.mark.slow
@pytest.mark.parametrize(("quality", "height"), [("fast", 64), ("paper", 24)])
def test_neural_render_does_not_paint_a_masked_rig_onto_the_floor(demo, models, quality, height):
    rigged, mask = paint_rig(demo.images)
    lands = where_rig_lands(demo, mask, height)
    assert lands.sum() > 20
    clean, _ = _render(demo, models, demo.images, None, quality, height, "clean")
    painted, _ = _render(demo, models, rigged, None, quality, height, "rig")
    masked, views = _render(demo, models, rigged, "auto", quality, height, "rig")
    assert views.nadir_mask is not None and views.nadir_mask.shape == (2, 1, 256, 512)
    assert views.nadir_notes[0].startswith("detected")
    assert (painted - clean)[:, lands].abs().mean() > 0.08  # without masks: the tripod
    assert (masked - clean)[:, lands].abs().mean() < 0.01
    assert (masked - clean)[:, ~lands].abs().mean() < 0.003  # and nothing else changes
    dark = torch.tensor(DARK).view(3, 1)
    assert (masked[:, lands] - dark).abs().mean() > 0.25


@pytest.mark.slow
def test_where_every_source_is_masked_the_floor_comes_from_around_it(demo, models):
    """A 40-degree cap masks the middle view's whole floor patch under it in both sources:
    the renderer keeps their inpainted floor there, not the tripod."""
    rigged, _ = paint_rig(demo.images, hub_deg=20.0, leg_deg=30.0)
    clean, _ = _render(demo, models, demo.images, None, "fast", 64, "clean")
    painted, _ = _render(demo, models, rigged, None, "fast", 64, "big rig")
    masked, views = _render(demo, models, rigged, 40.0, "fast", 64, "big rig")
    assert views.nadir_notes == ["cap 40", "cap 40"]
    nadir_rows = slice(58, 64)  # the middle view's floor under it
    err_masked = (masked - clean)[:, nadir_rows].abs().mean()
    err_painted = (painted - clean)[:, nadir_rows].abs().mean()
    assert err_painted > 0.15 and err_masked < min(0.08, 0.35 * err_painted)


@pytest.mark.gl
def test_preview_does_not_draw_a_masked_rig(demo):
    from panogrf.renderer.gl_preview import PreviewRenderer, create_headless_context

    rigged, mask = paint_rig(demo.images)
    masks, _ = nadir_masks(rigged[SOURCES], "auto")
    filled = inpaint_masked(rigged[SOURCES], masks)
    depth = F.interpolate(demo.depths[SOURCES], size=(128, 256), mode="nearest")[:, 0].numpy()
    c2w = demo.c2w[SOURCES].numpy()
    target = demo.c2w[1].numpy()

    def u8(x):
        return (x.permute(0, 2, 3, 1).numpy() * 255 + 0.5).astype(np.uint8)

    ctx = create_headless_context()
    try:
        out = {}
        for name, images, m in (
            ("clean", demo.images[SOURCES], None),
            ("painted", rigged[SOURCES], None),
            ("masked", filled, masks[:, 0].numpy()),
            ("sharp", filled, masks[:, 0].numpy()),
        ):
            with PreviewRenderer(ctx, u8(images), depth, c2w, masks=m) as pr:
                geo = 64 if name == "sharp" else None
                out[name] = pr.render(target, 128, geo)[0].astype(np.float32) / 255
    finally:
        ctx.release()
    lands = where_rig_lands(demo, mask, 128).numpy()
    assert lands.sum() > 100
    err = {k: np.abs(v - out["clean"])[lands].mean() for k, v in out.items()}
    assert err["painted"] > 0.08
    assert err["masked"] < 0.03 and err["sharp"] < 0.03
    assert np.abs(out["masked"] - out["clean"])[~lands].mean() < 0.01
    assert math.isfinite(float(out["masked"].sum()))


def test_a_mask_given_to_the_preview_must_match_its_sources():
    from panogrf.renderer.gl_preview import PreviewRenderer

    with pytest.raises(ValueError, match="masks"):
        PreviewRenderer(
            None,
            np.zeros((2, 16, 32, 3), np.uint8),
            np.ones((2, 8, 16), np.float32),
            np.tile(np.eye(4), (2, 1, 1)),
            masks=np.zeros((1, 16, 32), bool),
        )


def test_views_carry_their_masks_into_caches_and_refined_copies():
    from helpers.nets import random_models

    from panogrf.model.refine import RefineConfig
    from panogrf.renderer.methods import SourceViews

    torch.manual_seed(0)
    images = torch.rand(2, 3, 32, 64) * 0.2 + 0.4
    images, _ = paint_rig(images)
    c2w = torch.eye(4).repeat(2, 1, 1)
    c2w[1, 0, 3] = 1.0
    views = SourceViews(images, c2w, nadir=25.0)
    assert views.nadir_mask is not None and views.nadir_mask.dtype == torch.bool
    assert (views.images[:, :, views.nadir_mask[0, 0]] > 0.2).all()  # the rig is gone
    models = random_models()
    views.depth["full"] = torch.full((2, 1, 16, 32), 2.0)  # no estimator: plumbing only
    cache = views.cache_for("panogrf", models)
    assert cache.mask is not None and cache.select([1]).mask.shape == (1, 1, 32, 64)
    views.caches[("panogrf", "full")] = cache.with_mask(None)  # as read from the disk cache
    assert views.cache_for("panogrf", models).mask is not None
    quick = RefineConfig(smooth=1.0, coarse=1, iterations=1, height=16)
    refined = views.refined(quick, models)
    assert refined.nadir_mask is views.nadir_mask and torch.equal(refined.images, views.images)
    unmasked = SourceViews(images, c2w)
    assert unmasked.nadir_mask is None and torch.equal(unmasked.images, images)
    assert rig_mask(32, 64).any()
