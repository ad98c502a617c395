"""`DepthConfig`: how the depth chain (`panogrf.model.depth.DepthEstimator`) estimates depth,
fixed at construction, with the sweeps it uses; the figures that chose each setting beside it."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import torch
from torch import Tensor

from panogrf.model.sweep import SweepConfig


class DepthMode(StrEnum):
    """What the depth chain runs (`panogrf.model.depth.DepthEstimator.forward`)."""

    FULL = "full"
    """The monocular network guiding the MVS network, fused with the unguided one (PanoGRF)."""
    MVS = "mvs"
    """The unguided MVS network alone (the no-mono ablation)."""
    MONO = "mono"
    """The monocular network alone (the no-MVS ablation)."""


@dataclass
class DepthEstimate:
    """What `panogrf.model.depth.DepthEstimator` returns."""

    depth: Tensor  # [V, 1, H, W] spherical depth, metres
    mono: Tensor  # [V, 1, H, W] the monocular depth
    out_of_range: Tensor  # [V, 1, H, W] bool: clamped at the top of the depth range
    sources: list[list[int]]  # views used as sources, per reference view
    warnings: list[str] = field(default_factory=list)


DEFAULT_SWEEP = SweepConfig()
#: A short search (0.86x to 1.16x) for mode "full"'s sweep: measured, not the default (see
#: `DepthConfig.fusion_sweep`).
SHORT_SWEEP = SweepConfig(candidates=7, span=0.15)


@dataclass(frozen=True)
class DepthConfig:
    """How `DepthEstimator` estimates depth: fixed at construction (`DepthEstimator.configured`
    makes an estimator of other settings that shares the networks)."""

    working_height: int = 128
    """Rows the networks run at (panoramas are resized to it and the depth back)."""
    min_baseline: float = 0.05
    """Sources closer than this to the reference (metres) carry no parallax: dropped."""
    mvs_sources: int | None = 2
    """Each view's sources: at most this many, its nearest of those ``min_baseline`` away (None:
    all), as the networks trained (a view and two others). Three photos keep every source; in a
    home of 32 photos (`docs/lean-chain.md`, "A home of many photos") the held-out views render
    0.23 dB better, LPIPS the same, the preparation 0.72x (every source: 31 cost volumes
    averaged, those of other rooms adding noise)."""
    sweep: SweepConfig | None = DEFAULT_SWEEP
    """The photometric sweep after the MVS network in mode "mvs" (None: no sweep in any mode,
    and no fusion, median or blend)."""
    fusion_sweep: SweepConfig = DEFAULT_SWEEP
    """The sweep of mode "full": it fuses the mono-guided and the unguided MVS depth (each
    pixel keeps the one its sources agree with) and searches around it. A short search
    (`SHORT_SWEEP`) with the monocular depth as a third hypothesis has the lower L1 on
    synthetic rooms (0.139 against 0.172 m), this one on the real triplet (0.173 against 0.231
    m: a real capture's mono-guided depth is off further than the short search reaches);
    `benchmarks/depth_fusion.py`."""
    median: int = 7
    """Side of the median filter after the sweep (modes "full" and "mvs"), in pixels of the
    working resolution (1: none; `median_filter`). Mean L1 of the validation sets (full):
    0.1745 m without, 0.1595 with 5, 0.1553 with 7, 0.1545 with 9."""
    sweep_sources: int = 2
    """The sweep and the refinement compare each view with at most this many of its nearest
    sources (`compared_sources`)."""
    far_from: float = 1.0
    """Where a view's nearest source is at least this far (metres), the sweep and the
    refinement leave out its sources beyond ``far_factor`` times that distance: with that much
    parallax the far photo adds nothing the near one does not say. Three views prepared
    together, 18 validation scenes not seen before (`docs/lean-chain.md`, "Only the near
    sources"): depth L1 0.0591 -> 0.0592 m, the preparation 0.71x where a source is left
    out; nearer (0.13-0.5 m) the far photo's longer baseline makes the depth 2-10 % better.
    Infinity: every source."""
    far_factor: float = 1.5
    """See ``far_from``."""
    fuse: bool = True
    """Mode "full" with the unguided network loaded: both depths enter the sweep, each pixel
    keeping the one its sources agree with (see `sweep_depth`'s ``others``)."""
    switch_gain: float = 0.0
    """How much better the unguided depth must match to replace the mono-guided one."""
    mono_hypothesis: bool = False
    """Mode "full" fused: the monocular depth enters the sweep as a third hypothesis. Off: it
    pays with the short search only (see ``fusion_sweep``)."""
    select_margin: float = 0.1
    """Pixels whose selector probability is within this of one half keep the photometric
    rule's choice (0: the selector's everywhere): the rule's doubtful choices are single
    pixels, which the median outvotes; the selector's come in patches. Mean L1 of the
    validation sets: 0 0.1552, 0.1 0.1545, 0.2 0.1552."""
    canonical: bool = True
    """Mode "full" with the unguided network loaded: the MVS networks and the sweep work in the
    world scaled by k = median(mono / unguided MVS depth) (`_world_scale`), the room sizes the
    monocular network learned, and the depth is scaled back by 1 / k: the mono prior and the
    cost volume agree on scale, as in training. One more pass of the unguided network.
    Mean L1 (classic and home) with the world scaled by 1, 0.7 and 1.4: off 0.156 / 0.210 /
    0.301, on 0.155 / 0.126 / 0.215."""


def view_sources(
    c2w: Tensor, min_baseline: float, count: int | None = None
) -> tuple[list[list[int]], list[str]]:
    """Each view's sources (the ``count`` nearest other views at least ``min_baseline`` away,
    closer ones giving no parallax; None: all of them, in order) and warnings about the views
    left without."""
    v = c2w.shape[0]
    sources: list[list[int]] = [[] for _ in range(v)]
    warnings: list[str] = []
    centres = c2w[:, :3, 3]
    for ref in range(v):
        dist = torch.linalg.vector_norm(centres - centres[ref], dim=-1)
        src = [j for j in range(v) if j != ref and float(dist[j]) >= min_baseline]
        close = [j for j in range(v) if j != ref and float(dist[j]) < min_baseline]
        if close:
            warnings.append(
                f"view {ref}: views {close} are within {min_baseline} m of it "
                "(no parallax): not used as sources"
            )
        if not src:
            if v > 1:
                warnings.append(f"view {ref}: no usable source, monocular depth")
            continue
        if count is not None and len(src) > count:
            src = sorted(sorted(src, key=lambda j: float(dist[j]))[:count])
        sources[ref] = src
    return sources, warnings


def compared_sources(
    config: DepthConfig, c2w: Tensor, sources: list[list[int]], scale: float = 1.0
) -> list[list[int]]:
    """The sources the sweep and the refinement compare each view with: its
    ``config.sweep_sources`` nearest of ``sources``, less those beyond ``config.far_factor``
    times the nearest one's distance where that is at least ``config.far_from`` (``scale``:
    units of ``c2w`` per metre)."""
    centres = c2w[:, :3, 3] / scale
    out = []
    for r, src in enumerate(sources):
        dist = {j: float(torch.linalg.vector_norm(centres[j] - centres[r])) for j in src}
        near = sorted(src, key=dist.__getitem__)[: config.sweep_sources]
        if near and dist[near[0]] >= config.far_from:
            near = [j for j in near if dist[j] <= config.far_factor * dist[near[0]]]
        out.append(near)
    return out
