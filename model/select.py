"""A learned choice between the mono-guided and the unguided MVS depth, pixel by pixel.

Mode "full" fuses two depth hypotheses in the photometric sweep (`panogrf.model.refine`): the
mono-guided network's and the unguided one's. The sweep's own rule keeps, per pixel, the one
its nearest sources match best at its own depth. Where the match says little (blank walls,
bright windows, repeated texture) that rule keeps the mono-guided depth, and on a real capture
the monocular prior is often wrong exactly there. On the training run's held-back scenes the
rule's choice scores 0.203 m, the selector's 0.177 and the truth's 0.151
(`lab/training/depth_select.log`).

`HypothesisSelector` makes the choice from what is known at that point, per pixel: each
hypothesis' photometric cost curve (its cost, its best cost, how far the search would move it,
how flat the curve is), how far apart the two hypotheses are and how far each is from the
monocular depth, each network's confidence (the peak of its cost-volume softmax), and the
reference image's brightness and texture. It is trained on the training scenes
(`panogrf train select`) with the truth deciding which search end is nearer, the monocular
network put out of its domain on some scenes (`panogrf.app.train.augment.out_of_domain`) so
that a wrong prior is among what it sees.

It also sees a summary of the whole panorama (``SelectorConfig.context``): whether the prior
holds is a property of the capture. And it can see, per pixel, whether each hypothesis' search
end reappears in the view's sources (``SelectorConfig.consistency``, `cross_view_consistency`):
the point it puts in the world, seen from a source, should lie on that source's own depth. The
photometric curves say how well the colours match, which blank walls and repeated wallpaper
leave open; this says whether the views agree on the geometry. The choice is therefore made
once the sweep has every view's search ends (`panogrf.model.sweep.Chooser.finish`).

Where its probability is within a margin of one half, the caller keeps the photometric rule's
choice (`choose`'s ``fallback``; `DepthEstimator.select_margin`).

25k parameters at 128 x 256: about 0.02 s per pair of views (`depth_select_val.json`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, cast

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from panogrf.model.erp import erp_to_world, latitude_weights, sample_erp, world_to_erp
from panogrf.model.layers import CircularConv2d
from panogrf.model.ssim import box_mean

#: Channels of `selection_features`.
FEATURES = 18
#: Channels of `cross_view_consistency`, after them.
CONSISTENCY = 2
#: Largest |log depth| disagreement `cross_view_consistency` reports.
CONSISTENCY_CAP = 0.5


@dataclass(frozen=True)
class SelectorConfig:
    """Size of the selector."""

    channels: int = 32
    """Width of the hidden layers."""
    rows: int = 128
    """Rows at which the features are pooled and the choice is made."""
    context: bool = False
    """A scene-wide summary (the latitude-weighted mean of the hidden features, through a
    linear layer) added to every pixel's hidden features: whether the monocular prior holds is
    a property of the whole capture, which a pixel's neighbourhood cannot see."""
    consistency: bool = False
    """The selector also sees how well each hypothesis' search end agrees in 3D with the
    search ends of the view's sources (`cross_view_consistency`): a depth that is right in
    one view reappears in the others, whatever the texture says."""


def local_std(gray: Tensor, k: int = 7) -> Tensor:
    """Standard deviation of [1, 1, H, W] over a k x k window (wrapping in width)."""
    mean = box_mean(gray, k)
    return (box_mean(gray * gray, k) - mean * mean).clamp(min=0).sqrt()


