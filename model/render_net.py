"""The generalizable spherical radiance field's learned parts (PanoGRF section 3.1, NeuRay-style).

- `AppearanceEncoder`: a small residual U-Net with circular padding, image -> C-channel
  features at half the encoder's working resolution.
- `GeometryEncoder`: image + estimated depth -> per-pixel parameters of a mixture of two
  logistics over inverse depth, the *visibility* of any point along the source's rays.
- `Aggregator`: for every sample point and every source view, the view's appearance feature,
  projected colour, visibility, depth residual and relative view direction are encoded, pooled
  over views (visibility-weighted mean and variance, so any number of views works) and decoded
  to a density and to blending weights of the projected colours.

Everything here is per sample; the ray casting, projection and compositing are functions in
`panogrf.renderer`. Shapes: V views, N points, C channels.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import cast

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from panogrf.model.layers import CircularConv2d


@dataclass(frozen=True)
class RendererConfig:
    """Sizes of the renderer networks."""

    feature_channels: int = 16
    """Appearance feature channels (at half the encoder resolution)."""
    encoder_widths: tuple[int, ...] = (16, 24, 32)
    """Appearance U-Net widths at 1/2, 1/4, 1/8 of the encoder input."""
    geometry_width: int = 16
    """Width of the geometry encoder."""
    hidden: int = 48
    """Width of the aggregation MLPs."""
    view_channels: int = 24
    """Per-view code width inside the aggregator."""
    use_geometry: bool = True
    """Use the depth-derived visibility and residuals (False: the no-geometry ablation)."""
    encoder_height: int = 256
    """Panoramas are resized to this height (width 2x) for the appearance encoder."""


class RendererPreset(StrEnum):
    """A named configuration of the renderer networks (`PRESETS`)."""

    PANOGRF = "panogrf"
    """The shipped renderer."""
    NO_GEOMETRY = "no_geometry"
    """The ablation without the depth-derived visibility and residuals."""
    TINY = "tiny"
    """The model-size ladder's smaller rung."""
    LARGE = "large"
    """The model-size ladder's larger rung."""


PRESETS: dict[RendererPreset, RendererConfig] = {
    RendererPreset.PANOGRF: RendererConfig(),
    RendererPreset.NO_GEOMETRY: RendererConfig(use_geometry=False),
    # The model-size ladder's smaller rung: half the widths everywhere.
    RendererPreset.TINY: RendererConfig(
        feature_channels=8,
        encoder_widths=(8, 12, 16),
        geometry_width=8,
        hidden=24,
        view_channels=12,
    ),
    # The ladder's larger rung: one and a half times the widths everywhere.
    RendererPreset.LARGE: RendererConfig(
        feature_channels=24,
        encoder_widths=(24, 36, 48),
        geometry_width=24,
        hidden=72,
        view_channels=36,
    ),
}


