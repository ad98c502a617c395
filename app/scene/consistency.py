"""Does a scene's geometry agree with its pixels? Depth-based warping between its views.

For a target view with depth, every pixel is lifted to the world and looked up in a source
view. Where poses, depths and the ERP convention all agree, the warped source reproduces the
target on the pixels the source also sees; rotation alone (no parallax) does not. A wrong sign,
a transposed pose or a shifted seam makes the two PSNRs meet.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from panogrf.model.warp import backward_warp, rotate_panorama


@dataclass(frozen=True)
class ReprojectionResult:
    source: int
    target: int
    baseline_m: float
    """Distance between the two camera centres."""
    covered: float
    """Fraction of target pixels with depth that the source also sees (not occluded)."""
    psnr_depth_warp: float
    """PSNR (dB) of the depth-warped source against the target on covered pixels."""
    psnr_rotation_only: float
    """PSNR (dB) of the source rotated to the target orientation, same pixels."""


def _masked_psnr(a: torch.Tensor, b: torch.Tensor, mask: torch.Tensor) -> float:
    """PSNR over the pixels of ``mask`` [1, H, W] (all channels) of images in [0, 1]."""
    m = mask.expand_as(a)
    mse = float(((a - b)[m] ** 2).mean())
    return math.inf if mse == 0 else 10.0 * math.log10(1.0 / mse)


def reprojection_check(
    images: torch.Tensor,  # [V, 3, H, W] in [0, 1]
    c2w: torch.Tensor,  # [V, 4, 4]
    depths: torch.Tensor,  # [V, 1, H, W] metres, 0 = unknown
    source: int,
    target: int,
    occlusion_tol: float = 0.05,
) -> ReprojectionResult:
    """Warp view ``source`` into view ``target`` with the depths and score both warps."""
    s, t = slice(source, source + 1), slice(target, target + 1)
    warped, visible = backward_warp(
        images[s], c2w[s], depths[s], c2w[t], depths[t], occlusion_tol=occlusion_tol
    )
    rotated = rotate_panorama(images[s], c2w[s], c2w[t])
    mask = visible[0]
    valid = (depths[t] > 0).sum().clamp(min=1)
    return ReprojectionResult(
        source=source,
        target=target,
        baseline_m=float(torch.linalg.vector_norm(c2w[source, :3, 3] - c2w[target, :3, 3])),
        covered=float(mask.sum() / valid),
        psnr_depth_warp=_masked_psnr(warped[0], images[target], mask),
        psnr_rotation_only=_masked_psnr(rotated[0], images[target], mask),
    )
