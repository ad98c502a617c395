"""Training data helpers: depth downsampling and the yaw-roll augmentation."""

from __future__ import annotations

import numpy as np
import pytest

from panogrf.app.scene.consistency import reprojection_check
from panogrf.app.scene.folder import load_scene
from panogrf.app.train.data import downsample_depth, yaw_roll
from panogrf.assets import path as asset_path


def test_downsample_depth_drops_edges():
    d = np.array([[1.0, 1.0, 2.0, 4.0], [1.0, 1.02, 2.0, 2.0]], np.float32)
    out = downsample_depth(d, 2)
    assert out.shape == (1, 2)
    assert np.isclose(out[0, 0], 1.005) and out[0, 1] == 0.0


@pytest.mark.parametrize("shift", [1, 37, -100])
def test_yaw_roll_keeps_the_scene_consistent(shift):
    s = load_scene(asset_path("demo"), load_images=True).images
    images, depths, c2w = s.images.clone(), s.depths[:, 0].clone(), s.c2w.clone()
    img0, dep0, pose0 = yaw_roll(images[0], depths[0], c2w[0], shift)
    images[0], depths[0], c2w[0] = img0, dep0, pose0
    r = reprojection_check(images, c2w, depths[:, None], 0, 1)
    assert r.psnr_depth_warp > 32.0  # as consistent as before the roll
    r2 = reprojection_check(images, c2w, depths[:, None], 1, 0)
    assert r2.psnr_depth_warp > 32.0
