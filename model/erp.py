"""Equirectangular (ERP) geometry: pixels, directions, projection and sampling with wrap-around.

Conventions (docs/conventions.md), the same everywhere in the project:
- camera frame OpenGL: x right, y up, looking down -z; poses are camera-to-world 4x4 (metres);
- an ERP image has width W = 2H; pixel (u, v) (column, row) has its centre at integer
  coordinates, and
  ``lon = 2*pi*((u+0.5)/W - 0.5)``, ``lat = pi*(0.5 - (v+0.5)/H)``,
  ``d = (cos(lat) sin(lon), sin(lat), -cos(lat) cos(lon))``:
  the centre column looks along -z, the right quarter along +x, the top row up (+y);
- depth is spherical: the Euclidean distance from the camera centre, in metres.

Sampling wraps horizontally (left and right edges are neighbours) and clamps vertically.
Shapes: ``...`` any batch shape; ``H W`` image size; ``C`` channels; ``N`` points.
"""

from __future__ import annotations

import functools
import math

import torch
import torch.nn.functional as F
from torch import Tensor


def pixel_to_lonlat(u: Tensor, v: Tensor, height: int, width: int) -> tuple[Tensor, Tensor]:
    """Pixel coordinates (centres at integers) -> (longitude, latitude) in radians."""
    lon = 2.0 * math.pi * ((u + 0.5) / width - 0.5)
    lat = math.pi * (0.5 - (v + 0.5) / height)
    return lon, lat


def lonlat_to_direction(lon: Tensor, lat: Tensor) -> Tensor:
    """(lon, lat) [...] radians -> unit direction [..., 3] in the camera frame."""
    cos_lat = torch.cos(lat)
    return torch.stack((cos_lat * torch.sin(lon), torch.sin(lat), -cos_lat * torch.cos(lon)), -1)


def direction_to_lonlat(d: Tensor) -> tuple[Tensor, Tensor]:
    """Direction [..., 3] (any length > 0) -> (lon in [-pi, pi], lat in [-pi/2, pi/2]).

    On the vertical axis (x = z = 0) longitude is undefined; it is then 0 (the centre column),
    and the gradients stay finite there instead of becoming NaN.
    """
    x, y, z = d.unbind(-1)
    r2 = x * x + z * z
    off_axis = r2 > torch.finfo(d.dtype).tiny
    # The `where`s keep atan2(0, 0) and sqrt'(0) out of the backward pass at the poles.
    lon = torch.atan2(x, torch.where(off_axis, -z, 1.0))
    horizontal = torch.where(off_axis, torch.sqrt(torch.where(off_axis, r2, 1.0)), 0.0)
    lat = torch.atan2(y, horizontal)
    return lon, lat


def lonlat_to_pixel(lon: Tensor, lat: Tensor, height: int, width: int) -> tuple[Tensor, Tensor]:
    """(lon, lat) radians -> continuous pixel coordinates (u, v), pixel centres at integers."""
    u = (lon / (2.0 * math.pi) + 0.5) * width - 0.5
    v = (0.5 - lat / math.pi) * height - 0.5
    return u, v


def pixel_to_direction(u: Tensor, v: Tensor, height: int, width: int) -> Tensor:
    """Pixel coordinates [...] -> unit direction [..., 3] in the camera frame."""
    return lonlat_to_direction(*pixel_to_lonlat(u, v, height, width))


def direction_to_pixel(d: Tensor, height: int, width: int) -> Tensor:
    """Direction [..., 3] -> continuous pixel coordinates [..., 2] as (u, v)."""
    u, v = lonlat_to_pixel(*direction_to_lonlat(d), height, width)
    return torch.stack((u, v), -1)


