"""360-degree multi-view stereo with mono-guided depth candidates (PanoGRF section 3.2).

For every reference pixel, D = N_mono + N_uni candidate depths: N_mono around the monocular
depth mu at equal-probability-mass offsets of a Gaussian (sigma, truncated at +-beta sigma),
N_uni uniform in [d_min, d_max], sorted per pixel. The 3D point at each candidate is moved into
every source camera, projected to ERP (with wrap) and the source feature sampled; the cost is
|f_src - f_ref|, averaged over sources. A 3D U-Net (circular padding in width) regularises the
volume; a 2D decoder turns it, the soft-argmin depth and (mono-guided preset) the monocular
features into depth.

Shapes: B batch, S sources, C channels, D candidates, h w the volume grid (1/4 of the input).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from panogrf.model.depth_config import DepthMode
from panogrf.model.erp import direction_to_pixel, erp_directions, invert_rigid, sample_erp
from panogrf.model.layers import CircularConv2d


@dataclass(frozen=True)
class MVSConfig:
    """Candidates and network sizes of the 360-degree MVS."""

    n_mono: int = 5
    """Candidates around the monocular depth (0: no mono guidance)."""
    n_uni: int = 59
    """Candidates uniform (linear) in [d_min, d_max]."""
    sigma: float = 0.5
    """Standard deviation (metres) of the Gaussian around the monocular depth."""
    beta: float = 3.0
    """Truncation of that Gaussian, in sigmas."""
    d_min: float = 0.1
    """Smallest candidate depth (metres)."""
    d_max: float = 10.0
    """Largest candidate depth (metres)."""
    feature_channels: int = 16
    """Matching feature channels."""
    cost_groups: int = 4
    """Cost-volume channels: |f_src - f_ref| averaged within this many channel groups."""
    volume_channels: tuple[int, ...] = (8, 16, 24, 32)
    """3D U-Net widths at 1, 1/2, 1/4, 1/8 of the volume."""
    use_mono: bool = True
    """Feed the monocular depth and features to the decoder."""
    mono_feature_channels: int = 24
    """Channels of the monocular feature map (MonoDepthConfig.feature_channels)."""
    trunk: int = 0
    """Frozen ImageNet AlexNet convolutions (0-2; `panogrf.model.mono.PretrainedTrunk`) whose
    features at 1/4 (and 1/8) join the matching features: features learned from real
    photographs, which match real captures where features learned from our renders do not."""

    @property
    def num_candidates(self) -> int:
        return self.n_mono + self.n_uni


#: The MVS networks, by the depth mode that runs each as its own: mode full the mono-guided
#: one, mode mvs the unguided one (which mode full also runs, for the fusion).
PRESETS: dict[DepthMode, MVSConfig] = {
    DepthMode.FULL: MVSConfig(),
    DepthMode.MVS: MVSConfig(n_mono=0, n_uni=64, use_mono=False),
}


def mono_offsets(n_mono: int, beta: float = 3.0, dtype: torch.dtype = torch.float64) -> Tensor:
    """Offsets b_k (in sigmas) of the mono-guided candidates, PanoGRF eq. 4: [n_mono].

    The Gaussian truncated at +-beta holds probability P* = erf(beta / sqrt 2); it is cut into
    n_mono bins of equal mass P*/n_mono, and b_k is the mid-point of the probits at the edges of
    bin k. For n_mono = 5, beta = 3: [-1.9194, -0.5457, 0, 0.5457, 1.9194].
    """
    if n_mono <= 0:
        return torch.zeros(0, dtype=dtype, device="cpu")
    p_star = math.erf(beta / math.sqrt(2.0))
    edges = (1.0 - p_star) / 2.0 + p_star * torch.arange(
        n_mono + 1, dtype=torch.float64, device="cpu"
    ) / n_mono
    probit: Tensor = math.sqrt(2.0) * torch.special.erfinv(2.0 * edges - 1.0)
    return (0.5 * (probit[:-1] + probit[1:])).to(dtype)


def depth_candidates(
    mu: Tensor | None,
    config: MVSConfig,
    size: tuple[int, int] | None = None,
    *,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """Per-pixel sorted candidate depths [B, D, h, w] (metres).

    mu: monocular depth [B, 1, h, w] (needed when n_mono > 0); ``size`` (h, w), ``device``,
    ``dtype`` and a batch of 1 are used when mu is None.
    """
    if config.n_mono > 0 and mu is None:
        raise ValueError("mono-guided candidates need the monocular depth mu")
    if mu is None:
        if size is None:
            raise ValueError("depth_candidates needs mu or size")
        ref = torch.zeros(1, 1, *size, device=device, dtype=dtype)
    else:
        ref = mu
    b, _, h, w = ref.shape
    uni = torch.linspace(
        config.d_min, config.d_max, config.n_uni, device=ref.device, dtype=ref.dtype
    )
    cands = [uni.view(1, -1, 1, 1).expand(b, -1, h, w)]
    if config.n_mono > 0:
        assert mu is not None  # checked above
        off = mono_offsets(config.n_mono, config.beta, mu.dtype).to(mu.device).view(1, -1, 1, 1)
        cands.insert(0, (mu + off * config.sigma).clamp(config.d_min, config.d_max))
    return torch.sort(torch.cat(cands, 1), dim=1).values


def cost_volume(
    ref_feat: Tensor,  # [B, C, h, w]
    src_feat: Tensor,  # [B, S, C, h, w]
    ref_c2w: Tensor,  # [B, 4, 4]
    src_c2w: Tensor,  # [B, S, 4, 4]
    candidates: Tensor,  # [B, D, h, w]
    src_weight: Tensor,  # [B, S] 1 for a usable source, 0 to ignore it
    groups: int | None = None,
) -> Tensor:
    """Mean over sources of |f_src - f_ref| at every candidate: [B, G, D, h, w].

    With ``groups`` G the C channels' absolute differences are averaged within G groups (a
    cheaper volume for the 3D network); without, G = C.
    """
    b, c, h, w = ref_feat.shape
    s = src_feat.shape[1]
    d = candidates.shape[1]
    dirs = erp_directions(h, w, device=ref_feat.device, dtype=ref_feat.dtype)  # [h, w, 3]
    pts = candidates[..., None] * dirs  # [B, D, h, w, 3] reference camera frame
    pts = pts.reshape(b, -1, 3)
    g = groups or c
    if c % g:
        raise ValueError(f"groups={g} must divide the {c} feature channels")
    total = ref_feat.new_zeros(b, g, d, h, w)
    for j in range(s):
        rel = invert_rigid(src_c2w[:, j]) @ ref_c2w  # reference camera -> source camera
        p = pts @ rel[:, :3, :3].transpose(1, 2) + rel[:, None, :3, 3]
        uv = direction_to_pixel(p, h, w)
        sampled = sample_erp(src_feat[:, j], uv).reshape(b, c, d, h, w)
        diff = (sampled - ref_feat[:, :, None]).abs()
        if g != c:
            diff = diff.reshape(b, g, c // g, d, h, w).mean(2)
        total = total + diff * src_weight[:, j].view(b, 1, 1, 1, 1)
    return total / src_weight.sum(1).clamp(min=1.0).view(b, 1, 1, 1, 1)


class _CircConv3d(nn.Module):
    """k x k x k conv + BN + ReLU over [B, C, D, h, w], wrapping in w, zero padding in D and h."""

    def __init__(self, cin: int, cout: int, stride: int = 1, kernel: int = 3) -> None:
        super().__init__()
        pad = kernel // 2
        self.pad = pad
        self.conv = nn.Conv3d(cin, cout, kernel, stride=stride, padding=(pad, pad, 0), bias=False)
        self.post = nn.Sequential(nn.BatchNorm3d(cout), nn.ReLU(inplace=True))

    def forward(self, x: Tensor) -> Tensor:
        if self.pad:
            x = torch.cat((x[..., -self.pad :], x, x[..., : self.pad]), -1)
        out: Tensor = self.post(self.conv(x))
        return out


class CostRegularizer(nn.Module):
    """3D U-Net (3 down, 3 up): volume [B, C, D, h, w] -> logits [B, D, h, w].

    3x3x3 convolutions run at 1/2 of the volume and below; at full resolution only 1x1x1 mixing
    (3D convolutions are the bulk of a CPU's training time).
    """

    def __init__(self, cin: int, widths: tuple[int, ...]) -> None:
        super().__init__()
        self.inp = _CircConv3d(cin, widths[0], kernel=1)
        self.down = nn.ModuleList(
            nn.Sequential(_CircConv3d(a, b, stride=2), _CircConv3d(b, b))
            for a, b in zip(widths[:-1], widths[1:], strict=True)
        )
        # Upsampled coarse features are projected to the skip's width and added to it.
        self.lift = nn.ModuleList(
            nn.Conv3d(b, a, 1) for a, b in zip(widths[:-1], widths[1:], strict=True)
        )
        self.up = nn.ModuleList(_CircConv3d(a, a) for a in widths[1:-1])
        self.out = nn.Sequential(nn.ReLU(inplace=True), nn.Conv3d(widths[0], 1, 1))

    def forward(self, x: Tensor) -> Tensor:
        x = self.inp(x)
        skips = [x]
        for down in self.down:
            x = down(x)
            skips.append(x)
        skips.pop()
        for level in range(len(skips) - 1, -1, -1):
            skip = skips[level]
            x = F.interpolate(x, size=skip.shape[-3:], mode="trilinear", align_corners=False)
            x = skip + self.lift[level](x)
            if level > 0:
                x = self.up[level - 1](x)
        logits: Tensor = self.out(x)[:, 0]
        return logits


def _conv2(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(
        CircularConv2d(cin, cout, 3, stride=stride, padding=1, bias=False),
        nn.BatchNorm2d(cout),
        nn.ReLU(inplace=True),
    )


@dataclass
class MVSOutput:
    depth: Tensor  # [B, 1, H, W] metres at the input resolution
    expected: Tensor  # [B, 1, H, W] soft-argmin depth of the regularised volume
    probability: Tensor  # [B, D, h, w] softmax over candidates
    candidates: Tensor  # [B, D, h, w]


class MVSNet(nn.Module):
    """Reference + source panoramas (and the monocular output) -> reference depth."""

    mean: Tensor  # buffers (`register_buffer`)
    std: Tensor

    def __init__(self, config: MVSConfig = MVSConfig()) -> None:
        super().__init__()
        self.config = config
        fc = config.feature_channels
        self.feat_half = nn.Sequential(_conv2(3, fc, 2), _conv2(fc, fc))  # 1/2
        self.feat_quarter = nn.Sequential(
            _conv2(fc, fc, 2), _conv2(fc, fc), CircularConv2d(fc, fc, 1)
        )
        if config.trunk:
            from panogrf.model.mono import PretrainedTrunk

            if not 0 < config.trunk <= 2:
                raise ValueError("MVS trunk must be 0-2")
            self.trunk = PretrainedTrunk(config.trunk)
            self.from_trunk = self.trunk.projections([fc] * config.trunk)
        self.regularizer = CostRegularizer(config.cost_groups, config.volume_channels)
        d = config.num_candidates
        mono_in = 1 + config.mono_feature_channels if config.use_mono else 0
        self.dec_quarter = nn.Sequential(
            _conv2(d + 1 + (1 if config.use_mono else 0), 32), _conv2(32, 32)
        )
        self.dec_half = nn.Sequential(
            _conv2(32 + fc + 1 + mono_in, 32), _conv2(32, 16), CircularConv2d(16, 1, 3, padding=1)
        )
        mean = torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)
        std = torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)
        self.register_buffer("mean", mean, persistent=False)
        self.register_buffer("std", std, persistent=False)

    def features(self, image: Tensor) -> tuple[Tensor, Tensor]:
        """Matching features at 1/4 and decoder features at 1/2 of [B, 3, H, W]."""
        x = (image - self.mean) / self.std
        half = self.feat_half(x)
        quarter = self.feat_quarter(half)
        if self.config.trunk:
            with torch.no_grad():
                pre = self.trunk(x)
            for feat, proj in zip(pre, self.from_trunk, strict=True):
                up = proj(feat)
                if up.shape[-2:] != quarter.shape[-2:]:
                    up = F.interpolate(up, size=quarter.shape[-2:], mode="bilinear")
                quarter = quarter + up
        return quarter, half

    def forward(
        self,
        ref_image: Tensor,  # [B, 3, H, W] in [0, 1]
        src_images: Tensor,  # [B, S, 3, H, W]
        ref_c2w: Tensor,  # [B, 4, 4]
        src_c2w: Tensor,  # [B, S, 4, 4]
        src_weight: Tensor | None = None,  # [B, S]
        mono_depth: Tensor | None = None,  # [B, 1, H, W]
        mono_features: Tensor | None = None,  # [B, Cm, H/2, W/2]
    ) -> MVSOutput:
        cfg = self.config
        b, s = src_images.shape[:2]
        h, w = ref_image.shape[-2:]
        if cfg.use_mono and (mono_depth is None or mono_features is None):
            raise ValueError("this MVS preset reads the monocular depth and features")
        if src_weight is None:
            src_weight = ref_image.new_ones(b, s)
        feats_q, feats_h = self.features(
            torch.cat((ref_image[:, None], src_images), 1).flatten(0, 1)
        )
        feats_q = feats_q.unflatten(0, (b, s + 1))
        hq, wq = feats_q.shape[-2:]
        mu_q = None
        if mono_depth is not None:
            mu_q = F.interpolate(mono_depth, size=(hq, wq), mode="area")
        cands = depth_candidates(
            mu_q if cfg.n_mono > 0 else None,
            cfg,
            (hq, wq),
            device=ref_image.device,
            dtype=ref_image.dtype,
        )
        cands = cands.expand(b, -1, -1, -1)
        volume = cost_volume(
            feats_q[:, 0], feats_q[:, 1:], ref_c2w, src_c2w, cands, src_weight, cfg.cost_groups
        )
        logits = self.regularizer(volume)  # [B, D, hq, wq]
        prob = torch.softmax(logits, 1)
        expected = (prob * cands).sum(1, keepdim=True)
        scale = 1.0 / cfg.d_max
        xs = [logits, expected * scale]
        if cfg.use_mono:
            assert mu_q is not None  # use_mono: mono_depth is given (checked above)
            xs.append(mu_q * scale)
        x = self.dec_quarter(torch.cat(xs, 1))
        hh, wh = feats_h.shape[-2:]
        x = F.interpolate(x, size=(hh, wh), mode="bilinear", align_corners=False)
        expected_h = F.interpolate(expected, size=(hh, wh), mode="bilinear", align_corners=False)
        y = [x, feats_h.unflatten(0, (b, s + 1))[:, 0], expected_h * scale]
        if cfg.use_mono:
            assert mono_depth is not None and mono_features is not None  # checked above
            y += [F.interpolate(mono_depth, size=(hh, wh), mode="area") * scale, mono_features]
        depth_h = (expected_h + self.dec_half(torch.cat(y, 1))).clamp(cfg.d_min, cfg.d_max)
        up: dict[str, Any] = dict(size=(h, w), mode="bilinear", align_corners=False)
        return MVSOutput(
            depth=F.interpolate(depth_h, **up),
            expected=F.interpolate(expected, **up),
            probability=prob,
            candidates=cands,
        )
