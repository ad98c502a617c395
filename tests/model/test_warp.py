"""Backward warping and rotation of panoramas, checked on an analytic textured room."""

from __future__ import annotations

import math

import pytest
import torch
from helpers.room import (
    F64,
    H,
    W,
    erp_ray_directions,
    pose,
    psnr,
    ray_distance,
    render,
)

from panogrf.model.erp import rotation_about
from panogrf.model.warp import backward_warp, rotate_panorama

SRC = pose(rotation_about("y", 0.4) @ rotation_about("x", 0.1), [0.1, 0.0, 0.2])
TGT = pose(rotation_about("y", -0.9) @ rotation_about("z", 0.15), [0.7, 0.2, -0.5])


def test_room_warp_reproduces_the_target():
    src_img, src_depth = render(SRC)
    tgt_img, tgt_depth = render(TGT)
    colours, visible = backward_warp(src_img, SRC[None], src_depth, TGT[None], tgt_depth)
    assert colours.shape == (1, 3, H, W) and visible.shape == (1, 1, H, W)
    assert visible.dtype == torch.bool
    # A convex room hides nothing from the source. At 32 x 64 a pixel spans 5.6 degrees, so
    # on walls seen at grazing angles the nearest source depth can be off by more than 5 %:
    # a few false occlusions at the default tolerance, none at a looser one.
    assert visible.float().mean() > 0.9
    _, loose = backward_warp(
        src_img, SRC[None], src_depth, TGT[None], tgt_depth, occlusion_tol=0.15
    )
    assert loose.float().mean() > 0.995
    warped_psnr = psnr(colours, tgt_img, visible)
    rotated = rotate_panorama(src_img, SRC[None], TGT[None])
    rotated_psnr = psnr(rotated, tgt_img, visible)
    assert warped_psnr > 35.0
    assert warped_psnr > rotated_psnr + 10.0, (warped_psnr, rotated_psnr)


def test_room_warp_float32_and_without_source_depth():
    src_img, _ = render(SRC)
    tgt_img, tgt_depth = render(TGT)
    colours, visible = backward_warp(
        src_img.float(), SRC[None].float(), None, TGT[None].float(), tgt_depth.float()
    )
    assert colours.dtype == torch.float32
    assert visible.all()
    assert psnr(colours.double(), tgt_img, visible) > 35.0


def test_occlusion_by_a_ball_is_detected():
    # The ball sits near the target: the target sees parts of the walls (and of the ball) that
    # the ball hides from the source. 64 x 128 so that the hidden region is a few hundred pixels.
    height, width = 2 * H, 2 * W
    src_img, src_depth = render(SRC, ball=True, height=height, width=width)
    tgt_img, tgt_depth = render(TGT, ball=True, height=height, width=width)
    colours, visible = backward_warp(src_img, SRC[None], src_depth, TGT[None], tgt_depth)

    # Ground truth: is the target's surface point the first thing the source sees that way?
    dirs = erp_ray_directions(height, width) @ TGT[:3, :3].T
    points = TGT[:3, 3] + dirs * tgt_depth[0, 0, ..., None]
    to_points = points - SRC[:3, 3]
    dist = torch.linalg.vector_norm(to_points, dim=-1)
    first_hit = ray_distance(SRC[:3, 3], to_points / dist[..., None], ball=True)
    truly_visible = (first_hit - dist).abs() < 1e-6 * dist
    hidden = ~truly_visible
    assert hidden.float().mean() > 0.02, "the scene must actually occlude something"

    mask = visible[0, 0]
    # Hidden points are masked (at a silhouette the nearest source sample may still land on
    # the right surface, hence the margin); visible ones are kept, apart from grazing angles.
    assert (mask & hidden).sum() <= 0.05 * hidden.sum()
    assert (mask & truly_visible).sum() >= 0.92 * truly_visible.sum()
    # Without the occlusion test the hidden pixels get the ball's colour: far off.
    unchecked, everything = backward_warp(src_img, SRC[None], None, TGT[None], tgt_depth)
    assert everything.all()
    assert psnr(unchecked, tgt_img, hidden[None, None]) < 15.0
    # The kept pixels match the target, apart from blends across the ball's silhouette.
    assert psnr(colours, tgt_img, visible) > 30.0


def test_invalid_target_depth_is_not_visible():
    src_img, src_depth = render(SRC)
    _, tgt_depth = render(TGT)
    tgt_depth = tgt_depth.clone()
    tgt_depth[..., :4, :] = 0.0
    tgt_depth[..., 10, 5] = float("inf")
    tgt_depth[..., 11, 5] = float("nan")
    colours, visible = backward_warp(src_img, SRC[None], src_depth, TGT[None], tgt_depth)
    assert not visible[..., :4, :].any() and not visible[..., 10:12, 5].any()
    assert (colours[..., :4, :] == 0).all() and torch.isfinite(colours).all()
    _, visible_no_src = backward_warp(src_img, SRC[None], None, TGT[None], tgt_depth)
    expected = (tgt_depth > 0) & torch.isfinite(tgt_depth)
    assert torch.equal(visible_no_src, expected)


def test_warp_to_the_same_view_is_the_identity():
    gen = torch.Generator().manual_seed(0)
    img = torch.rand(2, 4, 16, 32, generator=gen, dtype=F64)
    depth = torch.rand(2, 1, 16, 32, generator=gen, dtype=F64) * 5 + 0.5
    c2w = torch.stack((SRC, TGT))
    colours, visible = backward_warp(img, c2w, depth, c2w, depth)
    assert visible.all()
    torch.testing.assert_close(colours, img)


