"""The shipped renderer weights on the bundled demo scene (real networks, real depth).

Rendering at an input pose must reproduce that input; no pixel may be NaN or infinite, poles
and seam included; the seam must be as continuous as any other pair of neighbouring columns.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from panogrf.app.scene.folder import load_scene
from panogrf.app.scene.session import default_models
from panogrf.assets import path as asset_path
from panogrf.model.metrics import ws_psnr
from panogrf.renderer.methods import SourceViews, render_view


@pytest.fixture(scope="module")
def demo():
    data = load_scene(asset_path("demo"), load_images=True).images
    models = default_models()
    return data, models


@pytest.mark.parametrize("quality", ["fast", "paper"])
def test_rendering_an_input_pose_reproduces_the_input(demo, quality):
    data, models = demo
    views = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]])
    height = 128 if quality == "fast" else 64  # 64 + 64 samples are slow on a CPU
    rgb = render_view("panogrf", views, data.c2w[0], height, models, quality)
    assert torch.isfinite(rgb).all()
    ref = torch.nn.functional.interpolate(data.images[0:1], size=rgb.shape[-2:], mode="area")
    assert float(ws_psnr(rgb[None], ref)) >= 35.0  # the photo itself, detail from it alone


def test_novel_view_is_finite_with_a_continuous_seam(demo):
    data, models = demo
    views = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]])
    rgb = render_view("panogrf", views, data.c2w[1], 128, models, "fast")
    assert torch.isfinite(rgb).all() and rgb.min() >= 0 and rgb.max() <= 1
    img = rgb.permute(1, 2, 0).numpy()
    neighbours = np.abs(np.diff(img, axis=1)).mean(axis=(0, 2))  # [W - 1] column pairs
    seam = np.abs(img[:, 0] - img[:, -1]).mean()
    assert seam <= np.percentile(neighbours, 95), (seam, np.percentile(neighbours, 95))
    # Poles: the first and last rows are finite and nearly uniform (one point each).
    for row in (img[0], img[-1]):
        assert row.std(axis=0).max() < 0.1


def test_novel_view_beats_the_nearest_source(demo):
    data, models = demo
    views = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]])
    ref = torch.nn.functional.interpolate(data.images[1:2], size=(128, 256), mode="area")
    ours = render_view("panogrf", views, data.c2w[1], 128, models, "fast")
    near = render_view("nearest", views, data.c2w[1], 128, models)
    assert float(ws_psnr(ours[None], ref)) > float(ws_psnr(near[None], ref)) + 3.0


def test_perspective_rays_match_the_panorama_they_replace(demo):
    """A perspective frame rendered from its own rays looks like the same view cut out of a
    panorama at the same angular resolution, at a fraction of the rays."""
    from panogrf.model.perspective import erp_to_perspective
    from panogrf.renderer.methods import render_perspective_view

    data, models = demo
    views = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]])
    w, h, fov = 96, 64, 70.0
    own = render_perspective_view("panogrf", views, data.c2w[1], w, h, fov, models, "fast")
    pano = render_view("panogrf", views, data.c2w[1], 160, models, "fast")
    cut = erp_to_perspective(pano, w, h, fov)
    assert own.shape == (3, h, w) and torch.isfinite(own).all()
    mse = float(((own - cut) ** 2).mean())
    assert 10 * np.log10(1 / mse) > 35.0  # 39.6 dB measured; it rises with the panorama rows
    # A method that is not neural has no ray renderer: the caller cuts its panorama.
    assert render_perspective_view("meshwarp", views, data.c2w[1], w, h, fov, models) is None
