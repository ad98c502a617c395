"""Spherical depth for every view of a scene: monocular, MVS-only or mono-guided MVS.

Every view is the reference once, with all other views as sources (cost volumes averaged).
Panoramas of any 2:1 size are resized to the networks' working resolution and the depth is
resized back. Degenerate input never yields NaN:
- one view: monocular depth, with a warning;
- a source at (nearly) the reference's position: that pair is dropped; with no pair left the
  view falls back to monocular depth, with a warning;
- depth at the top of the range (outdoor, or beyond ``d_max``): clamped, and flagged per pixel.

The multi-view modes end with a photometric sweep (`panogrf.model.refine.sweep_depth`): every
pixel of the MVS depth may move to the nearby depth at which its nearest sources agree best, at
twice the working resolution, where they clearly agree better than at the network's depth. The
cost volume works at a quarter of 128 rows; the sweep puts back the detail a real capture has.
Mode "full" fuses the mono-guided and the unguided network's depth there (each pixel keeps the
one its sources agree with; ``fusion_sweep``). A median filter then takes out the sweep's
speckle (``median``). With a ``blend`` (mode "full" fused), a learned per-pixel blend with the
monocular depth follows (`panogrf.model.blend`): at wide baselines the two fail in different
places. ``sweep=None`` turns the sweep (and the median and blend) off in every mode (training
does, to keep its depth caches cheap).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from panogrf.model.blend import DepthBlend, blend_features, parallax
from panogrf.model.erp import erp_directions
from panogrf.model.mono import MonoDepthNet, MonoOutput
from panogrf.model.mvs import MVSNet
from panogrf.model.progress import open_stage, stage
from panogrf.model.refine import (
    SweepConfig,
    cost_at,
    median_filter,
    nearest_sources,
    photometric_choice,
    sweep_depth,
)
from panogrf.model.select import (
    HypothesisSelector,
    cross_view_consistency,
    selection_features,
)

MODES = ("full", "mono", "mvs")
GUIDES = ("mono", "aligned", "banded", "mvs")
#: Bands of elevation of the "banded" guide (`DepthEstimator._banded`), equal in degrees.
GUIDE_BANDS = 6
DEFAULT_SWEEP = SweepConfig()
#: A short search (0.86x to 1.16x) for mode "full"'s sweep: measured, not the default (see
#: `DepthEstimator.fusion_sweep`).
SHORT_SWEEP = SweepConfig(candidates=7, span=0.15)


@dataclass
class DepthEstimate:
    depth: Tensor  # [V, 1, H, W] spherical depth, metres
    mono: Tensor  # [V, 1, H, W] the monocular depth
    out_of_range: Tensor  # [V, 1, H, W] bool: clamped at the top of the depth range
    sources: list[list[int]]  # views used as sources, per reference view
    warnings: list[str] = field(default_factory=list)


class DepthEstimator(nn.Module):
    """Mono network plus the MVS networks by mode ("full": mono-guided, "mvs": MVS only)."""

    def __init__(
        self,
        mono: MonoDepthNet,
        mvs: dict[str, MVSNet],
        working_height: int = 128,
        min_baseline: float = 0.05,
        sweep: SweepConfig | None = DEFAULT_SWEEP,
    ) -> None:
        super().__init__()
        self.mono = mono
        self.mvs = nn.ModuleDict(mvs)
        self.working_height = working_height
        self.min_baseline = min_baseline
        """Sources closer than this to the reference (metres) carry no parallax: dropped."""
        self.sweep = sweep
        """The photometric sweep after the MVS network in mode "mvs" (None: no sweep in any
        mode, and no fusion)."""
        self.fusion_sweep = DEFAULT_SWEEP
        """The sweep of mode "full": it fuses the mono-guided and the unguided MVS depth (each
        pixel keeps the one its sources agree with) and searches around it. Measured
        (`benchmarks/depth_fusion.py`, `depth_fusion_round7.json`): on 36 validation scenes
        (12 of them home rooms 3-5 m apart; the worlds also scaled by 0.7 and 1.4) a short
        search (`SHORT_SWEEP`, +-0.15 in log depth) with the monocular depth as a third
        hypothesis has the lower mean L1, 0.139 m against 0.172 for this +-0.5, and it also
        does with the monocular depth made wrong in shape (0.182 against 0.201). On the real
        triplet it is the other way round (full 0.231 against 0.173 m; 0.202 for +-0.25 and
        0.218 for +-0.15 without the monocular hypothesis): a real capture's mono-guided depth
        is off further than the short search reaches. The two disagree, so the search the
        real capture needs stays until a validation set with real-capture statistics decides."""
        self.median = 7
        """Side of the median filter after the sweep (modes "full" and "mvs"), in pixels of
        the working resolution (1: none); see `median_filter`. Chosen on the validation scenes
        (`benchmarks/depth_fusion.py`; mean L1 of the wide, classic and home sets):
        full 0.1745 m without, 0.1595 with 5, 0.1553 with 7, 0.1545 with 9 (flat from 7 on:
        the smaller window keeps more small things); MVS-only 0.2152 / 0.2003 / 0.1954."""
        self.sweep_sources = 2
        """The sweep compares each view with at most this many of its nearest sources."""
        self.fuse = True
        """Mode "full" with the unguided network loaded too: both depths enter the sweep, each
        pixel keeping the one its sources agree with (see `sweep_depth`'s ``others``)."""
        self.switch_gain = 0.0
        """How much better the unguided depth must match to replace the mono-guided one."""
        self.guide = "mono"
        """Mode "full" with the unguided network loaded: the depth that places the mono-guided
        network's candidates: "mono" (the paper), "aligned" (mono scaled per view by its median
        ratio to the unguided MVS depth: a metric scale from the known poses, not from the room
        sizes the monocular network learned), "banded" (mono scaled per view by a profile over
        elevation: the median ratio to the unguided MVS depth in each of `GUIDE_BANDS` bands,
        interpolated between their centres, `_banded`: a room of the wrong proportions, its
        floor too far for the ceiling it sees, is put right before it places the candidates)
        or "mvs" (the unguided MVS depth itself; the monocular features still go in).
        Measured on the validation scenes (`benchmarks/depth_fusion.py`): neither "aligned" nor
        "mvs" helps, so "mono" stays ("banded": `docs/analysis.md`)."""
        self.mono_hypothesis = False
        """Mode "full" fused: the monocular depth enters the sweep as a third hypothesis, kept
        where the sources agree with it better than with both MVS depths. Off: it pays on the
        validation scenes with the short search (see ``fusion_sweep``), not with this one."""
        self.selector: HypothesisSelector | None = None
        """Mode "full" fused (two hypotheses): a learned choice of each pixel's hypothesis
        instead of the sweep's photometric rule (`panogrf.model.select`); None: the rule."""
        self.select_margin = 0.1
        """Pixels whose selector probability is within this of one half keep the photometric
        rule's choice (0: the selector's everywhere). The rule's doubtful choices are single
        pixels, which the median outvotes; the selector's come in patches, which it keeps.
        Measured on the validation scenes (`depth_select_context_val.json`, mean L1 of the
        eight columns): 0 0.1609, 0.1 0.1593, 0.2 0.1595. Chosen again for the
        selector with cross-view consistency (`depth_select_margin_round18_val.json`): 0
        0.1552, 0.1 0.1545, 0.2 0.1552."""
        self.record: list[dict] | None = None
        """When a list, mode "full" fused appends, per reference view, the selector's input
        and where the search from each hypothesis ends (the selector's training data)."""
        self.blend: DepthBlend | None = None
        """Mode "full" fused: a learned per-pixel blend of the fused depth with the monocular
        depth after the median (`panogrf.model.blend`); None: the fused depth as it is."""
        self.blend_record: list[dict] | None = None
        """When a list, mode "full" fused appends, per reference view, the blend's input and
        the two depths it blends (its training data); the depth is not blended then."""
        self.canonical = True
        """Mode "full" with the unguided network loaded: the MVS networks and the sweep work in
        the world scaled by k = median(mono / unguided MVS depth) (`_world_scale`), the room
        sizes the monocular network learned, and the depth is scaled back by 1 / k. A monocular
        network cannot know the metric size of a room from one image, while the poses fix it;
        in the canonical world the mono prior and the cost volume agree on scale, as in
        training. Costs one more pass of the unguided network (in the canonical world).
        Measured on the validation scenes with the world scaled by 1, 0.7 and 1.4 (the same
        images; `benchmarks/depth_fusion.py --scales 1,0.7,1.4`, mean L1 in metres of classic
        and home): off 0.156 / 0.210 / 0.301 (MVS-only 0.189 / 0.190 / 0.300), on 0.155 /
        0.126 / 0.215; the first unguided pass scaled by k instead of run again: 0.155 /
        0.147 / 0.231."""

    @property
    def d_max(self) -> float:
        return self.mono.config.d_max

    def _fuses(self, mode: str) -> bool:
        """Mono-guided depth is fused with the unguided network's by the photometric sweep."""
        return self.fuse and mode == "full" and "mvs" in self.mvs and self.sweep is not None

    def _canonical(self, mode: str) -> bool:
        """The MVS networks (and the sweep) work in the world of the monocular network's scale."""
        return self.canonical and mode == "full" and "mvs" in self.mvs

    def _clean(self, depth: Tensor) -> Tensor:
        return torch.nan_to_num(depth, nan=self.d_max, posinf=self.d_max).clamp(0.05, self.d_max)

    def view_sources(self, c2w: Tensor) -> tuple[list[list[int]], list[str]]:
        """Each view's sources (every other view at least `min_baseline` away: closer ones
        give no parallax) and warnings about the views left without."""
        v = c2w.shape[0]
        sources: list[list[int]] = [[] for _ in range(v)]
        warnings: list[str] = []
        centres = c2w[:, :3, 3]
        for ref in range(v):
            dist = torch.linalg.vector_norm(centres - centres[ref], dim=-1)
            src = [j for j in range(v) if j != ref and float(dist[j]) >= self.min_baseline]
            close = [j for j in range(v) if j != ref and float(dist[j]) < self.min_baseline]
            if close:
                warnings.append(
                    f"view {ref}: views {close} are within {self.min_baseline} m of it "
                    "(no parallax): not used as sources"
                )
            if not src:
                if v > 1:
                    warnings.append(f"view {ref}: no usable source, monocular depth")
                continue
            sources[ref] = src
        return sources, warnings

    def _mvs(self, mode, small, c2w, mono, sources, depth: Tensor) -> Tensor:
        """``depth`` with every view that has sources replaced by network ``mode``'s estimate."""
        return self._mvs_confidence(mode, small, c2w, mono, sources, depth)[0]

    def _mvs_confidence(self, mode, small, c2w, mono, sources, depth: Tensor, step=None):
        """(`_mvs`'s depth, the network's confidence [V, 1, h, w]: the peak of its
        cost-volume softmax, 1 for views without sources). ``step``: called after each view
        (progress)."""
        net = self.mvs[mode]
        confidence = torch.ones_like(depth)
        cfg = net.config
        for ref, src in enumerate(sources):
            if not src:
                continue
            mono_kw = {}
            if cfg.use_mono or cfg.n_mono > 0:
                mono_kw = {
                    "mono_depth": mono.depth[ref : ref + 1],
                    "mono_features": mono.features[ref : ref + 1],
                }
            out = net(
                small[ref : ref + 1],
                small[src][None],
                c2w[ref : ref + 1],
                c2w[src][None],
                **mono_kw,
            )
            depth[ref] = out.depth[0]
            peak = out.probability.amax(1, keepdim=True)
            confidence[ref] = F.interpolate(
                peak, size=depth.shape[-2:], mode="bilinear", align_corners=False
            )[0]
            if step is not None:
                step()
        return depth, confidence

    def _aligned(self, mono: Tensor, mvs: Tensor, sources: list[list[int]]) -> Tensor:
        """``mono`` [V, 1, h, w] scaled per view with sources by median(mvs / mono) over the
        pixels inside the depth range (the scale kept within 0.5-2): `_banded` with one band."""
        return self._banded(mono, mvs, sources, bands=1)

    def _banded(
        self, mono: Tensor, mvs: Tensor, sources: list[list[int]], bands: int = GUIDE_BANDS
    ) -> Tensor:
        """``mono`` [V, 1, h, w] scaled per view with sources by a profile over elevation: the
        median of mvs / mono over the pixels inside the depth range in each of ``bands``
        equal bands of elevation (a band with fewer than 1 % of its pixels inside: the view's
        median), linearly interpolated in elevation between the band centres (constant beyond
        the outer ones), kept within 0.5-2."""
        out = mono.clone()
        h = mono.shape[-2]
        band = (torch.arange(h, device=mono.device) * bands) // h  # band of each row
        centres = (
            torch.arange(bands, dtype=mono.dtype, device=mono.device) + 0.5
        ) * h / bands - 0.5
        rows = torch.arange(h, dtype=mono.dtype, device=mono.device)
        for v, src in enumerate(sources):
            ok = (mvs[v, 0] < 0.98 * self.d_max) & (mono[v, 0] > 0.05)
            if not src or int(ok.sum()) == 0:
                continue
            ratio = mvs[v, 0] / mono[v, 0].clamp(min=0.05)
            overall = ratio[ok].median()
            scales = []
            for b in range(bands):
                inside = ok & (band == b)[:, None]
                needed = max(1.0, 0.01 * int((band == b).sum()) * mono.shape[-1])
                scales.append(ratio[inside].median() if int(inside.sum()) >= needed else overall)
            profile = _interp(rows, centres, torch.stack(scales)).clamp(0.5, 2.0)
            out[v] = (mono[v] * profile.to(mono)[:, None]).clamp(0.05, self.d_max)
        return out

    def _world_scale(self, mono: Tensor, mvs: Tensor, sources: list[list[int]]) -> float:
        """k = median(mono / mvs) over the pixels of views with sources that are inside the
        depth range in both (1 when there are none), kept within 0.25-4."""
        ok = torch.zeros_like(mvs, dtype=torch.bool)
        for v, src in enumerate(sources):
            if src:
                ok[v] = (mvs[v] < 0.98 * self.d_max) & (mono[v] < 0.98 * self.d_max)
        ok &= (mvs > 0.05) & (mono > 0.05)
        if int(ok.sum()) == 0:
            return 1.0
        return float((mono[ok] / mvs[ok]).median().clamp(0.25, 4.0))

    def _blended(self, pixels, c2w, depth, mono, sources, scale: float) -> Tensor:
        """``depth`` [V, 1, h, w] blended with the monocular depth ``mono`` by `blend`, every
        view with sources (``sources``: those the sweep compared it with); recorded into
        ``blend_record`` instead when that is a list."""
        cfg = self.fusion_sweep
        hh, ww = cfg.height, 2 * cfg.height
        mode = "area" if pixels.shape[-2] > hh else "bilinear"
        img = F.interpolate(pixels, size=(hh, ww), mode=mode)
        dirs = erp_directions(hh, ww, device=depth.device, dtype=depth.dtype)
        d_range = (0.05, self.d_max)
        logs = torch.log(torch.stack((self._clean(depth), self._clean(mono)), 1)[:, :, 0])
        up = dict(size=(hh, ww), mode="bilinear", align_corners=False)
        ends = {r: logs[r] for r, src in enumerate(sources) if src}
        consistency = cross_view_consistency(ends, c2w, sources)
        rows = self.blend.config.rows if self.blend is not None else depth.shape[-2]
        out = depth.clone()
        with stage("depth: blend with the monocular depth", len(ends)) as progress:
            for r, log_pair in ends.items():
                fine = F.interpolate(log_pair[None], **up)[0]
                cost = torch.stack(
                    [cost_at(img, c2w, r, sources[r], d, dirs, cfg, d_range) for d in fine]
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
                if self.blend_record is not None:
                    self.blend_record.append(
                        {"view": r, "features": feats, "logs": log_pair, "scale": scale}
                    )
                else:
                    blended = self.blend.blend(feats[None], log_pair[:1], log_pair[1:])
                    out[r] = self._clean(torch.exp(blended))
                progress.advance()
        return out

    def _chooser(self, pixels: Tensor, mono: Tensor, confidence: Tensor) -> _SelectorChooser:
        """`sweep_depth`'s ``chooser`` for the two fused hypotheses: the selector's choice
        (or, without one, the photometric rule), made once every view's search ends are
        known (`cross_view_consistency`); the selector's input appended to ``record`` when
        recording. mono, confidence: [V, 1 | 2, h, w] at the working resolution."""
        return _SelectorChooser(self, pixels, mono, confidence)

    @torch.no_grad()
    def forward(
        self, images: Tensor, c2w: Tensor, mode: str = "full", detail: Tensor | None = None
    ) -> DepthEstimate:
        """images [V, 3, H, W] in [0, 1] (W = 2H), c2w [V, 4, 4] -> `DepthEstimate`.

        ``detail``: the same panoramas at a higher resolution for the photometric sweep (by
        default ``images``), when the caller passes working-resolution images."""
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        if self.guide not in GUIDES:
            raise ValueError(f"guide must be one of {GUIDES}, got {self.guide!r}")
        if mode != "mono" and mode not in self.mvs:
            raise ValueError(f"no weights loaded for mode {mode!r}")
        v, _, h, w = images.shape
        if w != 2 * h:
            raise ValueError(f"panoramas must be 2:1, got {h}x{w}")
        hw = (self.working_height, 2 * self.working_height)
        small = F.interpolate(images, size=hw, mode="area") if (h, w) != hw else images
        with stage("depth: monocular network", 1) as progress:
            mono = self.mono(small)
            progress.advance()
        warnings: list[str] = []
        sources: list[list[int]] = [[] for _ in range(v)]
        depth = mono.depth.clone()
        others: tuple[Tensor, ...] = ()
        scale = 1.0  # the world's scale for the MVS networks (see ``canonical``)
        if mode != "mono":
            if v == 1:
                warnings.append("one view only: monocular depth (no multi-view stereo)")
            sources, notes = self.view_sources(c2w)
            warnings += notes
            guide = mono
            # Network passes over every view with sources: the unguided one (twice when it
            # first fixes the world's scale), then the guided one.
            canonical = self._canonical(mode)
            passes = 1 + int(self._fuses(mode) or canonical) + int(canonical)
            progress = open_stage("depth: multi-view stereo", passes * sum(map(bool, sources)))
            step = progress.advance
            if self._fuses(mode) or self._canonical(mode):
                unguided, conf_u = self._mvs_confidence(
                    "mvs", small, c2w, mono, sources, mono.depth.clone(), step
                )
                if self._canonical(mode):
                    scale = self._world_scale(mono.depth, self._clean(unguided), sources)
                    c2w = c2w.clone()
                    c2w[:, :3, 3] *= scale
                    unguided, conf_u = self._mvs_confidence(
                        "mvs", small, c2w, mono, sources, mono.depth.clone(), step
                    )
                if self._fuses(mode):
                    others = (unguided, mono.depth) if self.mono_hypothesis else (unguided,)
                if self.guide == "aligned":
                    guide = MonoOutput(self._aligned(mono.depth, unguided, sources), mono.features)
                elif self.guide == "banded":
                    guide = MonoOutput(self._banded(mono.depth, unguided, sources), mono.features)
                elif self.guide == "mvs":
                    guide = MonoOutput(self._clean(unguided), mono.features)
            depth, conf = self._mvs_confidence(mode, small, c2w, guide, sources, depth, step)
            progress.close()
            if len(others) == 1:
                conf = torch.cat((conf, conf_u), 1)  # [V, 2, h, w]
        depth = self._clean(depth)
        if mode != "mono" and self.sweep is not None and any(sources):
            nearest = nearest_sources(c2w, sources, self.sweep_sources)
            pixels = images if detail is None else detail
            clean = tuple(self._clean(o) for o in others)
            chooser = None
            if len(clean) == 1 and (self.selector is not None or self.record is not None):
                chooser = self._chooser(pixels, mono.depth, conf)
            depth = sweep_depth(
                pixels,
                c2w,
                depth,
                nearest,
                self.fusion_sweep if mode == "full" else self.sweep,
                (0.05, self.d_max),
                others=clean,
                switch_gain=self.switch_gain,
                chooser=chooser,
            )
            depth = median_filter(depth, self.median)
            if len(clean) == 1 and (self.blend is not None or self.blend_record is not None):
                depth = self._blended(pixels, c2w, depth, mono.depth, nearest, scale)
            if chooser is not None and self.record is not None:
                for entry in self.record:
                    entry.setdefault("scale", scale)
        canonical_far = None
        if scale != 1.0:
            # Clamped at the top of the range in the canonical world: flagged in the metric one.
            canonical_far = depth >= 0.98 * self.d_max
            depth = self._clean(depth / scale)
        mono_depth = mono.depth
        if (h, w) != hw:
            depth = F.interpolate(depth, size=(h, w), mode="bilinear", align_corners=False)
            mono_depth = F.interpolate(
                mono_depth, size=(h, w), mode="bilinear", align_corners=False
            )
            if canonical_far is not None:
                canonical_far = F.interpolate(canonical_far.float(), size=(h, w)) > 0.5
        out_of_range = depth >= 0.98 * self.d_max
        if canonical_far is not None:
            out_of_range |= canonical_far
        return DepthEstimate(depth, mono_depth, out_of_range, sources, warnings)


def _interp(x: Tensor, xp: Tensor, fp: Tensor) -> Tensor:
    """Piecewise-linear interpolation of (xp, fp) at x (xp increasing; constant beyond its
    ends), as numpy's interp."""
    if len(xp) == 1:
        return fp[0].expand(x.shape)
    i = torch.searchsorted(xp, x).clamp(1, len(xp) - 1)
    x0, x1 = xp[i - 1], xp[i]
    t = ((x - x0) / (x1 - x0)).clamp(0.0, 1.0)
    return fp[i - 1] + t * (fp[i] - fp[i - 1])


class _SelectorChooser:
    """`DepthEstimator._chooser`: each view's selection features and photometric rule are made
    when the sweep reaches it; the choice is made in `finish`, when the cross-view consistency
    of every view's search ends can be measured."""

    def __init__(self, estimator: DepthEstimator, pixels: Tensor, mono: Tensor, confidence):
        self.est = estimator
        self.pixels, self.mono, self.confidence = pixels, mono, confidence
        self.rows = estimator.selector.config.rows if estimator.selector is not None else 128
        self.images: dict[int, Tensor] = {}
        self.pending: dict[int, tuple[Tensor, Tensor]] = {}  # view -> (features, rule)

    def __call__(self, r: int, cost: Tensor, log_hyp: Tensor, ends: Tensor, offsets: Tensor):
        hh, ww = cost.shape[-2:]
        if hh not in self.images:
            mode = "area" if self.pixels.shape[-2] > hh else "bilinear"
            self.images[hh] = F.interpolate(self.pixels, size=(hh, ww), mode=mode)
        up = dict(size=(hh, ww), mode="bilinear", align_corners=False)
        log_mono = F.interpolate(torch.log(self.est._clean(self.mono[r : r + 1])), **up)[0, 0]
        conf = F.interpolate(self.confidence[r : r + 1], **up)[0]
        feats = selection_features(
            self.images[hh][r], cost, log_hyp, ends, log_mono, conf, offsets, self.rows
        )
        self.pending[r] = (feats, photometric_choice(cost, offsets, self.est.switch_gain))
        return None

    def finish(self, ends: dict[int, Tensor], c2w: Tensor, sources: list[list[int]]):
        pooled = {
            r: F.interpolate(ends[r][None], size=feats.shape[-2:], mode="area")[0]
            for r, (feats, _) in self.pending.items()
        }
        consistency = cross_view_consistency(pooled, c2w, sources)
        out = {}
        for r, (feats, rule) in self.pending.items():
            feats = torch.cat((feats, consistency[r]))
            if self.est.record is not None:
                pool = dict(size=feats.shape[-2:], mode="area")
                self.est.record.append(
                    {
                        "view": r,
                        "features": feats,
                        "ends": pooled[r],
                        "rule": F.interpolate(rule[None, None].to(feats), **pool)[0, 0],
                    }
                )
            if self.est.selector is None:
                out[r] = rule
            else:
                out[r] = self.est.selector.choose(
                    feats, tuple(rule.shape), rule, self.est.select_margin
                )
        return out