def erp_directions(
    height: int,
    width: int,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """Unit ray directions of every pixel centre of an H x W panorama, camera frame: [H, W, 3].

    Made once per size, device and type and shared (every render asks for the same few): do
    not modify the result in place."""
    device = torch.get_default_device() if device is None else torch.device(device)
    if device.type == "meta":
        return _directions(height, width, device, dtype)
    return _shared_directions(height, width, device, dtype)


@functools.lru_cache(maxsize=16)  # a few sizes per command: tens of megabytes at most
def _shared_directions(height: int, width: int, device: torch.device, dtype: torch.dtype) -> Tensor:
    # A plain tensor even when first asked for under no_grad or inference mode.
    with torch.inference_mode(False), torch.no_grad():
        return _directions(height, width, device, dtype)


def _directions(height: int, width: int, device: torch.device, dtype: torch.dtype) -> Tensor:
    return erp_direction_rows(height, width, 0, height, device=device, dtype=dtype)


def erp_direction_rows(
    height: int,
    width: int,
    first: int,
    last: int,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """Rows ``first`` to ``last`` (excluded) of `erp_directions` (height, width): [last -
    first, W, 3], the same values, made anew (a band of a panorama too large to hold whole)."""
    v, u = torch.meshgrid(
        torch.arange(first, last, device=device, dtype=dtype),
        torch.arange(width, device=device, dtype=dtype),
        indexing="ij",
    )
    return pixel_to_direction(u, v, height, width)


def latitude_weights(
    height: int,
    width: int,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """cos(latitude) of every pixel row, broadcast to [H, W]: the ERP solid-angle weight."""
    v = torch.arange(height, device=device, dtype=dtype)
    lat = math.pi * (0.5 - (v + 0.5) / height)
    return torch.cos(lat)[:, None].expand(height, width)


def transform_points(points: Tensor, matrix: Tensor) -> Tensor:
    """Apply a 4x4 rigid transform [..., 4, 4] to points [..., N, 3] -> [..., N, 3]."""
    return points @ matrix[..., :3, :3].transpose(-1, -2) + matrix[..., None, :3, 3]


def invert_rigid(c2w: Tensor) -> Tensor:
    """Exact inverse of rigid transforms [..., 4, 4] (rotation + translation), no matrix inverse."""
    rot_t = c2w[..., :3, :3].transpose(-1, -2)
    out = torch.zeros_like(c2w)
    out[..., :3, :3] = rot_t
    out[..., :3, 3] = -(rot_t @ c2w[..., :3, 3:4])[..., 0]
    out[..., 3, 3].fill_(1.0)  # a kernel's argument, not a copy from the host
    return out


def world_to_erp(points: Tensor, c2w: Tensor, height: int, width: int) -> tuple[Tensor, Tensor]:
    """Project world points [..., N, 3] into ERP cameras c2w [..., 4, 4].

    Returns pixel coordinates [..., N, 2] (u, v) and spherical depth [..., N] in metres.
    A point at the camera centre gets depth 0 and an arbitrary (finite) pixel.
    """
    cam = transform_points(points, invert_rigid(c2w))
    depth = torch.linalg.vector_norm(cam, dim=-1)
    return direction_to_pixel(cam, height, width), depth


def erp_to_world(depth: Tensor, c2w: Tensor) -> Tensor:
    """Lift spherical depth maps [..., H, W] (metres) of cameras c2w [..., 4, 4] to the world.

    Returns world points [..., H*W, 3] in row-major pixel order. The batch shapes of ``depth``
    and ``c2w`` broadcast: pass depth [V, H, W] with c2w [V, 4, 4] (not [V, 1, H, W]).
    """
    height, width = depth.shape[-2:]
    dirs = erp_directions(height, width, device=depth.device, dtype=depth.dtype).reshape(-1, 3)
    cam = dirs * depth.reshape(*depth.shape[:-2], -1, 1)
    return transform_points(cam, c2w)


def pad_seam(image: Tensor, pad: int = 1) -> Tensor:
    """[B, C, H, W] -> [B, C, H, W + 2 pad]: ``pad`` wrapped columns on each side, for
    `sample_padded` (pad once, sample many times; bicubic sampling needs 2)."""
    return torch.cat((image[..., -pad:], image, image[..., :pad]), dim=-1)


def sample_padded(padded: Tensor, uv: Tensor, mode: str = "bilinear", pad: int = 1) -> Tensor:
    """`sample_erp` on a panorama already padded by `pad_seam` with ``pad`` columns:
    [B, C, H, W + 2 pad] -> [B, C, N]. ``mode``: "bilinear", "nearest" or "bicubic" (pad 2)."""
    height, width = padded.shape[-2], padded.shape[-1] - 2 * pad
    grid = padded_grid(uv, height, width, pad)
    out = F.grid_sample(padded, grid, mode=mode, padding_mode="border", align_corners=False)
    return out[:, :, 0]


def padded_grid(uv: Tensor, height: int, width: int, pad: int = 1) -> Tensor:
    """Pixel coordinates [B, N, 2] of an H x W panorama -> ``F.grid_sample``'s grid [B, 1, N, 2]
    on it padded by `pad_seam` with ``pad`` columns (u wrapped into the image first)."""
    u = torch.remainder(uv[..., 0] + 0.5, width) - 0.5  # in [-0.5, W - 0.5)
    x = (u + 0.5 + pad) / (width + 2 * pad) * 2.0 - 1.0
    y = (uv[..., 1] + 0.5) / height * 2.0 - 1.0
    return torch.stack((x, y), -1)[:, None]


def sample_erp(image: Tensor, uv: Tensor, mode: str = "bilinear") -> Tensor:
    """Sample panoramas at continuous pixel coordinates, wrapping horizontally.

    image: [B, C, H, W]; uv: [B, N, 2] as (u, v), pixel centres at integers (u may be any
    real number: it is taken modulo W). Rows clamp at the poles (no vertical wrap).
    Returns [B, C, N]. ``mode``: "bilinear" or "nearest".
    """
    # One wrapped column on each side makes the seam an ordinary interior neighbour.
    return sample_padded(pad_seam(image), uv, mode)


def sample_erp_directions(image: Tensor, directions: Tensor, mode: str = "bilinear") -> Tensor:
    """Sample panoramas [B, C, H, W] along camera-frame directions [B, N, 3] -> [B, C, N]."""
    height, width = image.shape[-2:]
    return sample_erp(image, direction_to_pixel(directions, height, width), mode=mode)


def rotation_about(axis: str, angle: float) -> Tensor:
    """3x3 rotation (float64) about the x, y or z axis by ``angle`` radians (right-handed)."""
    c, s = math.cos(angle), math.sin(angle)
    if axis == "x":
        m = [[1, 0, 0], [0, c, -s], [0, s, c]]
    elif axis == "y":
        m = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    elif axis == "z":
        m = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    else:
        raise ValueError(f"axis must be 'x', 'y' or 'z', got {axis!r}")
    return torch.tensor(m, dtype=torch.float64, device="cpu")
