"""Reprojection consistency on the bundled scene: it passes when poses and depth agree and fails
when a pose, the depth or the ERP seam is off."""

from __future__ import annotations

import math

import pytest
import torch

from panogrf.app.scene.consistency import reprojection_check
from panogrf.app.scene.folder import load_scene
from panogrf.assets import path as asset_path
from panogrf.model.erp import rotation_about


@pytest.fixture(scope="module")
def demo():
    return load_scene(asset_path("demo"), load_images=True).images


def test_depth_warp_beats_rotation_by_far(demo):
    for source in (0, 2):
        r = reprojection_check(demo.images, demo.c2w, demo.depths, source, 1)
        assert r.covered > 0.9
        assert r.psnr_depth_warp > 32.0
        assert r.psnr_depth_warp > r.psnr_rotation_only + 10.0
        assert math.isclose(r.baseline_m, 0.5, abs_tol=1e-6)


@pytest.mark.parametrize(
    "corrupt",
    ["yaw_5deg", "shift_10cm", "depth_x1.2", "seam_shift"],
)
def test_check_catches_inconsistency(demo, corrupt):
    images, c2w, depths = demo.images.clone(), demo.c2w.clone(), demo.depths.clone()
    if corrupt == "yaw_5deg":
        c2w[0, :3, :3] = c2w[0, :3, :3] @ rotation_about("y", math.radians(5)).float()
    elif corrupt == "shift_10cm":
        c2w[0, :3, 3] += torch.tensor([0.1, 0.0, 0.0])
    elif corrupt == "depth_x1.2":
        depths[1] *= 1.2
    elif corrupt == "seam_shift":
        images[0] = torch.roll(images[0], shifts=4, dims=-1)
    good = reprojection_check(demo.images, demo.c2w, demo.depths, 0, 1)
    bad = reprojection_check(images, c2w, depths, 0, 1, occlusion_tol=1.0)
    assert bad.psnr_depth_warp < good.psnr_depth_warp - 5.0
