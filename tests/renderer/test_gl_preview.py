"""The GL preview on headless EGL: the bundled scene's middle view warped from the outer two.

Checked against a golden image (tolerance for GL rasterisation differences; set
PANOGRF_DUMP_GOLDEN=1 to write the actual image beside the golden when the test fails) and,
independently, against the real middle panorama.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from panogrf.app.images import read_rgb, write_rgb
from panogrf.app.scene import load_scene
from panogrf.assets import path as asset_path
from panogrf.model.metrics import ws_psnr

GOLDEN = Path(__file__).parent.parent / "golden" / "preview_demo_mid.png"

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def demo():
    data = load_scene(asset_path("demo"), load_images=True).images
    images = (data.images.permute(0, 2, 3, 1).numpy() * 255 + 0.5).astype(np.uint8)
    depth = F.interpolate(data.depths, size=(128, 256), mode="nearest")[:, 0].numpy()
    return data, images, depth


@pytest.fixture(scope="module")
def gl():
    from panogrf.renderer.gl_preview import create_headless_context

    ctx = create_headless_context()
    yield ctx
    ctx.release()


def test_preview_matches_the_golden_image_and_the_real_view(gl, demo):
    from panogrf.renderer.gl_preview import PreviewRenderer

    data, images, depth = demo
    with PreviewRenderer(gl, images[[0, 2]], depth[[0, 2]], data.c2w[[0, 2]].numpy()) as pr:
        rgb, dist = pr.render(data.c2w[1].numpy(), 256)
    assert rgb.shape == (256, 512, 3) and dist.shape == (256, 512)
    assert np.isfinite(dist).all() and (dist > 0).mean() > 0.97  # 0: filled holes
    x = torch.from_numpy(rgb).permute(2, 0, 1)[None].float() / 255
    assert float(ws_psnr(x, data.images[1:2])) > 27.0
    gt = data.depths[1, 0].numpy()
    ok = gt > 0
    assert np.median(np.abs(dist[ok] - gt[ok]) / gt[ok]) < 0.01
    golden = read_rgb(GOLDEN)
    diff = np.abs(rgb.astype(np.int16) - golden.astype(np.int16))
    close = (diff.max(-1) <= 8).mean()
    if close < 0.98 and os.environ.get("PANOGRF_DUMP_GOLDEN"):
        write_rgb(GOLDEN.with_name(GOLDEN.stem + "_actual.png"), rgb)
    assert close >= 0.98, f"{close:.3f} of the pixels within 8 levels of the golden image"


def test_preview_at_a_source_pose_is_that_source(gl, demo):
    from panogrf.renderer.gl_preview import PreviewRenderer

    data, images, depth = demo
    with PreviewRenderer(gl, images, depth, data.c2w.numpy()) as pr:
        rgb, _ = pr.render(data.c2w[0].numpy(), 256)
        # Seam: the first and last columns are neighbours like any other two.
        seam = np.abs(rgb[:, 0].astype(float) - rgb[:, -1].astype(float)).mean()
        inner = np.abs(np.diff(rgb.astype(float), axis=1)).mean()
    x = torch.from_numpy(rgb).permute(2, 0, 1)[None].float() / 255
    assert float(ws_psnr(x, data.images[0:1])) > 30.0
    assert seam < 3 * inner + 2.0


def test_bad_input(gl, demo):
    from panogrf.renderer.gl_preview import PreviewRenderer

    _, images, depth = demo
    with pytest.raises(ValueError, match="disagree"):
        PreviewRenderer(gl, images, depth[:2], np.tile(np.eye(4), (3, 1, 1)))