def selection_features(
    image: Tensor,  # [3, H, W] the reference view in [0, 1], at the sweep's resolution
    cost: Tensor,  # [2, D, H, W] the sweep's cost curves, mono-guided first
    log_hyp: Tensor,  # [2, H, W] the hypotheses (log metres)
    ends: Tensor,  # [2, H, W] where the search from each ends (log metres)
    log_mono: Tensor,  # [H, W] the monocular depth (log metres)
    confidence: Tensor,  # [2, H, W] each network's peak probability
    offsets: Tensor,  # [D] the sweep's log-depth offsets
    rows: int = 128,
) -> Tensor:
    """The selector's input [FEATURES, rows, 2 rows]: everything at the sweep's resolution,
    area-pooled to ``rows``."""
    h, w = image.shape[-2:]
    best = cost.amin(1)
    centre = cost[:, int(torch.argmin(offsets.abs()))]
    span = float(offsets.abs().max().clamp(min=1e-6))
    gray = image.mean(0, keepdim=True)[None]
    lat = latitude_weights(h, w, device=image.device, dtype=image.dtype)[None]
    feats = torch.cat(
        [
            centre,
            best,
            (ends - log_hyp) / span,
            cost.mean(1) - best,
            (log_hyp[1] - log_hyp[0])[None],
            (ends[1] - ends[0])[None],
            log_mono[None] - log_hyp,
            gray[0] - 0.5,
            local_std(gray)[0] * 4,
            lat,
            confidence,
            log_hyp[:1] / 2.3,
        ]
    )
    if h != rows:
        feats = F.interpolate(feats[None], size=(rows, 2 * rows), mode="area")[0]
    return feats


def cross_view_consistency(
    ends: dict[int, Tensor], c2w: Tensor, sources: list[list[int]]
) -> dict[int, Tensor]:
    """For every view r of ``ends`` (its hypotheses' search ends [2, h, w], log metres), how far
    each end's point is from the surfaces its sources' ends put there: [2, h, w], the smallest
    |log(distance from the source) - log(the source's end at that pixel)| over the sources in
    ``ends`` and their two ends (nearest pixel), at most `CONSISTENCY_CAP` (also where no
    source has ends). Small: the end reappears in another view's depth."""
    out = {}
    for r, e in ends.items():
        h, w = e.shape[-2:]
        best = torch.full_like(e, CONSISTENCY_CAP)
        points = erp_to_world(torch.exp(e), c2w[r].to(e))  # [2, h*w, 3]
        for s in sources[r]:
            if s not in ends:
                continue
            uv, dist = world_to_erp(points, c2w[s].to(e), h, w)
            seen = sample_erp(ends[s][None].expand(2, -1, -1, -1), uv, "nearest")  # [2, 2, N]
            gap = (torch.log(dist.clamp(min=1e-3))[:, None] - seen).abs().amin(1)
            best = torch.minimum(best, gap.reshape(2, h, w))
        out[r] = best.clamp(max=CONSISTENCY_CAP)
    return out


def dilated_trunk(inputs: int, channels: int) -> nn.Sequential:
    """Three circular 3 x 3 convolutions (dilation 1, 2, 4: 15 pixels across) with ReLUs,
    then a 1 x 1 to one logit: the selector's and the blend's (`panogrf.model.blend`) network.
    Its first four modules make the hidden features (see `scene_summary`)."""
    return nn.Sequential(
        CircularConv2d(inputs, channels, 3, padding=1),
        nn.ReLU(inplace=True),
        CircularConv2d(channels, channels, 3, padding=2, dilation=2),
        nn.ReLU(inplace=True),
        CircularConv2d(channels, channels, 3, padding=4, dilation=4),
        nn.ReLU(inplace=True),
        nn.Conv2d(channels, 1, 1),
    )


def scene_summary(hidden: Tensor) -> Tensor:
    """The latitude-weighted mean [B, C] of hidden features [B, C, h, w] over the panorama."""
    h, w = hidden.shape[-2:]
    lat = latitude_weights(h, w, dtype=hidden.dtype, device=hidden.device)
    return (hidden * lat).sum((-2, -1)) / lat.sum()


