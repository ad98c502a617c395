"""The photometric error that the sweep and the refinement score warps by: per pixel
0.85 (1 - SSIM) / 2 + 0.15 |a - b| over 3x3 windows (ERP: wrapping at the seam, rows repeated at
the poles), the mean over the colour channels.

It is a few dozen passes over every pixel of every warp, the largest share of a scene's
preparation on a CPU, so it is written for few passes: the three windowed terms (a, a^2, a b)
are padded in one buffer and summed by one separable box sum, the rest is arithmetic in
place, and its gradient (`Photometric`) is written out rather than recorded, with the window
mean's adjoint (a full box sum folded back through the padding) in place of autograd's slices.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

C1, C2 = 0.01**2, 0.03**2


def _pad_w(x: Tensor, p: int = 1) -> Tensor:
    """``x`` [..., H, W] padded by ``p``: columns wrapped around the seam, rows repeated."""
    x = torch.cat((x[..., -p:], x, x[..., :p]), -1)
    return torch.cat((x[..., :1, :].expand(*x.shape[:-2], p, -1), x,
                      x[..., -1:, :].expand(*x.shape[:-2], p, -1)), -2)  # fmt: skip


def _box_sum(x: Tensor, k: int) -> Tensor:
    """Sum over k x k windows of [..., H + k - 1, W + k - 1] (already padded) -> [..., H, W]:
    separable sums of shifted slices (``F.avg_pool2d`` with stride 1 is several times slower
    on a CPU)."""
    h, w = x.shape[-2] - k + 1, x.shape[-1] - k + 1
    rows = x[..., 0:h, :] + x[..., 1 : 1 + h, :]
    for i in range(2, k):
        rows += x[..., i : i + h, :]
    out = rows[..., 0:w] + rows[..., 1 : 1 + w]
    for j in range(2, k):
        out += rows[..., j : j + w]
    return out


def box_mean_padded(x: Tensor, k: int) -> Tensor:
    """Mean over k x k windows of [..., H + k - 1, W + k - 1] (already padded) -> [..., H, W]."""
    return _box_sum(x, k).mul_(1.0 / (k * k))


def box_mean(x: Tensor, k: int) -> Tensor:
    """Mean of [..., H, W] over a k x k window (wrapping at the seam, rows repeated)."""
    return box_mean_padded(_pad_w(x, k // 2), k)


def _window_adjoint(g: Tensor) -> Tensor:
    """The adjoint of the 3x3 `box_mean` of [..., H, W]: a full 3x3 sum of ``g`` / 9, folded back
    through the padding (the rows it repeated, the columns it wrapped)."""
    padded = g.new_zeros(*g.shape[:-2], g.shape[-2] + 4, g.shape[-1] + 4)
    padded[..., 2:-2, 2:-2] = g
    y = box_mean_padded(padded, 3)  # [..., H + 2, W + 2]
    y[..., 1, :] += y[..., 0, :]
    y[..., -2, :] += y[..., -1, :]
    core = y[..., 1:-1, 1:-1]
    core[..., -1] += y[..., 1:-1, 0]
    core[..., 0] += y[..., 1:-1, -1]
    return core


def reference_stats(b: Tensor) -> tuple[Tensor, Tensor]:
    """The 3x3 window mean and variance of a reference image [B, 3, H, W] that
    `photometric_error` compares against (computed once where many images meet one reference)."""
    mu = box_mean(b, 3)
    return mu, box_mean(b * b, 3) - mu**2


def _windows(a: Tensor, b: Tensor) -> Tensor:
    """The 3x3 window means of a, a^2 and a b: [3, B, 3, H, W], one padded buffer, one box."""
    h, w = a.shape[-2:]
    buf = a.new_empty(3, *a.shape[:-2], h + 2, w + 2)
    inner = buf[..., 1:-1, 1:-1]
    inner[0] = a
    torch.mul(a, a, out=inner[1])
    torch.mul(a, b, out=inner[2])
    buf[..., 1:-1, 0] = buf[..., 1:-1, w]
    buf[..., 1:-1, -1] = buf[..., 1:-1, 1]
    buf[..., 0, :] = buf[..., 1, :]
    buf[..., -1, :] = buf[..., h, :]
    return box_mean_padded(buf, 3)


def _ssim_parts(a: Tensor, b: Tensor, stats: tuple[Tensor, Tensor]) -> tuple[Tensor, ...]:
    """SSIM's numerator and denominator factors: n1, n2, d1, d2 (SSIM = n1 n2 / (d1 d2)), and
    the window mean of ``a``."""
    mu_b, var_b = stats
    mu_a, s_aa, s_ab = _windows(a, b)
    mu_ab = mu_a * mu_b
    n2 = s_ab.sub_(mu_ab).mul_(2).add_(C2)  # 2 cov + c2
    n1 = mu_ab.mul_(2).add_(C1)  # 2 mu_a mu_b + c1
    sq = mu_a * mu_a
    d2 = s_aa.sub_(sq).add_(var_b).add_(C2)  # var_a + var_b + c2
    d1 = sq.add_(mu_b * mu_b).add_(C1)  # mu_a^2 + mu_b^2 + c1
    return n1, n2, d1, d2, mu_a


def _error(ssim: Tensor, a: Tensor, b: Tensor) -> Tensor:
    """0.85 clamp((1 - SSIM) / 2) + 0.15 |a - b|, the mean over channels; ``ssim`` is used up."""
    err = ssim.neg_().add_(1).mul_(0.5).clamp_(0, 1).mul_(0.85)
    err += (a - b).abs_().mul_(0.15)
    return err.mean(1)


def photometric_error(a: Tensor, b: Tensor, b_stats: tuple[Tensor, Tensor] | None = None) -> Tensor:
    """Per-pixel 0.85 (1 - SSIM) / 2 + 0.15 L1 of images [B, 3, H, W] -> [B, H, W] (``b`` may
    be [1, 3, H, W] against a batch of ``a``; ``b_stats``: `reference_stats` of ``b``, which
    takes no gradient). Differentiable in ``a`` (`Photometric`)."""
    stats = reference_stats(b) if b_stats is None else b_stats
    if torch.is_grad_enabled() and a.requires_grad:
        out: Tensor = Photometric.apply(a, b, *stats)  # type: ignore[no-untyped-call]
        return out
    n1, n2, d1, d2, _ = _ssim_parts(a, b, stats)
    return _error(n1.mul_(n2).div_(d1.mul_(d2)), a, b)


class Photometric(torch.autograd.Function):
    """`photometric_error` with its gradient in ``a`` written out (module docstring)."""

    @staticmethod
    def forward(ctx: Any, a: Tensor, b: Tensor, mu_b: Tensor, var_b: Tensor) -> Tensor:
        n1, n2, d1, d2, mu_a = _ssim_parts(a, b, (mu_b, var_b))
        den = d1 * d2
        ssim = n1 * n2
        ssim /= den
        # Where the clamp of (1 - SSIM) / 2 to [0, 1] passes the gradient (as torch's clamp).
        passes = (ssim >= -1) & (ssim <= 1)
        ctx.save_for_backward(a, b, mu_a, mu_b, n1, n2, d1, d2, den, ssim, passes)
        return _error(ssim.clone(), a, b)

    @staticmethod
    def backward(ctx: Any, *grads: Tensor) -> tuple[Tensor | None, ...]:
        a, b, mu_a, mu_b, n1, n2, d1, d2, den, ssim, passes = ctx.saved_tensors
        g = grads[0][:, None] / a.shape[1]  # the channel mean
        gs = passes * (g * -0.425)  # d error / d SSIM
        gn = gs / den
        gd1 = (gs * ssim).div_(d1).neg_()
        gd2 = (gs * ssim).div_(d2).neg_()
        gn1, gn2 = gn * n2, gn.mul_(n1)
        # d SSIM / d (window means of a, a^2, a b), then back through the windows at once.
        g_mu = ((gn1 - gn2).mul_(mu_b).add_((gd1 - gd2).mul_(mu_a))).mul_(2)
        back = _window_adjoint(torch.stack((g_mu, gd2, gn2.mul_(2))))
        grad = back[0]
        grad += back[1].mul_(a).mul_(2)
        grad += back[2].mul_(b)
        grad += torch.sign(a - b).mul_(g * 0.15)
        return grad, None, None, None
