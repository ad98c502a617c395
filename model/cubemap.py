"""Cubemap <-> ERP resampling for the cubemap branch of the 360-degree monocular depth network.

A cubemap is six 90-degree perspective faces [B, 6, C, F, F] in the order of ``FACE_NAMES``.
Each face is an upright image (row 0 at the top) of a camera that looks along the face's axis
(OpenGL camera frame: looking down its own -z). The side faces have +y up; the up face has
+z (back) at its top, the down face -z (front) at its top.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from panogrf.model.erp import erp_directions, rotation_about, sample_erp_directions

FACE_NAMES = ("front", "right", "back", "left", "up", "down")


def face_rotations(
    dtype: torch.dtype = torch.float32, device: torch.device | str | None = None
) -> Tensor:
    """Camera-to-panorama rotations of the six faces [6, 3, 3] (front = identity), on
    ``device`` (default: the CPU)."""
    half = math.pi / 2
    rots = [
        torch.eye(3, dtype=torch.float64, device="cpu"),
        rotation_about("y", -half),  # right: looks along +x
        rotation_about("y", math.pi),  # back: looks along +z
        rotation_about("y", half),  # left: looks along -x
        rotation_about("x", half),  # up: looks along +y
        rotation_about("x", -half),  # down: looks along -y
    ]
    return torch.stack(rots).to(device or "cpu", dtype)


def face_directions(
    face_size: int, *, device: torch.device | str | None = None, dtype: torch.dtype = torch.float32
) -> Tensor:
    """Unit directions (panorama camera frame) of every face pixel centre: [6, F, F, 3]."""
    t = (torch.arange(face_size, device=device, dtype=dtype) + 0.5) / face_size * 2.0 - 1.0
    y, x = torch.meshgrid(-t, t, indexing="ij")
    local = torch.stack((x, y, -torch.ones_like(x)), -1)
    local = local / torch.linalg.vector_norm(local, dim=-1, keepdim=True)
    rots = face_rotations(dtype, device)
    return torch.einsum("kij,hwj->khwi", rots, local)


def erp_to_cubemap(erp: Tensor, face_size: int, mode: str = "bilinear") -> Tensor:
    """Resample panoramas [B, C, H, W] to cubemaps [B, 6, C, F, F]."""
    b, c = erp.shape[:2]
    dirs = face_directions(face_size, device=erp.device, dtype=erp.dtype).reshape(1, -1, 3)
    out = sample_erp_directions(erp, dirs.expand(b, -1, -1), mode=mode)
    return out.reshape(b, c, 6, face_size, face_size).permute(0, 2, 1, 3, 4)


def cubemap_to_erp(faces: Tensor, height: int, width: int, mode: str = "bilinear") -> Tensor:
    """Resample cubemaps [B, 6, C, F, F] to panoramas [B, C, H, W].

    Every ERP pixel reads the face whose axis is closest to its direction (ties at face edges
    go to the first such face); samples outside a face's interior clamp to its border.
    """
    b, _, c, fsize, _ = faces.shape
    dirs = erp_directions(height, width, device=faces.device, dtype=faces.dtype)  # [H, W, 3]
    rots = face_rotations(faces.dtype, faces.device)
    local = torch.einsum("kji,hwj->khwi", rots, dirs)  # rotate into each face's frame (R^T d)
    forward = -local[..., 2]  # [6, H, W] component along each face's viewing axis
    face_idx = forward.argmax(0)  # [H, W]
    out = faces.new_zeros(b, c, height, width)
    for k in range(6):
        mask = face_idx == k
        if not mask.any():
            continue
        loc = local[k][mask]  # [N, 3]
        fx = loc[:, 0] / -loc[:, 2]
        fy = -loc[:, 1] / -loc[:, 2]  # image rows grow downwards
        grid = torch.stack((fx, fy), -1)[None, None].expand(b, -1, -1, -1)
        vals = F.grid_sample(
            faces[:, k], grid, mode=mode, padding_mode="border", align_corners=False
        )
        out[:, :, mask] = vals[:, :, 0]
    del fsize
    return out