class HypothesisSelector(nn.Module):
    """Selection features [B, FEATURES, h, w] -> logit [B, 1, h, w] that the unguided depth's
    search ends nearer the truth than the mono-guided one's."""

    def __init__(self, config: SelectorConfig = SelectorConfig()) -> None:
        super().__init__()
        self.config = config
        c = config.channels
        self.inputs = FEATURES + (CONSISTENCY if config.consistency else 0)
        self.net = dilated_trunk(self.inputs, c)
        self.context = nn.Linear(c, c) if config.context else None

    def forward(self, features: Tensor) -> Tensor:
        """features [B, C >= inputs, h, w]: the first ``inputs`` channels are read (the
        consistency channels follow `selection_features`' when recorded)."""
        hidden = self.net[:4](features[:, : self.inputs])
        if self.context is not None:
            hidden = hidden + self.context(scene_summary(hidden))[..., None, None]
        logit: Tensor = self.net[4:](hidden)
        return logit

    def choose(
        self,
        features: Tensor,
        size: tuple[int, int],
        fallback: Tensor | None = None,
        margin: float = 0.0,
    ) -> Tensor:
        """Index [H, W] (0 mono-guided, 1 unguided) at ``size`` from features [C, h, w].
        With ``fallback`` (an index [H, W]), pixels whose probability is within ``margin`` of
        one half take the fallback's choice instead."""
        logit: Tensor = self(features[None])
        if logit.shape[-2:] != size:
            logit = F.interpolate(logit, size=size, mode="bilinear", align_corners=False)
        choice = (logit[0, 0] > 0).long()
        if fallback is not None and margin > 0:
            unsure = (torch.sigmoid(logit[0, 0]) - 0.5).abs() < margin
            choice = torch.where(unsure, fallback, choice)
        return choice


class SelectorChooser:
    """`panogrf.model.sweep.Chooser` of mode "full"'s two hypotheses: each view's selection
    features and photometric rule are made when the sweep reaches it; the choice is made in
    `finish`, when the cross-view consistency of every view's search ends can be measured:
    the ``selector``'s (the rule's within ``margin`` of one half), or without one the rule's.
    ``record`` (a list): each view's selector input is appended (its training data).
    log_mono [V, 1, h, w]: the monocular log depth; confidence [V, 2, h, w] the networks'."""

    def __init__(
        self,
        selector: HypothesisSelector | None,
        margin: float,
        switch_gain: float,
        pixels: Tensor,
        log_mono: Tensor,
        confidence: Tensor,
        record: list[dict[str, Any]] | None = None,
    ) -> None:
        self.selector, self.margin, self.switch_gain = selector, margin, switch_gain
        self.pixels, self.log_mono, self.confidence = pixels, log_mono, confidence
        self.record = record
        self.rows = selector.config.rows if selector is not None else 128
        self.images: dict[int, Tensor] = {}
        self.pending: dict[int, tuple[Tensor, Tensor]] = {}  # view -> (features, rule)

    def __call__(
        self, r: int, cost: Tensor, log_hyp: Tensor, ends: Tensor, offsets: Tensor
    ) -> None:
        from panogrf.model.sweep import photometric_choice

        hh, ww = cost.shape[-2:]
        if hh not in self.images:
            mode = "area" if self.pixels.shape[-2] > hh else "bilinear"
            self.images[hh] = F.interpolate(self.pixels, size=(hh, ww), mode=mode)
        up: dict[str, Any] = dict(size=(hh, ww), mode="bilinear", align_corners=False)
        log_mono = F.interpolate(self.log_mono[r : r + 1], **up)[0, 0]
        conf = F.interpolate(self.confidence[r : r + 1], **up)[0]
        feats = selection_features(
            self.images[hh][r], cost, log_hyp, ends, log_mono, conf, offsets, self.rows
        )
        self.pending[r] = (feats, photometric_choice(cost, offsets, self.switch_gain))
        return None

    def finish(
        self, ends: dict[int, Tensor], c2w: Tensor, sources: list[list[int]]
    ) -> dict[int, Tensor]:
        pooled = {
            r: F.interpolate(ends[r][None], size=feats.shape[-2:], mode="area")[0]
            for r, (feats, _) in self.pending.items()
        }
        consistency = cross_view_consistency(pooled, c2w, sources)
        out: dict[int, Tensor] = {}
        for r, (feats, rule) in self.pending.items():
            feats = torch.cat((feats, consistency[r]))
            if self.record is not None:
                pool: dict[str, Any] = dict(size=feats.shape[-2:], mode="area")
                self.record.append(
                    {
                        "view": r,
                        "features": feats,
                        "ends": pooled[r],
                        "rule": F.interpolate(rule[None, None].to(feats), **pool)[0, 0],
                    }
                )
            if self.selector is None:
                out[r] = rule
            else:
                out[r] = self.selector.choose(
                    feats, cast(tuple[int, int], tuple(rule.shape)), rule, self.margin
                )
        return out
