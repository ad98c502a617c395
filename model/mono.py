"""360-degree monocular depth: an ERP branch and a cubemap branch fused at every scale (UniFuse).

The ERP branch sees the whole panorama with circular padding in width; the cubemap branch sees
six undistorted 90-degree faces. At each encoder scale the cube features are resampled to the
ERP grid and fused into the ERP branch (unidirectional: cube -> ERP), as in UniFuse. A U-Net
decoder turns the fused features into spherical depth ``d_max * sigmoid(x)``; its mid-level
feature map is what the MVS decoder also reads (PanoGRF code).

Optionally (``MonoDepthConfig.trunk``) the first convolutions of an ImageNet-pretrained AlexNet,
frozen, add their features to the ERP branch at 1/4, 1/8 and 1/16: features learned from real
photographs, which carry over to real captures where features learned only from our synthetic
rooms do not. UniFuse and PanoGRF start from an ImageNet ResNet-18 for the same reason.

Sized for a 2-core CPU: a few hundred thousand parameters at 128 x 256.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, cast

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from panogrf.model.cubemap import face_directions
from panogrf.model.erp import direction_to_pixel, erp_directions
from panogrf.model.layers import CircularConv2d


@dataclass(frozen=True)
class MonoDepthConfig:
    """Size of the monocular depth network."""

    channels: tuple[int, ...] = (16, 32, 48, 80)
    """Encoder widths at 1/2 (stem), 1/4, 1/8, 1/16 of the input."""
    d_max: float = 10.0
    """Largest depth the network can output (metres)."""
    feature_channels: int = 24
    """Channels of the mid-level decoder feature map handed to the MVS decoder (at 1/2)."""
    trunk: int = 0
    """Convolutions (0-3) of an ImageNet-pretrained AlexNet, frozen, whose features join the
    ERP branch at 1/4, 1/8 and 1/16 (`PretrainedTrunk`). Features learned from real photographs
    carry over to real captures where features learned from our renders do not (the paper's
    mono network starts from an ImageNet ResNet-18 for the same reason). 0: none."""

    @classmethod
    def from_dict(cls, stored: dict[str, Any]) -> MonoDepthConfig:
        """The config as stored with trained weights (JSON: tuples came back as lists)."""
        fields: dict[str, Any] = {
            k: tuple(v) if isinstance(v, list) else v for k, v in stored.items()
        }
        return cls(**fields)


def _block(cin: int, cout: int, stride: int, circular: bool) -> nn.Sequential:
    conv = CircularConv2d if circular else nn.Conv2d
    return nn.Sequential(
        conv(cin, cout, 3, stride=stride, padding=1, bias=False),
        nn.BatchNorm2d(cout),
        nn.ReLU(inplace=True),
        conv(cout, cout, 3, padding=1, bias=False),
        nn.BatchNorm2d(cout),
        nn.ReLU(inplace=True),
    )


class _Encoder(nn.Module):
    def __init__(self, channels: tuple[int, ...], circular: bool) -> None:
        super().__init__()
        stages = [_block(3, channels[0], 2, circular)]  # full resolution is too dear on a CPU
        stages += [
            _block(a, b, 2, circular) for a, b in zip(channels[:-1], channels[1:], strict=True)
        ]
        self.stages = nn.ModuleList(stages)

    def forward(self, x: Tensor) -> list[Tensor]:
        feats = []
        for stage in self.stages:
            x = stage(x)
            feats.append(x)
        return feats


class CubeToErp(nn.Module):
    """Resample cube-face feature maps [B*6, C, F, F] onto an H x W ERP grid -> [B, C, H, W].

    The six faces are laid side by side and one `grid_sample` reads them; the sampling grid
    depends only on (F, H, W) and is cached.
    """

    def __init__(self) -> None:
        super().__init__()
        self._grids: dict[tuple[int, int, int, str, torch.dtype], Tensor] = {}

    def _grid(
        self, face: int, height: int, width: int, device: torch.device, dtype: torch.dtype
    ) -> Tensor:
        key = (face, height, width, str(device), dtype)
        if key not in self._grids:
            from panogrf.model.cubemap import face_rotations

            dirs = erp_directions(height, width, device="cpu", dtype=torch.float64)  # [H, W, 3]
            local = torch.einsum("kji,hwj->khwi", face_rotations(torch.float64), dirs)
            fwd = -local[..., 2]
            k = fwd.argmax(0)  # [H, W]
            loc = local.gather(0, k[None, ..., None].expand(1, height, width, 3))[0]
            fx = loc[..., 0] / -loc[..., 2]
            fy = -loc[..., 1] / -loc[..., 2]
            # x in the 6-face atlas: face k occupies [k, k+1) of 6 equal parts; stay inside it.
            half_texel = 1.0 / face
            fx = fx.clamp(-1 + half_texel, 1 - half_texel)
            fy = fy.clamp(-1 + half_texel, 1 - half_texel)
            gx = (k.double() + (fx + 1) / 2) / 6 * 2 - 1
            self._grids[key] = torch.stack((gx, fy), -1)[None].to(device, dtype)
        return self._grids[key]

    def forward(self, cube: Tensor, height: int, width: int) -> Tensor:
        bk, c, f, _ = cube.shape
        b = bk // 6
        atlas = cube.reshape(b, 6, c, f, f).permute(0, 2, 3, 1, 4).reshape(b, c, f, 6 * f)
        grid = self._grid(f, height, width, cube.device, cube.dtype).expand(b, -1, -1, -1)
        return F.grid_sample(
            atlas, grid, mode="bilinear", padding_mode="border", align_corners=False
        )


class ErpToCube(nn.Module):
    """Resample panoramas [B, C, H, W] to cube faces [B*6, C, F, F] (grid cached per size)."""

    def __init__(self) -> None:
        super().__init__()
        self._grids: dict[tuple[int, int, int, str, torch.dtype], Tensor] = {}

    def forward(self, erp: Tensor, face: int) -> Tensor:
        b, c, h, w = erp.shape
        key = (face, h, w, str(erp.device), erp.dtype)
        if key not in self._grids:
            dirs = face_directions(face, device="cpu", dtype=torch.float64)
            uv = direction_to_pixel(dirs, h, w)  # [6,F,F,2]
            gx = (uv[..., 0] + 0.5) / w * 2 - 1
            gy = (uv[..., 1] + 0.5) / h * 2 - 1
            self._grids[key] = (
                torch.stack((gx, gy), -1).reshape(1, 6 * face, face, 2).to(erp.device, erp.dtype)
            )
        grid = self._grids[key].expand(b, -1, -1, -1)
        # Face pixels never sit exactly on the seam, so "border" padding loses nothing here.
        out = F.grid_sample(erp, grid, mode="bilinear", padding_mode="border", align_corners=False)
        return out.reshape(b, c, 6, face, face).permute(0, 2, 1, 3, 4).reshape(b * 6, c, face, face)


# torchvision AlexNet ``features`` (in, out, kernel, stride, padding); a 3x3/2 max-pool follows
# the first two. The same layout as `panogrf.model.lpips` (whose weights fill it).
_ALEX = ((3, 64, 11, 4, 2), (64, 192, 5, 1, 2), (192, 384, 3, 1, 1))
# Input pixel on which output pixel 0 of each convolution is centred (output j: stride*j + this).
_CENTRE = (3, 7, 15)


class PretrainedTrunk(nn.Module):
    """The first ``layers`` AlexNet convolutions on an ERP image, frozen: ImageNet-normalised
    [B, 3, H, W] -> feature maps at 1/4, 1/8, 1/16 (ReLU after each convolution).

    ERP wraps in width: the image is padded circularly by ``wrap`` pixels before the trunk and
    the features are resampled at the centres of the 1/4, 1/8, 1/16 grids. Its weights come
    from the bundled LPIPS AlexNet (``convs.{i}.*``), put in by the code that trains or loads the
    network (weights files leave them out); they never train (``requires_grad`` off, no batch
    norm inside).
    """

    wrap = 64  # > half the receptive field of the third convolution (99 px): seamless

    def __init__(self, layers: int) -> None:
        super().__init__()
        self.convs = nn.ModuleList(
            nn.Conv2d(cin, cout, k, stride=s, padding=p) for cin, cout, k, s, p in _ALEX[:layers]
        )
        self.requires_grad_(False)

    def projections(self, widths: list[int]) -> nn.ModuleList:
        """1x1 convolutions from each trunk level to ``widths``, zero-initialised: a network
        with the trunk added starts out as the network without it."""
        projs = [
            nn.Conv2d(cast(nn.Conv2d, conv).out_channels, w, 1)
            for conv, w in zip(self.convs, widths, strict=True)
        ]
        for proj in projs:
            assert proj.bias is not None  # made with one
            nn.init.zeros_(proj.weight)
            nn.init.zeros_(proj.bias)
        return nn.ModuleList(projs)

    def forward(self, x: Tensor) -> list[Tensor]:
        h, w = x.shape[-2:]
        p = self.wrap
        y = torch.cat((x[..., -p:], x, x[..., :p]), -1)
        feats = []
        for i, conv in enumerate(self.convs):
            if i > 0:
                y = F.max_pool2d(y, 3, 2)
            y = F.relu(conv(y))
            feats.append(self._on_grid(y, 4 * 2**i, _CENTRE[i], h, w))
        return feats

    def _on_grid(self, y: Tensor, stride: int, centre: int, h: int, w: int) -> Tensor:
        """Feature map y (output column j centred on padded input pixel stride * j + centre)
        sampled at the centres of the h/stride x w/stride grid of the unpadded image. The
        offset is the same for every cell, so a turn by a multiple of ``stride`` pixels turns
        the result by whole cells."""
        rows, cols = y.shape[-2:]
        gy = (
            stride * torch.arange(h // stride, device=y.device) + (stride - 1) / 2 - centre
        ) / stride
        gx = (
            stride * torch.arange(w // stride, device=y.device)
            + (stride - 1) / 2
            + self.wrap
            - centre
        ) / stride
        grid = torch.stack(
            (
                (2 * gx / max(cols - 1, 1) - 1)[None, :].expand(len(gy), -1),
                (2 * gy / max(rows - 1, 1) - 1)[:, None].expand(-1, len(gx)),
            ),
            -1,
        ).to(y)
        grid = grid[None].expand(y.shape[0], -1, -1, -1)
        return F.grid_sample(y, grid, mode="bilinear", padding_mode="border", align_corners=True)


class _Fuse(nn.Module):
    """ERP <- cube fusion at one scale: the ERP feature plus a gated projection of both."""

    def __init__(self, ch: int) -> None:
        super().__init__()
        self.mix = nn.Sequential(
            CircularConv2d(2 * ch, ch, 3, padding=1, bias=False),
            nn.BatchNorm2d(ch),
            nn.ReLU(inplace=True),
        )
        self.gate = nn.Sequential(CircularConv2d(2 * ch, ch, 1), nn.Sigmoid())

    def forward(self, erp: Tensor, cube_on_erp: Tensor) -> Tensor:
        both = torch.cat((erp, cube_on_erp), 1)
        out: Tensor = erp + self.gate(both) * self.mix(both)
        return out


class _Up(nn.Module):
    def __init__(self, cin: int, skip: int, cout: int) -> None:
        super().__init__()
        self.conv = _block(cin + skip, cout, 1, circular=True)

    def forward(self, x: Tensor, skip: Tensor) -> Tensor:
        x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
        out: Tensor = self.conv(torch.cat((x, skip), 1))
        return out


@dataclass
class MonoOutput:
    depth: Tensor  # [B, 1, H, W] spherical depth, metres, in (0, d_max)
    features: Tensor  # [B, feature_channels, H/2, W/2] last decoder features (at 1/2)


#: A stage a training (or a benchmark) inserts around the monocular network in one call of
#: the depth chain (`panogrf.model.depth.DepthEstimator`'s ``mono_stages``): given the network
#: (or the stage inside it) and the images, what the chain reads as the network's output.
MonoStage = Callable[[Callable[[Tensor], MonoOutput], Tensor], MonoOutput]


class MonoDepthNet(nn.Module):
    """ERP image [B, 3, H, W] in [0, 1] (W = 2H, H divisible by 32) -> `MonoOutput`."""

    mean: Tensor  # buffers (`register_buffer`)
    std: Tensor

    def __init__(self, config: MonoDepthConfig = MonoDepthConfig()) -> None:
        super().__init__()
        self.config = config
        ch = config.channels
        self.erp_encoder = _Encoder(ch, circular=True)
        self.cube_encoder = _Encoder(ch, circular=False)
        self.fuse = nn.ModuleList(_Fuse(c) for c in ch)
        if config.trunk:
            if not 0 < config.trunk <= len(_ALEX) or config.trunk > len(ch) - 1:
                raise ValueError(f"trunk must be 0-{min(len(_ALEX), len(ch) - 1)}")
            self.trunk = PretrainedTrunk(config.trunk)
            self.from_trunk = self.trunk.projections(list(ch[1 : 1 + config.trunk]))
        self.to_cube = ErpToCube()
        self.to_erp = CubeToErp()
        ups = []
        for i in range(len(ch) - 1, 0, -1):
            ups.append(_Up(ch[i], ch[i - 1], ch[i - 1]))
        self.ups = nn.ModuleList(ups)
        self.feature_head = CircularConv2d(ch[0], config.feature_channels, 1)
        self.head = CircularConv2d(ch[0], 1, 3, padding=1)
        mean = torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)
        std = torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)
        self.register_buffer("mean", mean, persistent=False)
        self.register_buffer("std", std, persistent=False)

    def forward(self, image: Tensor) -> MonoOutput:
        b, _, h, w = image.shape
        if w != 2 * h or h % 32:
            raise ValueError(f"expected W = 2H with H divisible by 32, got {w}x{h} (W x H)")
        x = (image - self.mean) / self.std
        erp_feats = self.erp_encoder(x)
        cube_feats = self.cube_encoder(self.to_cube(x, h // 2))  # faces of H/2: same sampling
        fused = []
        for erp_f, cube_f, fuse in zip(erp_feats, cube_feats, self.fuse, strict=True):
            fused.append(fuse(erp_f, self.to_erp(cube_f, *erp_f.shape[-2:])))
        if self.config.trunk:
            with torch.no_grad():
                pre = self.trunk(x)
            for i, (feat, proj) in enumerate(zip(pre, self.from_trunk, strict=True)):
                fused[i + 1] = fused[i + 1] + proj(feat)
        y = fused[-1]
        for up, skip in zip(self.ups, reversed(fused[:-1]), strict=True):
            y = up(y, skip)
        logits = F.interpolate(self.head(y), size=(h, w), mode="bilinear", align_corners=False)
        depth = self.config.d_max * torch.sigmoid(logits)
        return MonoOutput(depth=depth, features=self.feature_head(y))
