"""Warping panoramas between poses: depth-based backward warping and pure rotation.

Frames and units follow docs/conventions.md: OpenGL camera frames, camera-to-world poses in
metres, spherical depth (Euclidean distance from the camera centre). Sampling wraps around
the seam and clamps at the poles (``sample_erp``).
"""

from __future__ import annotations

import torch
from torch import Tensor

from panogrf.model.erp import (
    erp_directions,
    erp_to_world,
    sample_erp,
    sample_erp_directions,
    world_to_erp,
)


def _check_image(
    name: str, x: Tensor, batch: int | None = None, channels: int | None = None
) -> None:
    if x.ndim != 4 or (batch is not None and x.shape[0] != batch):
        raise ValueError(f"{name} must be [B, C, H, W] with B = {batch}, got {tuple(x.shape)}")
    if channels is not None and x.shape[1] != channels:
        raise ValueError(f"{name} must have {channels} channel(s), got {tuple(x.shape)}")


def _check_pose(name: str, c2w: Tensor, batch: int) -> None:
    if c2w.shape != (batch, 4, 4):
        raise ValueError(f"{name} must be [B, 4, 4] with B = {batch}, got {tuple(c2w.shape)}")


def backward_warp(
    src_image: Tensor,  # [B, C, H, W]
    src_c2w: Tensor,  # [B, 4, 4]
    src_depth: Tensor | None,  # [B, 1, H, W] spherical depth (m), 0 = invalid; or None
    tgt_c2w: Tensor,  # [B, 4, 4]
    tgt_depth: Tensor,  # [B, 1, H2, W2] spherical depth (m), 0 = invalid
    occlusion_tol: float = 0.05,
) -> tuple[Tensor, Tensor]:
    """Fetch the source panorama's colours for every target pixel through the target's depth.

    Each target pixel is lifted to the world with its spherical depth, projected into the
    source camera and the source sampled there (bilinear, wrapping across the seam). A pixel
    is visible when its target depth is valid (> 0, finite) and, if ``src_depth`` is given,
    the source depth at the projected pixel (nearest sample) agrees with the point's distance
    from the source camera within ``occlusion_tol`` (relative); otherwise the point is hidden
    behind something else in the source.

    Returns colours [B, C, H2, W2] (0 where not visible) and the visible mask [B, 1, H2, W2]
    (bool). Differentiable with respect to the source image.
    """
    _check_image("src_image", src_image)
    batch, _, height, width = src_image.shape
    _check_pose("src_c2w", src_c2w, batch)
    _check_pose("tgt_c2w", tgt_c2w, batch)
    _check_image("tgt_depth", tgt_depth, batch, 1)
    if src_depth is not None:
        _check_image("src_depth", src_depth, batch, 1)
        if src_depth.shape[-2:] != (height, width):
            raise ValueError(
                f"src_depth must have the size of src_image {(height, width)}, "
                f"got {tuple(src_depth.shape[-2:])}"
            )
    if not occlusion_tol > 0:
        raise ValueError(f"occlusion_tol must be > 0, got {occlusion_tol}")

    dtype = src_image.dtype
    tgt_h, tgt_w = tgt_depth.shape[-2:]
    depth = tgt_depth[:, 0].to(dtype)
    valid = (depth > 0) & torch.isfinite(depth)  # [B, H2, W2]
    # Invalid pixels are lifted to the target centre: finite, and masked out below.
    depth = torch.where(valid, depth, 0.0)
    points = erp_to_world(depth, tgt_c2w.to(dtype))  # [B, H2*W2, 3]
    uv, distance = world_to_erp(points, src_c2w.to(dtype), height, width)  # [B, N, 2], [B, N]
    colours = sample_erp(src_image, uv)  # [B, C, N]

    visible = valid.reshape(batch, -1)
    if src_depth is not None:
        seen = sample_erp(src_depth.to(dtype), uv, mode="nearest")[:, 0]  # [B, N]
        visible = visible & (seen > 0) & ((seen - distance).abs() <= occlusion_tol * distance)

    visible = visible[:, None]  # [B, 1, N]
    colours = torch.where(visible, colours, 0.0)
    channels = src_image.shape[1]
    return (
        colours.reshape(batch, channels, tgt_h, tgt_w),
        visible.reshape(batch, 1, tgt_h, tgt_w),
    )


def rotate_panorama(src_image: Tensor, src_c2w: Tensor, tgt_c2w: Tensor) -> Tensor:
    """The source panorama [B, C, H, W] seen from the target's orientation, without parallax.

    The scene is taken as infinitely far away, so only the rotations of the poses [B, 4, 4]
    matter: a target pixel's direction d (target camera frame) is read from the source at
    ``R_src^T R_tgt d``. Returns [B, C, H, W] (bilinear, wrapping across the seam).
    """
    _check_image("src_image", src_image)
    batch, _, height, width = src_image.shape
    _check_pose("src_c2w", src_c2w, batch)
    _check_pose("tgt_c2w", tgt_c2w, batch)
    dtype = src_image.dtype
    rel = src_c2w[:, :3, :3].to(dtype).transpose(1, 2) @ tgt_c2w[:, :3, :3].to(dtype)  # [B,3,3]
    dirs = erp_directions(height, width, device=src_image.device, dtype=dtype).reshape(-1, 3)
    src_dirs = dirs @ rel.transpose(1, 2)  # [B, H*W, 3]
    out = sample_erp_directions(src_image, src_dirs)  # [B, C, H*W]
    return out.reshape(batch, -1, height, width)
