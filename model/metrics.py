"""Image and depth metrics of the evaluation protocol (docs/conventions.md), in pure torch.

The one implementation used by the CLI, the evaluation and the tests. Images are float RGB
(any channel count) in [0, 1], shaped [C, H, W] (-> a scalar tensor []) or [B, C, H, W]
(-> per-image values [B]). Depth maps are metres. "WS-" metrics weight every pixel by
cos(latitude) of its row, which assumes an equirectangular image spanning latitudes -90..90
degrees top to bottom; they accept any H, W (the weight depends on the row only) but are only
meaningful for full 2:1 panoramas.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import torch
from torch import Tensor
from torch.nn import functional as F

from panogrf.model.erp import latitude_weights

# SSIM constants of Wang et al. 2004, as in skimage with gaussian_weights=True.
_SSIM_SIGMA = 1.5
_SSIM_RADIUS = 5  # int(3.5 * sigma + 0.5): scipy's truncate=3.5 -> an 11x11 window
_SSIM_K1 = 0.01
_SSIM_K2 = 0.03


def check_image_pair(x: Tensor, y: Tensor, name: str) -> None:
    """Raise ValueError unless x, y are same-shape float [C, H, W] / [B, C, H, W] in [0, 1]."""
    for label, t in (("first", x), ("second", y)):
        if not isinstance(t, Tensor):
            raise TypeError(f"{name}: expected torch tensors, got {type(t).__name__} ({label})")
        if not t.is_floating_point():
            raise ValueError(
                f"{name}: expected float images in [0, 1], got dtype {t.dtype} ({label}); "
                "divide 8-bit images by 255"
            )
        if t.dim() not in (3, 4):
            raise ValueError(
                f"{name}: expected [C, H, W] or [B, C, H, W], got shape {tuple(t.shape)} ({label})"
            )
    if x.shape != y.shape:
        raise ValueError(f"{name}: shapes differ: {tuple(x.shape)} vs {tuple(y.shape)}")
    for label, t in (("first", x.detach()), ("second", y.detach())):
        if not bool(torch.isfinite(t).all()):
            bad = int((~torch.isfinite(t)).sum())
            raise ValueError(f"{name}: {label} image has {bad} NaN/inf values")
        lo, hi = float(t.min()), float(t.max())
        if lo < 0.0 or hi > 1.0:
            raise ValueError(
                f"{name}: expected values in [0, 1], got [{lo:.4g}, {hi:.4g}] ({label}); "
                "clamp renders, divide 8-bit images by 255"
            )


def _batched(x: Tensor, y: Tensor, name: str) -> tuple[Tensor, Tensor, bool]:
    """Validate, promote to >= float32 and add a batch axis: -> [B, C, H, W] x 2, was_single."""
    check_image_pair(x, y, name)
    dtype = torch.promote_types(x.dtype, torch.float32)
    single = x.dim() == 3
    x, y = x.to(dtype), y.to(dtype)
    return (x[None], y[None], True) if single else (x, y, False)


def _mse_to_psnr(mse: Tensor) -> Tensor:
    """10 log10(1 / mse) for a data range of 1; inf where mse is 0 (identical images)."""
    return 10.0 * torch.log10(1.0 / mse)


def psnr(x: Tensor, y: Tensor) -> Tensor:
    """PSNR in dB of images in [0, 1]: [C, H, W] -> [], [B, C, H, W] -> [B]; inf if equal."""
    x, y, single = _batched(x, y, "psnr")
    out = _mse_to_psnr((x - y).pow(2).mean(dim=(1, 2, 3)))
    return out[0] if single else out


def ws_psnr(x: Tensor, y: Tensor) -> Tensor:
    """Spherically weighted PSNR in dB of ERP images in [0, 1] (Sun et al. 2017).

    WMSE = sum w (x - y)^2 / sum w over rows, columns and channels, w = cos(latitude) of the
    row; WS-PSNR = 10 log10(1 / WMSE). Shapes as `psnr`. Equals PSNR when the error is the same
    in every row.
    """
    x, y, single = _batched(x, y, "ws_psnr")
    w = latitude_weights(x.shape[-2], x.shape[-1], device=x.device, dtype=x.dtype)  # [H, W]
    wmse = ((x - y).pow(2) * w).sum(dim=(1, 2, 3)) / (w.sum() * x.shape[1])
    out = _mse_to_psnr(wmse)
    return out[0] if single else out


def _gaussian_blur_valid(x: Tensor) -> Tensor:
    """Separable normalised 11x11 Gaussian, sigma 1.5, no padding.

    [N, 1, H, W] -> [N, 1, H - 10, W - 10].
    """
    t = torch.arange(-_SSIM_RADIUS, _SSIM_RADIUS + 1, device=x.device, dtype=x.dtype)
    g = torch.exp(-0.5 * (t / _SSIM_SIGMA) ** 2)
    g = g / g.sum()
    x = F.conv2d(x, g.view(1, 1, -1, 1))
    return F.conv2d(x, g.view(1, 1, 1, -1))


def ssim(x: Tensor, y: Tensor) -> Tensor:
    """Mean SSIM of images in [0, 1]: [C, H, W] -> [], [B, C, H, W] -> [B].

    Gaussian 11x11 window (sigma 1.5), K1 = 0.01, K2 = 0.03, data range 1, population
    covariances; averaged over channels and the pixels whose window lies inside the image.
    Matches skimage's ``structural_similarity(gaussian_weights=True, sigma=1.5,
    use_sample_covariance=False, data_range=1, channel_axis=...)``, which crops the same
    border. Needs H, W >= 11.
    """
    x, y, single = _batched(x, y, "ssim")
    b, c, h, w = x.shape
    win = 2 * _SSIM_RADIUS + 1
    if h < win or w < win:
        raise ValueError(f"ssim: expected images of at least {win}x{win}, got {w}x{h}")
    # Every channel is filtered on its own: fold channels into the batch axis.
    x, y = x.reshape(b * c, 1, h, w), y.reshape(b * c, 1, h, w)
    stats = _gaussian_blur_valid(torch.cat([x, y, x * x, y * y, x * y]))
    ux, uy, uxx, uyy, uxy = stats.chunk(5)
    vx, vy, vxy = uxx - ux * ux, uyy - uy * uy, uxy - ux * uy
    c1, c2 = _SSIM_K1**2, _SSIM_K2**2
    s = ((2 * ux * uy + c1) * (2 * vxy + c2)) / ((ux * ux + uy * uy + c1) * (vx + vy + c2))
    out = s.reshape(b, -1).mean(dim=1)
    return out[0] if single else out


@dataclass(frozen=True)
class DepthMetrics:
    """Depth errors of one image over its valid pixels, in metres (squared metres for L2)."""

    l1: float
    """Mean absolute error."""
    l2: float
    """Mean squared error."""
    rmse: float
    """Root mean squared error."""
    ws_l1: float
    """cos(latitude)-weighted mean absolute error."""
    ws_l2: float
    """cos(latitude)-weighted mean squared error."""
    ws_rmse: float
    """Square root of ws_l2."""
    valid: int
    """Number of pixels the errors were averaged over."""

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)


def _as_depth_batch(t: Tensor, name: str, label: str) -> Tensor:
    """[H, W] / [B, H, W] / [B, 1, H, W] -> [B, H, W]."""
    if t.dim() == 4 and t.shape[1] == 1:
        return t[:, 0]
    if t.dim() == 3:
        return t
    if t.dim() == 2:
        return t[None]
    raise ValueError(
        f"{name}: expected {label} as [H, W], [B, H, W] or [B, 1, H, W], got {tuple(t.shape)}"
    )


def depth_metrics_batch(pred: Tensor, gt: Tensor, mask: Tensor | None = None) -> list[DepthMetrics]:
    """Per-image depth errors of pred vs gt in metres, one `DepthMetrics` per image.

    pred, gt: [B, H, W] or [B, 1, H, W] (an [H, W] map counts as B = 1); mask: optional bool of
    the same shape. A pixel is valid where gt > 0 and finite, and mask is true. Errors are
    averaged over valid pixels only, with the same set for every metric. Raises ValueError for
    mismatched shapes, non-finite predictions at valid pixels, or an image with no valid pixel.
    """
    name = "depth_metrics"
    if pred.shape != gt.shape:
        raise ValueError(f"{name}: shapes differ: pred {tuple(pred.shape)} vs gt {tuple(gt.shape)}")
    p = _as_depth_batch(pred, name, "pred")
    g = _as_depth_batch(gt, name, "gt")
    dtype = torch.promote_types(torch.promote_types(p.dtype, g.dtype), torch.float32)
    p, g = p.to(dtype), g.to(dtype)
    valid = torch.isfinite(g) & (g > 0)
    if mask is not None:
        if mask.shape != gt.shape or mask.dtype != torch.bool:
            raise ValueError(
                f"{name}: expected a bool mask of shape {tuple(gt.shape)}, "
                f"got {mask.dtype} {tuple(mask.shape)}"
            )
        valid = valid & _as_depth_batch(mask, name, "mask")
    bad = int((valid & ~torch.isfinite(p)).sum())
    if bad:
        raise ValueError(f"{name}: pred has {bad} NaN/inf values at valid pixels")
    counts = valid.sum(dim=(1, 2))  # [B]
    if bool((counts == 0).any()):
        empty = torch.nonzero(counts == 0).flatten().tolist()
        raise ValueError(f"{name}: no valid ground-truth pixels (gt > 0, finite) in image {empty}")

    # Zero the error at invalid pixels (where gt may be NaN) instead of multiplying NaN by 0.
    err = torch.where(valid, p - g, torch.zeros((), dtype=dtype, device=p.device))  # [B, H, W]
    w = latitude_weights(p.shape[-2], p.shape[-1], device=p.device, dtype=dtype) * valid
    n = counts.to(dtype)
    wsum = w.sum(dim=(1, 2))
    l1 = err.abs().sum(dim=(1, 2)) / n
    l2 = err.pow(2).sum(dim=(1, 2)) / n
    ws_l1 = (w * err.abs()).sum(dim=(1, 2)) / wsum
    ws_l2 = (w * err.pow(2)).sum(dim=(1, 2)) / wsum
    rows = torch.stack([l1, l2, l2.sqrt(), ws_l1, ws_l2, ws_l2.sqrt()], dim=1).tolist()
    out = []
    for row, k in zip(rows, counts.tolist(), strict=True):
        l1_, l2_, rmse, ws_l1_, ws_l2_, ws_rmse = (float(v) for v in row)
        out.append(DepthMetrics(l1_, l2_, rmse, ws_l1_, ws_l2_, ws_rmse, valid=int(k)))
    return out


def depth_metrics(pred: Tensor, gt: Tensor, mask: Tensor | None = None) -> DepthMetrics:
    """Depth errors of one map [H, W] (or [1, H, W], [1, 1, H, W]); see depth_metrics_batch."""
    if pred.dim() >= 3 and pred.shape[0] != 1:
        raise ValueError(
            f"depth_metrics: expected one depth map, got a batch {tuple(pred.shape)}; "
            "use depth_metrics_batch"
        )
    return depth_metrics_batch(pred, gt, mask)[0]


#: Bands of elevation (degrees, camera frame, top to bottom) of `depth_l1_by_band`: where a
#: depth is wrong (the ceiling, the walls, the floor).
ELEVATION_BANDS = ((90, 60), (60, 30), (30, 0), (0, -30), (-30, -60), (-60, -90))


def band_key(band: tuple[int, int]) -> str:
    """The name of an elevation band's L1, e.g. "l1_90_60"."""
    return f"l1_{band[0]}_{band[1]}"