def test_far_scene_warp_equals_rotation():
    gen = torch.Generator().manual_seed(1)
    img = torch.rand(1, 3, 16, 32, generator=gen, dtype=F64)
    far = torch.full((1, 1, 16, 32), 1e9, dtype=F64)
    colours, visible = backward_warp(img, SRC[None], far, TGT[None], far)
    assert visible.all()
    torch.testing.assert_close(
        colours, rotate_panorama(img, SRC[None], TGT[None]), atol=1e-6, rtol=0
    )


def test_warp_to_another_resolution():
    src_img, src_depth = render(SRC)
    tgt_depth = torch.full((1, 1, 8, 16), 2.0, dtype=F64)
    colours, visible = backward_warp(src_img, SRC[None], src_depth, TGT[None], tgt_depth)
    assert colours.shape == (1, 3, 8, 16) and visible.shape == (1, 1, 8, 16)


def test_rotate_panorama_identity_relative_pose_returns_input():
    gen = torch.Generator().manual_seed(2)
    img = torch.rand(2, 3, 16, 32, generator=gen, dtype=F64)
    src = torch.stack((SRC, TGT))
    tgt = src.clone()
    tgt[:, :3, 3] += torch.tensor([1.0, -2.0, 0.5], dtype=F64)  # translation does not matter
    torch.testing.assert_close(rotate_panorama(img, src, tgt), img)
    out32 = rotate_panorama(img.float(), src.float(), tgt.float())
    torch.testing.assert_close(out32, img.float(), atol=1e-5, rtol=0)


@pytest.mark.parametrize(
    ("yaw", "shift"), [(math.pi / 2, W // 4), (-math.pi / 2, -W // 4), (math.pi, W // 2)]
)
def test_yaw_shifts_columns(yaw, shift):
    gen = torch.Generator().manual_seed(3)
    img = torch.rand(1, 3, H, W, generator=gen, dtype=F64)
    base = pose(rotation_about("x", 0.3) @ rotation_about("y", 1.1), [0.0, 0.0, 0.0])
    turned = pose(base[:3, :3] @ rotation_about("y", yaw), [0.3, 0.0, 0.0])
    out = rotate_panorama(img, base[None], turned[None])
    # Turning left by 90 degrees (+yaw about +y) brings what was at lon - 90 deg to the centre.
    torch.testing.assert_close(out, torch.roll(img, shift, dims=-1), atol=1e-9, rtol=0)


def test_rotation_round_trip_is_close():
    src_img, _ = render(SRC)
    there = rotate_panorama(src_img, SRC[None], TGT[None])
    back = rotate_panorama(there, TGT[None], SRC[None])
    # Two bilinear resamplings of a smooth panorama: close, not exact.
    assert psnr(back, src_img, torch.ones(1, 1, H, W, dtype=torch.bool)) > 35.0


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_warp_on_cuda_matches_cpu():
    src_img, src_depth = render(SRC)
    _, tgt_depth = render(TGT)
    args = (
        src_img.float(),
        SRC[None].float(),
        src_depth.float(),
        TGT[None].float(),
        tgt_depth.float(),
    )
    cpu = backward_warp(*args)
    gpu = backward_warp(*(a.cuda() for a in args))
    torch.testing.assert_close(gpu[0].cpu(), cpu[0], atol=1e-4, rtol=0)
    assert (gpu[1].cpu() != cpu[1]).float().mean() < 0.01
    rotated = rotate_panorama(*(a.cuda() for a in args[:2]), args[3].cuda())
    torch.testing.assert_close(
        rotated.cpu(), rotate_panorama(args[0], args[1], args[3]), atol=1e-4, rtol=0
    )


def test_bad_inputs_are_errors():
    img = torch.rand(1, 3, H, W, dtype=F64)
    depth = torch.ones(1, 1, H, W, dtype=F64)
    c2w = SRC[None]
    with pytest.raises(ValueError, match="src_c2w"):
        backward_warp(img, SRC, depth, c2w, depth)
    with pytest.raises(ValueError, match="tgt_depth"):
        backward_warp(img, c2w, depth, c2w, depth[:, 0])
    with pytest.raises(ValueError, match="src_depth"):
        backward_warp(img, c2w, depth[..., :8, :16], c2w, depth)
    with pytest.raises(ValueError, match="tgt_c2w"):
        backward_warp(img, c2w, depth, torch.stack((SRC, TGT)), depth)
    with pytest.raises(ValueError, match="occlusion_tol"):
        backward_warp(img, c2w, depth, c2w, depth, occlusion_tol=0.0)
    with pytest.raises(ValueError, match="src_image"):
        rotate_panorama(img[0], c2w, c2w)


def test_backward_warp_gradcheck():
    gen = torch.Generator().manual_seed(4)
    img = torch.rand(1, 2, 4, 8, generator=gen, dtype=F64, requires_grad=True)
    depth = torch.rand(1, 1, 4, 8, generator=gen, dtype=F64) + 1.0
    tgt = TGT.clone()
    tgt[:3, 3] = torch.tensor([0.2, 0.1, -0.1], dtype=F64)
    assert torch.autograd.gradcheck(
        lambda x: backward_warp(x, SRC[None], None, tgt[None], depth)[0], (img,)
    )
