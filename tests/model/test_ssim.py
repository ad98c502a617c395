"""The photometric error's written-out forward and gradient against the plain formula and
autograd."""

from __future__ import annotations

import pytest
import torch
from helpers.photometric import plain_photometric

from panogrf.model.ssim import (
    _window_adjoint,
    box_mean,
    photometric_error,
    reference_stats,
)


def _pair(batch: int, dtype: torch.dtype = torch.float64) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(batch)
    b = torch.rand(1, 3, 7, 12, generator=g, dtype=dtype)
    a = (b + 0.3 * torch.rand(batch, 3, 7, 12, generator=g, dtype=dtype)).clamp(0, 1)
    return a, b


def test_the_error_and_its_gradient_match_the_plain_formula():
    a, b = _pair(3)
    a.requires_grad_(True)
    weights = torch.rand(3, 7, 12, dtype=torch.float64)
    got = photometric_error(a, b)
    want = plain_photometric(a, b)
    torch.testing.assert_close(got, want, rtol=0, atol=1e-12)
    (g_got,) = torch.autograd.grad((got * weights).sum(), a)
    (g_want,) = torch.autograd.grad((want * weights).sum(), a)
    torch.testing.assert_close(g_got, g_want, rtol=0, atol=1e-12)
    with torch.no_grad():  # the forward without a graph is the same error
        torch.testing.assert_close(photometric_error(a, b), want, rtol=0, atol=1e-12)


def test_gradcheck_including_where_the_clamp_cuts():
    a, b = _pair(2)
    a = a.detach().requires_grad_(True)
    stats = reference_stats(b)
    assert torch.autograd.gradcheck(lambda x: photometric_error(x, b, stats), (a,))
    # Anti-correlated windows: SSIM below 0 (the clamp's lower end still passes).
    assert torch.autograd.gradcheck(lambda x: photometric_error(1 - x, b, stats), (a,))


def test_the_window_adjoint_is_the_transpose_of_the_window_mean():
    g = torch.Generator().manual_seed(0)
    x = torch.rand(2, 3, 6, 9, generator=g, dtype=torch.float64)
    y = torch.rand(2, 3, 6, 9, generator=g, dtype=torch.float64)
    lhs = (box_mean(x, 3) * y).sum()
    rhs = (x * _window_adjoint(y)).sum()
    torch.testing.assert_close(lhs, rhs, rtol=1e-12, atol=0)


def test_inputs_are_left_as_they_were():
    a, b = _pair(2, torch.float32)
    stats = reference_stats(b)
    copies = [t.clone() for t in (a, b, *stats)]
    photometric_error(a, b, stats)
    photometric_error(a.clone().requires_grad_(True), b, stats).sum().backward()
    for before, after in zip(copies, (a, b, *stats), strict=True):
        assert torch.equal(before, after)


def test_one_channel_images_take_their_own_gradient():
    """One channel (a grey image): the error and its gradient are the plain formula's too."""
    a, b = _pair(2)
    a, b = a[:, :1].detach().requires_grad_(True), b[:, :1]
    got, want = photometric_error(a, b), plain_photometric(a, b)
    torch.testing.assert_close(got, want, rtol=0, atol=1e-12)
    (g_got,) = torch.autograd.grad(got.sum(), a)
    (g_want,) = torch.autograd.grad(want.sum(), a)
    torch.testing.assert_close(g_got, g_want, rtol=0, atol=1e-12)


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_on_cuda_the_error_and_its_gradient_match_the_plain_formula_and_the_cpu():
    a, b = _pair(3)
    weights = torch.rand(3, 7, 12, dtype=torch.float64)
    grads = {}
    for device in ("cpu", "cuda"):
        x = a.to(device).requires_grad_(True)
        got, want = photometric_error(x, b.to(device)), plain_photometric(x, b.to(device))
        torch.testing.assert_close(got, want, rtol=0, atol=1e-12)
        (g_got,) = torch.autograd.grad((got * weights.to(device)).sum(), x)
        (g_want,) = torch.autograd.grad((want * weights.to(device)).sum(), x)
        torch.testing.assert_close(g_got, g_want, rtol=0, atol=1e-12)
        grads[device] = g_got.cpu()
    torch.testing.assert_close(grads["cuda"], grads["cpu"], rtol=0, atol=1e-12)
