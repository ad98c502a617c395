"""A learned blend of the fused MVS depth with the monocular depth, pixel by pixel.

Mode "full" ends with the mono-guided and the unguided MVS depth fused by the photometric
sweep (`panogrf.model.select`). With the views 2-5 m apart, as real homes are captured, that
fused depth and the monocular network's fail in different places: the sources see a wall
under very different angles or not at all, while one panorama alone still shows a plausible
room. On the wide validation homes (6 scenes each, first and last view) the fused depth scores
0.147 / 0.157 / 0.259 m, the monocular depth 0.153 / 0.222 / 0.228, and the better of the two
per pixel 0.084 / 0.099 / 0.136 (`lab/analysis.md`).

`DepthBlend` predicts, per pixel, a weight a in [0, 1] and the depth becomes
exp((1 - a) log fused + a log mono). It sees what says which one to trust there
(`blend_features`): how well the nearest sources match at each depth (the photometric cost),
whether each depth reappears in the sources' own depths (`cross_view_consistency`), the
parallax the sources give at that pixel (none towards the baseline's ends, little far away),
how far apart the two depths are, and the image's brightness, texture and elevation, plus a
summary of the whole panorama. It is trained on the training scenes (`panogrf train blend`)
to the L1 of the blended depth, with the monocular network out of its domain on some of them,
so that a wrong prior is among what it sees. It starts near a = 0 (the fused depth).

Measured on the validation sets (`benchmarks/depth_fusion.py`, `depth_blend24_val.json`;
each set clean and with the monocular network out of its domain): mean L1 over the three wide
sets 0.1907 -> 0.1679 m, over five others 0.1535 -> 0.1388, every column lower, for 1.06 times
the time per pair of views.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, cast

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from panogrf.model.erp import erp_directions, erp_to_world, latitude_weights
from panogrf.model.select import dilated_trunk, local_std, scene_summary

if TYPE_CHECKING:
    from panogrf.model.sweep import SweepConfig

#: Channels of `blend_features`.
FEATURES = 11
#: Parallax (radians) at which the feature saturates.
PARALLAX_CAP = 0.5


@dataclass(frozen=True)
class BlendConfig:
    """Size of the blend network."""

    channels: int = 32
    """Width of the hidden layers."""
    rows: int = 128
    """Rows at which the features are pooled and the weight is predicted."""


def parallax(log_depth: Tensor, c2w: Tensor, r: int, sources: list[int]) -> Tensor:
    """The largest angle [h, w] (radians, at most `PARALLAX_CAP`) under which view ``r`` and
    one of its ``sources`` see the point that the depth [h, w] (log metres) puts at each pixel
    of view r; c2w [V, 4, 4]. Small: the sources cannot tell its depth."""
    h, w = log_depth.shape
    points = erp_to_world(torch.exp(log_depth), c2w[r].to(log_depth))  # [h*w, 3]
    to_ref = c2w[r, :3, 3].to(points) - points
    best = torch.zeros(h * w, dtype=log_depth.dtype, device=log_depth.device)
    for s in sources:
        to_src = c2w[s, :3, 3].to(points) - points
        cos = F.cosine_similarity(to_ref, to_src, dim=-1, eps=1e-6)
        best = torch.maximum(best, torch.acos(cos.clamp(-1.0, 1.0)))
    return best.clamp(max=PARALLAX_CAP).reshape(h, w)


def blend_features(
    image: Tensor,  # [3, H, W] the reference view in [0, 1], at the cost's resolution
    cost: Tensor,  # [2, H, W] the photometric cost at the fused and at the monocular depth
    log_fused: Tensor,  # [h, w] log metres
    log_mono: Tensor,  # [h, w] log metres
    consistency: Tensor,  # [2, h, w] `cross_view_consistency` of the fused and the mono depth
    parallax_rad: Tensor,  # [h, w] `parallax` at the fused depth
    rows: int = 128,
) -> Tensor:
    """`DepthBlend`'s input [FEATURES, rows, 2 rows]."""
    h, w = log_fused.shape
    gray = image.mean(0, keepdim=True)[None]
    pixels = torch.cat([cost, gray[0] - 0.5, local_std(gray)[0] * 4])  # [4, H, W]
    if pixels.shape[-2:] != (h, w):
        pixels = F.interpolate(pixels[None], size=(h, w), mode="area")[0]
    feats = torch.cat(
        [
            pixels[:2],
            (pixels[1] - pixels[0])[None],
            (log_mono - log_fused)[None],
            log_fused[None] / 2.3,
            consistency,
            parallax_rad[None] / PARALLAX_CAP,
            pixels[2:],
            latitude_weights(h, w, dtype=log_fused.dtype, device=log_fused.device)[None],
        ]
    )
    if h != rows:
        feats = F.interpolate(feats[None], size=(rows, 2 * rows), mode="area")[0]
    return feats


