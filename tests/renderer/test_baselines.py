"""Baselines on an analytic room: the depth-warped blend must reproduce the target, the nearest
source must not (no parallax), and both must be finite everywhere."""

from __future__ import annotations

import torch
from helpers.room import pose, render

from panogrf.model.erp import latitude_weights, rotation_about
from panogrf.renderer.baselines import nearest_source, render_meshwarp, render_nearest

SRC_A = pose(rotation_about("y", 0.3), [-0.6, 0.0, 0.1])
SRC_B = pose(rotation_about("y", -1.1), [0.7, 0.1, -0.2])
TGT = pose(rotation_about("y", 2.0), [0.1, 0.05, -0.05])


def ws_psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    w = latitude_weights(*a.shape[-2:], dtype=a.dtype)
    mse = (((a - b) ** 2) * w).sum() / (w.sum() * a.shape[0])
    return float(10 * torch.log10(1 / mse))


def _scene(height: int = 64):
    imgs, depths = zip(
        *(render(c, ball=True, height=height, width=2 * height) for c in (SRC_A, SRC_B)),
        strict=True,
    )
    target, _ = render(TGT, ball=True, height=height, width=2 * height)
    c2w = torch.stack((SRC_A, SRC_B)).float()
    return torch.cat(imgs).float(), c2w, torch.cat(depths).float(), target[0].float()


def test_nearest_source_is_the_closest_centre():
    c2w = torch.stack((SRC_A, SRC_B)).float()
    assert nearest_source(c2w, TGT.float()) == 1  # 0.62 m from B, 0.72 m from A
    assert nearest_source(c2w, SRC_A.float()) == 0


def test_meshwarp_reproduces_the_target_and_beats_the_nearest_source():
    images, c2w, depth, target = _scene()
    rgb, tgt_depth = render_meshwarp(images, c2w, depth, TGT.float(), 64)
    assert rgb.shape == (3, 64, 128) and tgt_depth.shape == (1, 64, 128)
    assert torch.isfinite(rgb).all() and (rgb >= 0).all() and (rgb <= 1).all()
    near = render_nearest(images, c2w, TGT.float(), 64)
    assert near.shape == (3, 64, 128) and torch.isfinite(near).all()
    warped, rotated = ws_psnr(rgb, target), ws_psnr(near, target)
    assert warped > 28.0, warped
    assert warped > rotated + 8.0, (warped, rotated)


def test_meshwarp_at_a_source_pose_returns_that_source():
    images, c2w, depth, _ = _scene()
    rgb, _ = render_meshwarp(images, c2w, depth, SRC_A.float(), 64)
    assert ws_psnr(rgb, images[0]) > 30.0


def test_outputs_any_height():
    images, c2w, depth, _ = _scene(32)
    rgb, d = render_meshwarp(images, c2w, depth, TGT.float(), 48)
    assert rgb.shape == (3, 48, 96) and d.shape == (1, 48, 96)
    assert render_nearest(images, c2w, TGT.float(), 16).shape == (3, 16, 32)
