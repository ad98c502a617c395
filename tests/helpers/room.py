"""An analytic textured room (a box with an optional ball) rendered exactly as panoramas."""

from __future__ import annotations

import math

import torch

F64 = torch.float64
H, W = 32, 64

# The room: an axis-aligned box (metres) seen from inside, optionally with a ball in it.
ROOM_LO = torch.tensor([-2.5, -1.4, -3.2], dtype=F64)
ROOM_HI = torch.tensor([3.0, 1.6, 2.7], dtype=F64)
BALL_CENTRE = torch.tensor([1.2, 0.1, -0.2], dtype=F64)
BALL_RADIUS = 0.45
# Colour of a world point: a smooth (low-frequency) function of its position.
WAVES = torch.tensor([[0.9, 0.3, -0.5], [-0.4, 1.1, 0.6], [0.5, -0.7, 0.8]], dtype=F64)
PHASES = torch.tensor([0.3, 1.7, -0.8], dtype=F64)


def colour_at(points: torch.Tensor) -> torch.Tensor:
    """World points [..., 3] -> RGB in [0.15, 0.85], [..., 3]."""
    return 0.5 + 0.35 * torch.sin(points @ WAVES.T + PHASES)


def erp_ray_directions(height: int, width: int) -> torch.Tensor:
    """Camera-frame pixel-centre directions [H, W, 3], written out from docs/conventions.md."""
    v, u = torch.meshgrid(
        torch.arange(height, dtype=F64), torch.arange(width, dtype=F64), indexing="ij"
    )
    lon = 2 * math.pi * ((u + 0.5) / width - 0.5)
    lat = math.pi * (0.5 - (v + 0.5) / height)
    return torch.stack(
        (torch.cos(lat) * torch.sin(lon), torch.sin(lat), -torch.cos(lat) * torch.cos(lon)), -1
    )


def ray_distance(origin: torch.Tensor, dirs: torch.Tensor, ball: bool) -> torch.Tensor:
    """Distance along unit rays [..., 3] from ``origin`` (inside the room) to the first surface."""
    with torch.no_grad():
        safe = torch.where(dirs.abs() > 1e-12, dirs, torch.full_like(dirs, 1e-12))
        exits = torch.where(dirs > 0, ROOM_HI - origin, ROOM_LO - origin) / safe
        t = exits.amin(-1)
        if ball:
            oc = origin - BALL_CENTRE
            b = dirs @ oc
            disc = b * b - (oc @ oc - BALL_RADIUS**2)
            t_ball = -b - torch.sqrt(disc.clamp_min(0))
            t = torch.where((disc > 0) & (t_ball > 0) & (t_ball < t), t_ball, t)
    return t


def render(
    c2w: torch.Tensor, ball: bool = False, height: int = H, width: int = W
) -> tuple[torch.Tensor, torch.Tensor]:
    """Analytic panorama of the room from c2w [4, 4]: image [1, 3, h, w], depth [1, 1, h, w]."""
    dirs = erp_ray_directions(height, width) @ c2w[:3, :3].T  # world frame
    origin = c2w[:3, 3]
    t = ray_distance(origin, dirs, ball)
    image = colour_at(origin + dirs * t[..., None])
    return image.permute(2, 0, 1)[None], t[None, None]


def pose(rotation: torch.Tensor, position) -> torch.Tensor:
    c2w = torch.eye(4, dtype=F64)
    c2w[:3, :3] = rotation
    c2w[:3, 3] = torch.tensor(position, dtype=F64)
    return c2w


def psnr(a: torch.Tensor, b: torch.Tensor, mask: torch.Tensor) -> float:
    """PSNR (dB) of images in [0, 1] over the pixels where mask [B, 1, H, W] is true."""
    m = mask.expand_as(a)
    mse = ((a - b)[m] ** 2).mean()
    return float(10 * torch.log10(1 / mse))
