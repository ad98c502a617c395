"""The depth warp's written-out gradient against autograd through the plain projection."""

from __future__ import annotations

import pytest
import torch

from panogrf.model.depth_warp import warp_along, warp_rays
from panogrf.model.erp import direction_to_pixel, erp_directions, pad_seam, sample_padded


def _setup(pairs: int = 2, h: int = 12, channels: int = 3):
    g = torch.Generator().manual_seed(pairs)
    images = torch.rand(pairs, channels, h, 2 * h, generator=g, dtype=torch.float64)
    ref = torch.eye(4, dtype=torch.float64).repeat(pairs, 1, 1)
    src = ref.clone()
    src[:, :3, 3] = torch.randn(pairs, 3, generator=g, dtype=torch.float64)
    dirs = erp_directions(h, 2 * h, dtype=torch.float64)
    depth = 0.8 + 2 * torch.rand(pairs, h, 2 * h, generator=g, dtype=torch.float64)
    return pad_seam(images), depth, *warp_rays(ref, src, dirs)


def _plain(padded, depth, rays, shift):
    p, h, w = depth.shape
    q = depth[..., None] * rays + shift[:, None, None]
    return sample_padded(padded, direction_to_pixel(q.reshape(p, -1, 3), h, w)).reshape(p, -1, h, w)


def test_the_warp_and_its_depth_gradient_match_autograd_through_the_projection():
    padded, depth, rays, shift = _setup()
    depth.requires_grad_(True)
    got, want = warp_along(padded, depth, rays, shift), _plain(padded, depth, rays, shift)
    torch.testing.assert_close(got, want, rtol=0, atol=1e-12)
    weights = torch.rand_like(got)
    (g_got,) = torch.autograd.grad((got * weights).sum(), depth)
    (g_want,) = torch.autograd.grad((want * weights).sum(), depth)
    assert g_want.abs().max() > 0.1  # the warp does move with the depth
    torch.testing.assert_close(g_got, g_want, rtol=1e-9, atol=1e-9)


def test_gradcheck_on_one_channel():
    padded, depth, rays, shift = _setup(pairs=1, h=8, channels=1)
    depth.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda d: warp_along(padded, d, rays, shift), (depth,))


def test_one_set_of_rays_serves_a_batch_of_depths():
    padded, depth, rays, shift = _setup(pairs=1)
    depths = torch.stack((depth[0], 1.5 * depth[0], 0.7 * depth[0]))
    batched = warp_along(padded.expand(3, -1, -1, -1), depths, rays, shift)
    for k in range(3):
        one = warp_along(padded, depths[k : k + 1], rays, shift)
        torch.testing.assert_close(batched[k : k + 1], one, rtol=0, atol=1e-12)


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_on_cuda_the_warp_and_its_gradient_match_autograd_and_the_cpu():
    padded, depth, rays, shift = _setup()
    weights = torch.rand(2, 3, 12, 24, dtype=torch.float64)
    grads = {}
    for device in ("cpu", "cuda"):
        d = depth.to(device).requires_grad_(True)
        args = (padded.to(device), d, rays.to(device), shift.to(device))
        got, want = warp_along(*args), _plain(*args)
        torch.testing.assert_close(got, want, rtol=0, atol=1e-12)
        (g_got,) = torch.autograd.grad((got * weights.to(device)).sum(), d)
        (g_want,) = torch.autograd.grad((want * weights.to(device)).sum(), d)
        torch.testing.assert_close(g_got, g_want, rtol=1e-9, atol=1e-9)
        grads[device] = g_got.cpu()
    torch.testing.assert_close(grads["cuda"], grads["cpu"], rtol=1e-9, atol=1e-9)