class DepthBlend(nn.Module):
    """Blend features [B, FEATURES, h, w] -> logit [B, 1, h, w] of the monocular depth's
    weight."""

    def __init__(self, config: BlendConfig = BlendConfig()) -> None:
        super().__init__()
        self.config = config
        c = config.channels
        self.net = dilated_trunk(FEATURES, c)
        self.context = nn.Linear(c, c)
        """A scene-wide summary (the latitude-weighted mean of the hidden features) added to
        every pixel's: whether the prior holds is a property of the whole capture."""
        with torch.no_grad():
            cast(Tensor, self.net[-1].bias).fill_(-3.0)  # starts at the fused depth

    def forward(self, features: Tensor) -> Tensor:
        hidden = self.net[:4](features)
        hidden = hidden + self.context(scene_summary(hidden))[..., None, None]
        logit: Tensor = self.net[4:](hidden)
        return logit

    def blend(self, features: Tensor, log_fused: Tensor, log_mono: Tensor) -> Tensor:
        """The blended log depth [B, h, w] of log_fused, log_mono [B, h, w] (the weight made
        at the features' rows, resized to the depth's)."""
        logit: Tensor = self(features)
        if logit.shape[-2:] != log_fused.shape[-2:]:
            logit = F.interpolate(
                logit, size=log_fused.shape[-2:], mode="bilinear", align_corners=False
            )
        a = torch.sigmoid(logit[:, 0])
        return log_fused + a * (log_mono - log_fused)


def blend_views(
    blend: DepthBlend | None,
    pixels: Tensor,
    c2w: Tensor,
    depth: Tensor,
    mono: Tensor,
    sources: list[list[int]],
    sweep: SweepConfig,
    d_max: float,
    scale: float,
    record: list[dict[str, Any]] | None = None,
) -> Tensor:
    """``depth`` [V, 1, h, w] (clean, metres) blended with the monocular depth ``mono`` by
    ``blend``, every view with sources (``sources``: those the sweep compared it with; the
    photometric costs at ``sweep``'s rows, `panogrf.model.sweep.cost_at`); recorded into
    ``record`` instead (with the world's ``scale``) when that is a list."""
    from panogrf.model.progress import stage
    from panogrf.model.select import cross_view_consistency
    from panogrf.model.sweep import cost_at

    hh, ww = sweep.height, 2 * sweep.height
    mode = "area" if pixels.shape[-2] > hh else "bilinear"
    img = F.interpolate(pixels, size=(hh, ww), mode=mode)
    dirs = erp_directions(hh, ww, device=depth.device, dtype=depth.dtype)
    d_range = (0.05, d_max)
    logs = torch.log(torch.stack((depth, mono), 1)[:, :, 0])
    up: dict[str, Any] = dict(size=(hh, ww), mode="bilinear", align_corners=False)
    ends = {r: logs[r] for r, src in enumerate(sources) if src}
    consistency = cross_view_consistency(ends, c2w, sources)
    rows = blend.config.rows if blend is not None else depth.shape[-2]
    out = depth.clone()
    with stage("depth: blend with the monocular depth", len(ends)) as progress:
        for r, log_pair in ends.items():
            fine = F.interpolate(log_pair[None], **up)[0]
            cost = torch.stack(
                [cost_at(img, c2w, r, sources[r], d, dirs, sweep, d_range) for d in fine]
            )
            feats = blend_features(
                img[r],
                cost,
                log_pair[0],
                log_pair[1],
                consistency[r],
                parallax(log_pair[0], c2w, r, sources[r]),
                rows,
            )
            if record is not None:
                record.append({"view": r, "features": feats, "logs": log_pair, "scale": scale})
            else:
                assert blend is not None  # the caller blends or records
                blended = torch.exp(blend.blend(feats[None], log_pair[:1], log_pair[1:]))
                out[r] = torch.nan_to_num(blended, nan=d_max, posinf=d_max).clamp(0.05, d_max)
            progress.advance()
    return out
