"""Spherical depth for every view of a scene: monocular, MVS-only or mono-guided MVS.

Every view is the reference once, its nearest views the sources (``mvs_sources``; costs averaged).
Panoramas of any 2:1 size are resized to the networks' working resolution and the depth is
resized back. Degenerate input never yields NaN:
- one view: monocular depth, with a warning;
- a source at (nearly) the reference's position: that pair is dropped; with no pair left the
  view falls back to monocular depth, with a warning;
- depth at the top of the range (outdoor, or beyond ``d_max``): clamped, and flagged per pixel.

The multi-view modes end with a photometric sweep (`panogrf.model.sweep.sweep_depth`): every
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

import dataclasses
import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from panogrf.model.blend import DepthBlend, blend_views
from panogrf.model.depth_config import (
    DEFAULT_SWEEP,
    SHORT_SWEEP,
    DepthConfig,
    DepthEstimate,
    DepthMode,
    compared_sources,
    view_sources,
)
from panogrf.model.mono import MonoDepthNet, MonoOutput, MonoStage
from panogrf.model.mvs import MVSNet
from panogrf.model.progress import open_stage, stage
from panogrf.model.select import HypothesisSelector, SelectorChooser
from panogrf.model.sweep import SweepConfig, median_filter, sweep_depth

MODES = tuple(DepthMode)
__all__ = [
    "DEFAULT_SWEEP",
    "MODES",
    "SHORT_SWEEP",
    "DepthConfig",
    "DepthEstimate",
    "DepthMode",
    "DepthEstimator",
]


class DepthEstimator(nn.Module):
    """Mono network plus the MVS networks by mode ("full": mono-guided, "mvs": MVS only).

    Its settings (`DepthConfig`; each readable as an attribute, none settable), the optional
    learned ``selector`` (`panogrf.model.select`: each pixel's hypothesis in mode "full" fused;
    None: the photometric rule) and ``blend`` (`panogrf.model.blend`: the fused depth blended
    with the monocular one; None: no blend), and ``weight_files`` (where the networks came from:
    what a cached estimate is keyed by) are fixed at construction."""

    _FIXED = ("selector", "blend", "weight_files", "config")

    # `DepthConfig`'s fields, read-only properties set below the class (`_setting`).
    working_height: int
    min_baseline: float
    mvs_sources: int | None
    sweep: SweepConfig | None
    fusion_sweep: SweepConfig
    median: int
    sweep_sources: int
    far_from: float
    far_factor: float
    fuse: bool
    switch_gain: float
    mono_hypothesis: bool
    select_margin: float
    canonical: bool

    def __init__(
        self,
        mono: MonoDepthNet,
        mvs: dict[str, MVSNet],
        config: DepthConfig | None = None,
        *,
        selector: HypothesisSelector | None = None,
        blend: DepthBlend | None = None,
        weight_files: Sequence[str | Path] = (),
        **settings: Any,
    ) -> None:
        """``settings``: `DepthConfig` fields that override ``config``'s."""
        super().__init__()
        self.mono = mono
        self.mvs = nn.ModuleDict(mvs)
        self.selector = selector
        self.blend = blend
        self.weight_files = tuple(weight_files)
        self.config = dataclasses.replace(config or DepthConfig(), **settings)
        self._frozen = True

    def __setattr__(self, name: str, value: Any) -> None:
        if name in self._FIXED and self.__dict__.get("_frozen"):
            raise AttributeError(
                f"DepthEstimator.{name} is fixed at construction: use configured({name}=...)"
            )
        super().__setattr__(name, value)

    def configured(self, **changes: Any) -> DepthEstimator:
        """An estimator with other settings (`DepthConfig` fields, ``selector``, ``blend``)
        sharing this one's networks, in the same mode (training or evaluation); with settings
        other than these it has no ``weight_files`` (estimates are cached under the weights
        files' key only as the files configure it)."""
        parts = {k: changes.pop(k, getattr(self, k)) for k in ("selector", "blend")}
        config = dataclasses.replace(self.config, **changes)
        same = config == self.config and all(parts[k] is getattr(self, k) for k in parts)
        return DepthEstimator(
            self.mono,
            cast(dict[str, MVSNet], dict(self.mvs)),
            config,
            weight_files=self.weight_files if same else (),
            **parts,
        ).train(self.training)

    @property
    def d_max(self) -> float:
        return self.mono.config.d_max

    def _fuses_canonical(self, mode: DepthMode) -> tuple[bool, bool]:
        """(mono-guided depth is fused with the unguided network's by the photometric sweep,
        the MVS networks (and the sweep) work in the world of the monocular network's scale)."""
        both = mode == DepthMode.FULL and DepthMode.MVS in self.mvs
        return self.fuse and both and self.sweep is not None, self.canonical and both

    def _clean(self, depth: Tensor) -> Tensor:
        return torch.nan_to_num(depth, nan=self.d_max, posinf=self.d_max).clamp(0.05, self.d_max)

    def view_sources(self, c2w: Tensor) -> tuple[list[list[int]], list[str]]:
        """Each view's sources and warnings about the views left without (`view_sources`)."""
        return view_sources(c2w, self.min_baseline, self.mvs_sources)

    def _mvs_confidence(
        self,
        mode: DepthMode,
        small: Tensor,
        c2w: Tensor,
        mono: MonoOutput,
        sources: list[list[int]],
        depth: Tensor,
        step: Callable[[], object] | None = None,
    ) -> tuple[Tensor, Tensor]:
        """(`_mvs`'s depth, the network's confidence [V, 1, h, w]: the peak of its
        cost-volume softmax, 1 for views without sources). ``step``: called after each view
        (progress)."""
        net = cast(MVSNet, self.mvs[mode])
        confidence = torch.ones_like(depth)
        cfg = net.config
        for ref, src in enumerate(sources):
            if not src:
                continue
            mono_kw: dict[str, Tensor] = {}
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

    def _chooser(
        self, pixels: Tensor, mono: Tensor, confidence: Tensor, record: list[dict[str, Any]] | None
    ) -> SelectorChooser:
        """`sweep_depth`'s ``chooser`` for the two fused hypotheses (`SelectorChooser`).
        mono, confidence: [V, 1 | 2, h, w] at the working resolution."""
        return SelectorChooser(
            self.selector,
            self.select_margin,
            self.switch_gain,
            pixels,
            torch.log(self._clean(mono)),
            confidence,
            record,
        )

    @torch.no_grad()
    def forward(
        self,
        images: Tensor,
        c2w: Tensor,
        mode: DepthMode | str = DepthMode.FULL,
        detail: Tensor | None = None,
        *,
        record: list[dict[str, Any]] | None = None,
        blend_record: list[dict[str, Any]] | None = None,
        mono_stages: Sequence[MonoStage] = (),
    ) -> DepthEstimate:
        """images [V, 3, H, W] in [0, 1] (W = 2H), c2w [V, 4, 4] -> `DepthEstimate`.

        The stages: the networks (`_networks`: monocular, then the MVS passes), the photometric
        stages (`_photometric`: sweep and fusion, median, blend; modes "full" and "mvs" with a
        sweep), the depth back in the metric world at the panoramas' size (`_finish`).
        ``detail``: the same panoramas at a higher resolution for the photometric sweep (by
        default ``images``), when the caller passes working-resolution images. Training taps
        (mode "full" fused): ``record`` gets, per reference view, the selector's input and
        where the search from each hypothesis ends; ``blend_record`` the blend's input and the
        two depths it blends (the depth is then not blended). Training perturbations:
        ``mono_stages`` around the monocular network, each around the one before."""
        if mode not in MODES:
            raise ValueError(f"mode must be one of {[str(m) for m in MODES]}, got {mode!r}")
        mode = DepthMode(mode)
        if mode != DepthMode.MONO and mode not in self.mvs:
            raise ValueError(f"no weights loaded for mode {mode!r}")
        h, w = images.shape[-2:]
        if w != 2 * h:
            raise ValueError(f"panoramas must be 2:1, got {w}x{h} (width x height)")
        hw = (self.working_height, 2 * self.working_height)
        small = F.interpolate(images, size=hw, mode="area") if (h, w) != hw else images
        net = self._networks(mode, small, c2w, mono_stages)
        if mode != DepthMode.MONO and self.sweep is not None and any(net.sources):
            pixels = images if detail is None else detail
            net.depth = self._photometric(mode, pixels, net, record, blend_record)
        return self._finish(net, (h, w))

    def _networks(
        self, mode: DepthMode, small: Tensor, c2w: Tensor, mono_stages: Sequence[MonoStage] = ()
    ) -> _NetworkDepth:
        """The monocular network, then (modes "full" and "mvs") the MVS passes over every view
        with sources: the unguided one (twice when it first fixes the world's scale, see
        ``canonical``), then the mode's own."""
        v = small.shape[0]
        with stage("depth: monocular network", 1) as progress:
            forward: Callable[[Tensor], MonoOutput] = self.mono
            for wrap in mono_stages:
                forward = functools.partial(wrap, forward)
            mono = forward(small)
            progress.advance()
        net = _NetworkDepth(mono, mono.depth.clone(), [[] for _ in range(v)], c2w)
        if mode == DepthMode.MONO:
            net.depth = self._clean(net.depth)
            return net
        if v == 1:
            net.warnings.append("one view only: monocular depth (no multi-view stereo)")
        net.sources, notes = self.view_sources(c2w)
        net.warnings += notes
        sources, (fuses, canonical) = net.sources, self._fuses_canonical(mode)
        passes = 1 + int(fuses or canonical) + int(canonical)
        progress = open_stage("depth: multi-view stereo", passes * sum(map(bool, sources)))
        step = progress.advance
        conf_u: Tensor | None = None
        if fuses or canonical:
            unguided, conf_u = self._mvs_confidence(
                DepthMode.MVS, small, c2w, mono, sources, mono.depth.clone(), step
            )
            if canonical:
                net.scale = self._world_scale(mono.depth, self._clean(unguided), sources)
                c2w = c2w.clone()
                c2w[:, :3, 3] *= net.scale
                unguided, conf_u = self._mvs_confidence(
                    DepthMode.MVS, small, c2w, mono, sources, mono.depth.clone(), step
                )
            if fuses:
                net.others = (unguided, mono.depth) if self.mono_hypothesis else (unguided,)
        depth, conf = self._mvs_confidence(mode, small, c2w, mono, sources, net.depth, step)
        progress.close()
        net.c2w, net.depth = c2w, self._clean(depth)
        if len(net.others) == 1:
            assert conf_u is not None  # the unguided pass ran: it gave the other hypothesis
            net.confidence = torch.cat((conf, conf_u), 1)
        else:
            net.confidence = conf
        return net

    def _photometric(
        self,
        mode: DepthMode,
        pixels: Tensor,
        net: _NetworkDepth,
        record: list[dict[str, Any]] | None,
        blend_record: list[dict[str, Any]] | None,
    ) -> Tensor:
        """The sweep (fusing the hypotheses), the median and, mode "full" fused, the blend with
        the monocular depth, in the networks' world."""
        nearest = compared_sources(self.config, net.c2w, net.sources, net.scale)
        clean = tuple(self._clean(o) for o in net.others)
        fused = len(clean) == 1
        chooser = None
        if fused and (self.selector is not None or record is not None):
            assert net.confidence is not None  # `_networks` sets it in every multi-view mode
            chooser = self._chooser(pixels, net.mono.depth, net.confidence, record)
        sweep = self.fusion_sweep if mode == DepthMode.FULL else self.sweep
        assert sweep is not None  # `forward` runs the photometric stages with a sweep only
        depth = sweep_depth(
            pixels,
            net.c2w,
            net.depth,
            nearest,
            sweep,
            (0.05, self.d_max),
            others=clean,
            switch_gain=self.switch_gain,
            chooser=chooser,
        )
        depth = median_filter(depth, self.median)
        if fused and (self.blend is not None or blend_record is not None):
            depth = blend_views(
                self.blend,
                pixels,
                net.c2w,
                self._clean(depth),
                self._clean(net.mono.depth),
                nearest,
                self.fusion_sweep,
                self.d_max,
                net.scale,
                blend_record,
            )
        if chooser is not None and record is not None:
            for entry in record:
                entry.setdefault("scale", net.scale)
        return depth

    def _finish(self, net: _NetworkDepth, size: tuple[int, int]) -> DepthEstimate:
        """The depth scaled back to the metric world and resized to ``size``, with what is
        clamped at the top of the range flagged."""
        depth, canonical_far = net.depth, None
        if net.scale != 1.0:
            # Clamped at the top of the range in the canonical world: flagged in the metric one.
            canonical_far = depth >= 0.98 * self.d_max
            depth = self._clean(depth / net.scale)
        mono_depth = net.mono.depth
        if tuple(depth.shape[-2:]) != tuple(size):
            up: dict[str, Any] = dict(size=size, mode="bilinear", align_corners=False)
            depth, mono_depth = F.interpolate(depth, **up), F.interpolate(mono_depth, **up)
            if canonical_far is not None:
                canonical_far = F.interpolate(canonical_far.float(), size=size) > 0.5
        out_of_range = depth >= 0.98 * self.d_max
        if canonical_far is not None:
            out_of_range |= canonical_far
        return DepthEstimate(depth, mono_depth, out_of_range, net.sources, net.warnings)


@dataclass
class _NetworkDepth:
    """What the networks give `DepthEstimator.forward`'s later stages."""

    mono: MonoOutput
    depth: Tensor
    """[V, 1, h, w] metres in the networks' world (scaled by ``scale``), clean."""
    sources: list[list[int]]
    c2w: Tensor  # [V, 4, 4] the poses in the networks' world
    scale: float = 1.0
    """The world's scale for the MVS networks (see ``DepthConfig.canonical``)."""
    others: tuple[Tensor, ...] = ()
    """Further depth hypotheses for the sweep (the unguided MVS depth, mode "full" fused)."""
    confidence: Tensor | None = None
    """[V, 1 | 2, h, w] the MVS networks' confidence (the mode's, then the unguided one's)."""
    warnings: list[str] = field(default_factory=list)


def _setting(name: str) -> property:
    return property(lambda self: getattr(self.config, name), doc=f"``config.{name}``")


for _name in DepthConfig.__dataclass_fields__:  # read-only: estimator.median is config.median
    setattr(DepthEstimator, _name, _setting(_name))
