"""Training-time corruptions of what real captures do to images and to the mono prior.

`photometric` changes each panorama as a real 360-degree camera does from shot to shot:
exposure (with highlights clipping), white balance, gamma, the falloff of the two fisheye
lenses towards their seam, sensor noise, slight blur and JPEG-like loss of detail, and a tripod
or operator blob at the nadir. Geometry is untouched, so depth and poses stay exact.

`corrupt_mono` makes the monocular depth wrong the ways it is wrong on real rooms (a wrong
global scale, smooth regions too near or too far), so the mono-guided MVS learns to check its
prior against the cost volume instead of copying it. It corrupts the depth only: the
monocular features that go with it stay as the network computed them. `out_of_domain` makes
the monocular network itself wrong, depth and features alike, the way a real room it never
learned makes it wrong: it sees a panorama blended with another one. `wrong_heights` makes
the monocular depth plausible but for the room's height: the ceiling and the floor too near or
too far, as on a real room whose ceiling is higher or lower than the rooms the network learned.
`seen_warped` goes further: the monocular network sees the panorama as a room of another
height (`room_warp`), so its depth and its features are wrong together, as on a real room.

All functions draw from a torch.Generator and work on batches [B, C, H, W].
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import Tensor

from panogrf.model.mono import MonoOutput


def _elevations(rows: int, dtype=torch.float32) -> Tensor:
    """Elevation (radians) of the centres of ``rows`` ERP rows, top first."""
    return math.pi * (0.5 - (torch.arange(rows, dtype=dtype) + 0.5) / rows)


def _u(gen: torch.Generator, b: int, lo: float, hi: float, *shape: int) -> Tensor:
    return lo + (hi - lo) * torch.rand(b, *shape, generator=gen)


def _smooth_field(gen: torch.Generator, b: int, h: int, w: int, cells: int = 4) -> Tensor:
    """Smooth random field [B, 1, H, W] in about [-1, 1], wrapping in width."""
    grid = torch.rand(b, 1, cells, 2 * cells, generator=gen) * 2 - 1
    grid = torch.cat((grid, grid[..., :1]), -1)  # wrap: the last column meets the first
    up = F.interpolate(grid, size=(h, w + w // (2 * cells)), mode="bicubic", align_corners=True)
    return up[..., :w]


def photometric(images: Tensor, gen: torch.Generator, strength: float = 1.0) -> Tensor:
    """Per-panorama camera corruptions of images [B, 3, H, W] in [0, 1] (a new tensor)."""
    b, _, h, w = images.shape
    x = images.clamp(0, 1) ** 2.2  # to linear light
    # Exposure (log-uniform, 0.55x - 1.8x) and white balance (+-12 % per channel).
    gain = torch.exp(_u(gen, b, math.log(0.55), math.log(1.8), 1, 1, 1) * strength)
    wb = 1 + strength * _u(gen, b, -0.12, 0.12, 3, 1, 1)
    x = x * gain * wb
    # Fisheye falloff: darker towards the stitching seam at longitude +-90 degrees.
    lon = (torch.arange(w) + 0.5) / w * 2 * math.pi - math.pi
    lat = _elevations(h)
    off_axis = torch.acos((torch.cos(lat)[:, None] * torch.cos(lon)[None]).abs().clamp(max=1))
    vignette = _u(gen, b, 0.0, 0.35 * strength, 1, 1, 1)
    x = x * (1 - vignette * (off_axis / (math.pi / 2)) ** 2)
    x = x.clamp(0, 1) ** (1 / 2.2)  # highlights clip, as a sensor does
    # Tone curve (gamma 0.8 - 1.25).
    x = x ** torch.exp(strength * _u(gen, b, -0.22, 0.22, 1, 1, 1))
    # Slight blur or JPEG-like block loss on some, then noise.
    soft = torch.rand(b, generator=gen) < 0.3 * strength
    if soft.any():
        blurred = F.avg_pool2d(F.pad(x[soft], (1, 1, 1, 1), mode="replicate"), 3, stride=1)
        x = x.clone()
        x[soft] = blurred
    x = x + torch.randn(x.shape, generator=gen) * _u(gen, b, 0.0, 0.02 * strength, 1, 1, 1)
    # A tripod / operator blob at the nadir on some panoramas.
    blob = torch.rand(b, generator=gen) < 0.3 * strength
    if blob.any():
        rows = (torch.arange(h) + 0.5) / h
        for i in torch.nonzero(blob).flatten().tolist():
            extent = float(_u(gen, 1, 0.04, 0.12))
            mask = (rows > 1 - extent).view(h, 1).expand(h, w)
            colour = _u(gen, 1, 0.05, 0.5, 3, 1)[0]
            x[i, :, mask] = colour.expand(-1, int(mask.sum()))
    return x.clamp(0, 1)


def corrupt_mono(depth: Tensor, gen: torch.Generator, p: float = 0.6) -> Tensor:
    """Monocular depth [B, 1, h, w] (metres) made wrong on a fraction ``p`` of the batch:
    a global scale of 0.7x - 1.4x times smooth regions off by up to +-40 %."""
    b, _, h, w = depth.shape
    hit = (torch.rand(b, 1, 1, 1, generator=gen) < p).to(depth.dtype)
    scale = torch.exp(_u(gen, b, math.log(0.7), math.log(1.4), 1, 1, 1))
    local = torch.exp(0.35 * _smooth_field(gen, b, h, w))
    wrong = depth * scale * local
    return hit * wrong + (1 - hit) * depth


def _smoothstep(x: Tensor) -> Tensor:
    x = x.clamp(0, 1)
    return x * x * (3 - 2 * x)


def wrong_heights(depth: Tensor, gen: torch.Generator, strength: float = 0.4) -> Tensor:
    """Monocular depth [B, 1, h, w] (metres, level cameras) with the ceiling and the floor put
    at wrong heights: the depth looking up scaled by exp(a), looking down by exp(b), a and b
    uniform in +-``strength`` per panorama, blended in smoothly between 12 and 44 degrees of
    elevation (the walls at the horizon keep their depth). A network that learned rooms of
    some heights puts a real room's ceiling where its rooms had theirs; the depth stays
    plausible, only the room's height is wrong, and a blank ceiling gives the cost volume
    nothing to correct it with."""
    b = depth.shape[0]
    a = _u(gen, b, -strength, strength, 1, 1, 1).to(depth.dtype)
    c = _u(gen, b, -strength, strength, 1, 1, 1).to(depth.dtype)
    return _heights_scaled(depth, a, c)


def _heights_scaled(depth: Tensor, up_log: Tensor, down_log: Tensor) -> Tensor:
    """``depth`` [B, 1, h, w] looking up scaled by exp(``up_log``), looking down by
    exp(``down_log``) ([B | 1, 1, 1, 1]), blended in between 12 and 44 degrees of elevation."""
    h = depth.shape[-2]
    lat = _elevations(h, depth.dtype)
    sin = torch.sin(lat).view(1, 1, h, 1)
    up, down = _smoothstep((sin - 0.2) / 0.5), _smoothstep((-sin - 0.2) / 0.5)
    return depth * torch.exp(up_log.to(depth.dtype) * up + down_log.to(depth.dtype) * down)


def out_of_domain(images: Tensor, gen: torch.Generator) -> Tensor:
    """Panoramas [B, 3, H, W] moved out of the monocular network's domain, for its input only:
    each blended (weight 0.35-0.55) with another panorama of the batch turned by a random yaw
    (itself, turned, in a batch of one). The network then sees structure that is not there and
    its depth and features are wrong together, as on a real room unlike anything it learned
    (`benchmarks/depth_fusion.py --mono-shift`, `depth_shift_before.json`: mean L1 0.198 ->
    0.466 m on 12 validation home scenes; the real dev triplet's, unblended: 0.434 m)."""
    b, _, _, w = images.shape
    other = images.roll(1, 0) if b > 1 else images
    shifts = (torch.rand(b, generator=gen) * w).long().tolist()
    other = torch.stack([o.roll(s, -1) for o, s in zip(other, shifts, strict=True)])
    alpha = _u(gen, b, 0.35, 0.55, 1, 1, 1)
    return (1 - alpha) * images + alpha * other


def mono_out_of_domain(partner: Tensor, gen: torch.Generator, features_only: bool = False):
    """A `MonoStage` (the depth chain's ``mono_stages``): the monocular network sees every view
    blended with ``partner``'s panoramas [V', 3, H, W] (another scene; the first V of them are
    used, resized to the input) by `out_of_domain`: its depth and features wrong together.
    ``features_only``: only its features are those of the blended view, its depth that of the
    view as it is."""

    def shifted(forward: Callable[[Tensor], MonoOutput], images: Tensor) -> MonoOutput:
        other = F.interpolate(partner[: len(images)], size=images.shape[-2:], mode="area")
        both = out_of_domain(torch.stack((images, other), 1).flatten(0, 1), gen)
        out = forward(both[0::2])
        if features_only:
            return MonoOutput(forward(images).depth, out.features)
        return out

    return shifted


def mono_depth_changed(change: Callable[[Tensor], Tensor]):
    """A `MonoStage`: the monocular depth is ``change(depth)`` at every call of the network;
    its features stay as computed."""

    def changed(forward: Callable[[Tensor], MonoOutput], images: Tensor) -> MonoOutput:
        out = forward(images)
        return MonoOutput(change(out.depth), out.features)

    return changed


def mono_wrong_heights(gen: torch.Generator, strength: float = 0.4, shared: bool = False):
    """A `MonoStage`: the monocular depth has its ceiling and floor at wrong heights
    (`wrong_heights`, one draw per call of the network); its features stay as computed.
    ``shared``: one draw now for every view and call instead, so the views read the same
    wrong room and agree with each other, as a real capture's views do (a per-view
    draw makes the views disagree, which the fusion's cross-view check sees)."""
    if not shared:
        return mono_depth_changed(lambda depth: wrong_heights(depth, gen, strength))
    a, c = _u(gen, 1, -strength, strength, 1, 1, 1), _u(gen, 1, -strength, strength, 1, 1, 1)
    return mono_depth_changed(lambda depth: _heights_scaled(depth, a, c))


def _rows_read_at(x: Tensor, elevation: Tensor) -> Tensor:
    """``x`` [B, C, H, W] (ERP) with each row read at ``elevation`` [B, H] (radians; bilinear
    between rows, columns unchanged)."""
    b, _, h, w = x.shape
    gx = torch.linspace(-1 + 1 / w, 1 - 1 / w, w, dtype=x.dtype, device=x.device)
    gy = (-2 / math.pi * elevation).to(x)  # a row centre's elevation e lies at y = -2 e / pi
    grid = torch.stack((gx.view(1, 1, w).expand(b, h, w), gy.view(b, h, 1).expand(b, h, w)), -1)
    return F.grid_sample(x, grid, mode="bilinear", padding_mode="border", align_corners=False)


def _warped_elevation(elevation: Tensor, up_log: Tensor, down_log: Tensor) -> Tensor:
    """atan(k tan e): where a point at elevation e [1 | B, H] appears when everything above the
    camera is exp(``up_log``) times as high and everything below exp(``down_log``) ([B])."""
    k = torch.where(elevation > 0, up_log[:, None].exp(), down_log[:, None].exp())
    return torch.atan(k * torch.tan(elevation))


def room_warp(images: Tensor, up_log: Tensor, down_log: Tensor, inverse: bool = False) -> Tensor:
    """Panoramas [B, C, H, W] of level cameras as they would look with the room's heights
    above the camera scaled by exp(``up_log``) and below by exp(``down_log``) ([B] each): a
    point at elevation e moves to atan(k tan e), its horizontal distance kept. Walls stretch or
    shrink vertically and the ceiling's corners move, as in a room of another height.
    ``inverse``: back from such a panorama (each row read where it went)."""
    h = images.shape[-2]
    e = _elevations(h, torch.float64)[None].expand(len(images), h)
    if inverse:
        source = _warped_elevation(e, up_log.double(), down_log.double())
    else:
        source = _warped_elevation(e, -up_log.double(), -down_log.double())
    return _rows_read_at(images, source)


#: Largest |log| of the factors `room_factors` draws (a room 0.74-1.35 times as high).
WARP_STRENGTH = 0.3


def room_factors(
    gen: torch.Generator, b: int, p: float = 1.0, strength: float = WARP_STRENGTH
) -> tuple[Tensor, Tensor]:
    """Log factors [b] above and below the camera for `room_warp`, uniform in +-``strength``,
    on a fraction ``p`` of the batch (0 on the rest: the room as it is; with ``p`` 1 nothing
    is drawn for it)."""
    if p >= 1:
        return _u(gen, b, -strength, strength), _u(gen, b, -strength, strength)
    hit = (torch.rand(b, generator=gen) < p).float()
    return hit * _u(gen, b, -strength, strength), hit * _u(gen, b, -strength, strength)


def seen_warped(forward, images: Tensor, up_log: Tensor, down_log: Tensor) -> MonoOutput:
    """What the monocular network ``forward`` returns for ``images`` shown as a room of other
    heights (`room_warp`), its depth and features read back at the images' own rows: a
    plausible room of the wrong height, depth and features wrong together."""
    out = forward(room_warp(images, up_log, down_log))
    return MonoOutput(
        room_warp(out.depth, up_log, down_log, inverse=True),
        room_warp(out.features, up_log, down_log, inverse=True),
    )


def mono_warped_room(gen: torch.Generator, strength: float = WARP_STRENGTH):
    """A `MonoStage`: the monocular network sees every panorama as a room of other heights
    (`seen_warped`, log factors uniform in +-``strength`` above and below the camera), as on a
    real room whose proportions the network did not learn (the triplet's ceiling): one draw
    now for every view and call, so the views see the same wrong room."""
    up, down = room_factors(gen, 1, strength=strength)

    def warped(forward: Callable[[Tensor], MonoOutput], images: Tensor) -> MonoOutput:
        b = len(images)
        return seen_warped(forward, images, up.expand(b), down.expand(b))

    return warped