def depth_l1_by_band(
    pred: Tensor, gt: Tensor, mask: Tensor, bands: Sequence[tuple[int, int]] = ELEVATION_BANDS
) -> dict[str, tuple[float, int]]:
    """The absolute depth error summed over each band of elevation, with its pixel count:
    {`band_key`: (sum, count)}, so that bands can be pooled over views and scenes (the mean is
    sum / count). pred, gt, mask: [..., H, W] equirectangular maps (rows top to bottom from
    +90 to -90 degrees); a pixel counts where mask is true."""
    if pred.shape != gt.shape or mask.shape != gt.shape:
        raise ValueError(
            f"depth_l1_by_band: shapes differ: pred {tuple(pred.shape)}, gt {tuple(gt.shape)}, "
            f"mask {tuple(mask.shape)}"
        )
    h = gt.shape[-2]
    lat = 90.0 - (torch.arange(h, dtype=torch.float64, device=gt.device) + 0.5) / h * 180.0
    error = torch.where(
        mask, (pred.double() - gt.double()).abs(), torch.zeros((), dtype=torch.float64)
    )
    out = {}
    for hi, lo in bands:
        rows = (lat <= hi) & (lat > lo)
        out[band_key((hi, lo))] = (float(error[..., rows, :].sum()), int(mask[..., rows, :].sum()))
    return out


__all__ = [
    "ELEVATION_BANDS",
    "band_key",
    "depth_l1_by_band",
    "DepthMetrics",
    "check_image_pair",
    "depth_metrics",
    "depth_metrics_batch",
    "psnr",
    "ssim",
    "ws_psnr",
]
