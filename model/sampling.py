"""Samples along spherical rays and volume compositing (pure functions on tensors).

A ray starts at a camera centre and runs along a unit direction; a sample is its distance ``t``
from the centre in metres (the spherical depth of the point). Samples are sorted by ``t``.

Shapes: R rays, S samples per ray.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

#: Length given to the last interval of every ray: whatever the last sample holds fills the rest.
LAST_DELTA = 1e3


def inverse_depth_samples(
    n_rays: int,
    n_samples: int,
    near: float | Tensor,
    far: float | Tensor,
    *,
    generator: torch.Generator | None = None,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """``n_samples`` per ray uniform in inverse depth over [near, far] metres: [R, S] ascending.

    With a ``generator`` each sample is jittered inside its bin (stratified, for training);
    without, samples sit at the bin centres (deterministic, for rendering). ``near`` and
    ``far`` may be 0-dim float64 tensors on the device (a replayed CUDA graph reads them; the
    same arithmetic as with floats), checked where they are made.
    """
    if not isinstance(near, Tensor) and not isinstance(far, Tensor) and not 0 < near < far:
        raise ValueError(f"need 0 < near < far, got near={near}, far={far}")
    edges = torch.linspace(0.0, 1.0, n_samples + 1, device=device, dtype=dtype)
    if generator is None:
        s = (0.5 * (edges[:-1] + edges[1:])).expand(n_rays, n_samples)
    else:
        jitter = torch.rand(n_rays, n_samples, generator=generator, dtype=dtype).to(device)
        s = edges[:-1] + jitter * (edges[1:] - edges[:-1])
    inv = 1.0 / near + s * (1.0 / far - 1.0 / near)  # descending inverse depth
    return 1.0 / inv


def sample_pdf(
    t: Tensor,  # [R, S] sorted sample depths whose weights are given
    weights: Tensor,  # [R, S] compositing weights of those samples
    n_samples: int,
    *,
    generator: torch.Generator | None = None,
) -> Tensor:
    """Importance samples [R, n] drawn from the piecewise-constant pdf of ``weights`` (no grad).

    The bins are the intervals between the mid-points of ``t`` (the first and last samples close
    the outer bins), in inverse depth; deterministic (evenly spaced quantiles) without a
    ``generator``. Returned samples are sorted.
    """
    with torch.no_grad():
        inv = 1.0 / t
        mids = 0.5 * (inv[:, 1:] + inv[:, :-1])
        edges = torch.cat((inv[:, :1], mids, inv[:, -1:]), -1)  # [R, S + 1], descending
        w = weights + 1e-5
        pdf = w / w.sum(-1, keepdim=True)
        cdf = torch.cat((torch.zeros_like(pdf[:, :1]), torch.cumsum(pdf, -1)), -1)
        cdf = cdf.clamp(max=1.0).contiguous()
        r = t.shape[0]
        if generator is None:
            u = (torch.arange(n_samples, device=t.device, dtype=t.dtype) + 0.5) / n_samples
            u = u.expand(r, n_samples).contiguous()
        else:
            u = torch.rand(r, n_samples, generator=generator, dtype=t.dtype).to(t.device)
        idx = torch.searchsorted(cdf, u, right=True).clamp(1, cdf.shape[-1] - 1)
        c0, c1 = cdf.gather(-1, idx - 1), cdf.gather(-1, idx)
        e0, e1 = edges.gather(-1, idx - 1), edges.gather(-1, idx)
        frac = ((u - c0) / (c1 - c0).clamp(min=1e-8)).clamp(0.0, 1.0)
        samples = 1.0 / (e0 + frac * (e1 - e0))
        return torch.sort(samples, -1).values


def guided_samples(
    near_proxy: Tensor,  # [R] proxy depth of the nearest surface (metres)
    far_proxy: Tensor,  # [R] proxy depth of the farthest surface nearby (>= near_proxy)
    n_samples: int,
    band: float = 0.2,
) -> Tensor:
    """Depth-guided samples [R, n] (sorted): half around each proxy, within +-``band`` of it
    in relative inverse depth. Where both proxies agree the two halves interleave."""
    if n_samples < 2:
        raise ValueError(f"guided sampling needs at least 2 samples, got {n_samples}")
    k_near = n_samples // 2
    k_far = n_samples - k_near

    def around(center: Tensor, k: int, phase: float) -> Tensor:
        s = (torch.arange(k, device=center.device, dtype=center.dtype) + phase) / k  # (0, 1)
        scale = torch.exp(band * (2.0 * s - 1.0))  # inverse-depth factors in [e^-b, e^b]
        return center[:, None] / scale  # depths

    t = torch.cat((around(near_proxy, k_near, 0.25), around(far_proxy, k_far, 0.75)), -1)
    return torch.sort(t, -1).values


@dataclass
class Composite:
    """Volume-rendered result of R rays."""

    rgb: Tensor  # [R, 3]
    depth: Tensor  # [R] expected spherical depth (metres) of the visible surface
    opacity: Tensor  # [R] accumulated opacity in [0, 1]
    weights: Tensor  # [R, S] compositing weights


def composite(sigma: Tensor, rgb: Tensor, t: Tensor) -> Composite:
    """Alpha compositing: ``w_i = alpha_i prod_{k<i} (1 - alpha_k)``, ``alpha = 1 - exp(-sigma
    delta)``; sigma [R, S] (1/m), rgb [R, S, 3], t [R, S] sorted (m). The last interval is
    `LAST_DELTA` long, so a ray that reaches it ends on its last sample."""
    delta = torch.cat((t[:, 1:] - t[:, :-1], torch.full_like(t[:, :1], LAST_DELTA)), -1)
    alpha = 1.0 - torch.exp(-torch.relu(sigma) * delta)
    # Transmittance through exclusive cumulative product (log space is stable for long rays).
    # (Summed along the first dimension of the transpose: a GPU's scan along a short last
    # dimension is slow, 0.76 ms for 131072 rays of 12 samples on an H200.)
    log_t = torch.cat((torch.zeros_like(alpha[:, :1]), _log1m(alpha[:, :-1])), -1)
    trans = torch.exp(torch.cumsum(log_t.T, 0).T)
    w = alpha * trans
    opacity = w.sum(-1)
    return Composite(
        rgb=(w[..., None] * rgb).sum(1),
        depth=(w * t).sum(-1) / opacity.clamp(min=1e-6),
        opacity=opacity,
        weights=w,
    )


def _log1m(alpha: Tensor) -> Tensor:
    return torch.log((1.0 - alpha).clamp(min=1e-10))


def composite_reference(sigma: Tensor, rgb: Tensor, t: Tensor) -> Composite:
    """The same as `composite`, as a plain loop over samples (slow, obviously right)."""
    r, s = sigma.shape
    out_rgb = torch.zeros(r, 3, dtype=sigma.dtype)
    out_depth = torch.zeros(r, dtype=sigma.dtype)
    weights = torch.zeros(r, s, dtype=sigma.dtype)
    for i in range(r):
        trans = 1.0
        for k in range(s):
            delta = float(t[i, k + 1] - t[i, k]) if k + 1 < s else LAST_DELTA
            alpha = 1.0 - float(torch.exp(-max(float(sigma[i, k]), 0.0) * torch.tensor(delta)))
            w = trans * alpha
            weights[i, k] = w
            out_rgb[i] += w * rgb[i, k]
            out_depth[i] += w * t[i, k]
            trans *= 1.0 - alpha
    opacity = weights.sum(-1)
    return Composite(out_rgb, out_depth / opacity.clamp(min=1e-6), opacity, weights)