def _conv(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(
        CircularConv2d(cin, cout, 3, stride=stride, padding=1, bias=False),
        nn.InstanceNorm2d(cout, affine=True),
        nn.ReLU(inplace=True),
    )


class _Res(nn.Module):
    def __init__(self, ch: int) -> None:
        super().__init__()
        self.body = nn.Sequential(_conv(ch, ch), CircularConv2d(ch, ch, 3, padding=1, bias=False))

    def forward(self, x: Tensor) -> Tensor:
        return F.relu(x + self.body(x))


class AppearanceEncoder(nn.Module):
    """Images [B, 3, H, W] in [0, 1] -> features [B, C, H/2, W/2] (residual U-Net)."""

    def __init__(self, widths: tuple[int, ...], out_channels: int) -> None:
        super().__init__()
        self.down = nn.ModuleList()
        cin = 3
        for w in widths:
            self.down.append(nn.Sequential(_conv(cin, w, stride=2), _Res(w)))
            cin = w
        self.up = nn.ModuleList(
            _conv(widths[i + 1] + widths[i], widths[i]) for i in range(len(widths) - 2, -1, -1)
        )
        self.out = CircularConv2d(widths[0], out_channels, 1)

    def forward(self, image: Tensor) -> Tensor:
        x = image * 2.0 - 1.0
        skips = []
        for stage in self.down:
            x = stage(x)
            skips.append(x)
        skips.pop()
        for up in self.up:
            skip = skips.pop()
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = up(torch.cat((x, skip), 1))
        out: Tensor = self.out(x)
        return out


class GeometryEncoder(nn.Module):
    """Image [B, 3, h, w] + depth [B, 1, h, w] (metres) -> visibility parameters [B, 6, h, w].

    The six channels are raw; `visibility` turns them into the mixture: two logistics over
    inverse depth x = 1/z with centres mu_k = x_D exp(0.3 tanh a_k) (x_D the estimated inverse
    depth), scales s_k = x_D (0.003 + 0.15 sigmoid b_k) and weights m = softmax(c).
    """

    def __init__(self, width: int) -> None:
        super().__init__()
        self.net = nn.Sequential(
            _conv(5, width),
            _conv(width, width),
            _conv(width, width),
            CircularConv2d(width, 6, 3, padding=1),
        )
        head = cast(CircularConv2d, self.net[-1])
        assert head.bias is not None  # made with one
        nn.init.zeros_(head.weight)
        nn.init.zeros_(head.bias)

    def forward(self, image: Tensor, depth: Tensor) -> Tensor:
        inv = 1.0 / depth.clamp(min=0.1)
        # Inverse depth relative to its local mean: edges and their side, scale-free.
        local = F.avg_pool2d(F.pad(inv, (2, 2, 2, 2), mode="replicate"), 5, stride=1)
        params: Tensor = self.net(torch.cat((image * 2.0 - 1.0, inv, inv / local - 1.0), 1))
        return params


def visibility(params: Tensor, depth: Tensor, z: Tensor) -> Tensor:
    """Visibility in [0, 1] of points at distance z from the source (metres).

    params [..., 6] (from `GeometryEncoder`, sampled at the points' pixels), depth [...] the
    source's estimated depth there, z [...]: 1 in front of the surface, falling to 0 behind.
    """
    x = 1.0 / z.clamp(min=1e-3)
    xd = 1.0 / depth.clamp(min=0.1)
    a, b, c = params[..., 0:2], params[..., 2:4], params[..., 4:6]
    mu = xd[..., None] * torch.exp(0.3 * torch.tanh(a))
    s = xd[..., None] * (0.003 + 0.15 * torch.sigmoid(b))
    m1 = torch.sigmoid(c[..., 0] - c[..., 1])  # softmax of two weights
    o = torch.sigmoid((mu - x[..., None]) / s)
    occlusion = m1 * o[..., 0] + (1.0 - m1) * o[..., 1]
    return 1.0 - occlusion


@dataclass
class PointFeatures:
    """What every source view says about N sample points: all [V, N, ...]."""

    appearance: Tensor  # [V, N, C]
    colour: Tensor  # [V, N, 3] projected source colour
    visibility: Tensor  # [V, N] in [0, 1]
    residual: Tensor  # [V, N] D_j / z_j - 1 (0 on the source's surface)
    direction: Tensor  # [V, N, 3] cos angle, |d_t - d_j|, log(z_j / t)


class Aggregator(nn.Module):
    """Per-view point features -> density [N] (1/m) and colour [N, 3].

    Each view's features are encoded by a small MLP; the codes are pooled over views
    (visibility-weighted mean and variance: the agreement of the views is the density cue);
    density is decoded from the pool, colour blends the projected source colours with weights
    from each view's code and the pool. Sized for a CPU: a few thousand multiply-adds per
    point and view.
    """

    def __init__(self, config: RendererConfig) -> None:
        super().__init__()
        self.config = config
        h, vc = config.hidden, config.view_channels
        cin = config.feature_channels + 3 + 3 + (3 if config.use_geometry else 0)
        self.view_mlp = nn.Sequential(
            nn.Linear(cin, h), nn.ReLU(inplace=True), nn.Linear(h, vc), nn.ReLU(inplace=True)
        )
        self.blend_view = nn.Linear(vc, 1)
        self.blend_pool = nn.Linear(2 * vc, 1, bias=False)
        self.density = nn.Sequential(
            nn.Linear(2 * vc + 1, h), nn.ReLU(inplace=True), nn.Linear(h, 1)
        )

    def forward(self, f: PointFeatures) -> tuple[Tensor, Tensor]:
        parts = [f.appearance, f.colour, f.direction]
        if self.config.use_geometry:
            r = f.residual[..., None]
            vis = f.visibility[..., None]
            parts += [vis, torch.tanh(5.0 * r), torch.tanh(50.0 * r)]
        else:
            vis = torch.ones_like(f.colour[..., :1])
        x = self.view_mlp(torch.cat(parts, -1))  # [V, N, vc]
        w = (vis + 1e-3) / (vis + 1e-3).sum(0, keepdim=True)
        mean = (w * x).sum(0)
        centred = x - mean
        pool = torch.cat((mean, (w * centred * centred).sum(0)), -1)  # [N, 2 vc]
        logit = self.blend_view(x) + self.blend_pool(pool) + torch.log(vis + 1e-3)
        e = torch.exp(logit - logit.amax(0))  # softmax over the (few) views, without its
        colour = (e * f.colour).sum(0) / e.sum(0)  # slow small-axis kernel: [N, 3]
        seen = vis.amax(0)  # [N, 1]: does any view see the point at all
        sigma = self.density(torch.cat((pool, seen), -1))[..., 0]
        return F.softplus(sigma - 1.0), colour


class RendererNet(nn.Module):
    """The renderer's three learned parts with their config."""

    def __init__(self, config: RendererConfig = RendererConfig()) -> None:
        super().__init__()
        self.config = config
        self.appearance = AppearanceEncoder(config.encoder_widths, config.feature_channels)
        self.geometry = GeometryEncoder(config.geometry_width) if config.use_geometry else None
        self.aggregator = Aggregator(config)
