"""Every way this project renders a novel view, behind one interface (CLI, eval, benchmarks).

A `SourceViews` holds the posed source panoramas of one scene and memoises what does not depend
on the target pose: estimated depth per depth mode and the renderer's `SceneCache` per
(renderer preset, depth mode). `render_view` renders a target pose with a named method:

| method        | depth | renderer    | what it is                                           |
|---------------|-------|-------------|------------------------------------------------------|
| panogrf       | full  | panogrf     | the method                                           |
| no_mono       | mvs   | panogrf     | ablation: MVS depth without mono guidance            |
| no_mvs        | mono  | panogrf     | ablation: monocular depth only                       |
| meshwarp      | full  | -           | baseline: depth-warped blend of the sources          |
| nearest       | -     | -           | baseline: nearest source, rotated                    |
| snerf         | -     | -           | baseline: radiance field fitted to the sources       |

Networks come from injected loaders, so this module reads no files. The renderer ablations
(no_geometry, the model-size ladder) are experiments: `lab/ablations.py` adds them.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, cast

import torch
from torch import Tensor

from panogrf.model.depth import DepthEstimator, DepthMode
from panogrf.model.depth_config import compared_sources
from panogrf.model.refine import RefineConfig, refine_depth
from panogrf.model.render_net import RendererNet, RendererPreset
from panogrf.renderer.baselines import render_meshwarp, render_nearest
from panogrf.renderer.cache import RENDER_SOURCES, SceneCache, build_cache
from panogrf.renderer.detail import render_detailed
from panogrf.renderer.nadir import (
    NadirSetting,
    fill_floor_depth,
    inpaint_masked,
    nadir_masks,
)
from panogrf.renderer.perspective import render_perspective
from panogrf.renderer.render import Quality

if TYPE_CHECKING:
    from panogrf.renderer.snerf import SNeRF


class Kind(StrEnum):
    """How a method turns the sources into a view."""

    NEURAL = "neural"  # PanoGRF's renderer on a `SceneCache`
    MESHWARP = "meshwarp"
    NEAREST = "nearest"
    SNERF = "snerf"


@dataclass(frozen=True)
class MethodSpec:
    """A rendering method: the depth it reads, the renderer preset it runs and its kind. The
    one description every caller passes down (no (preset, mode) pairs on the way)."""

    name: str
    depth_mode: DepthMode | None
    """`panogrf.model.depth.MODES` entry, or None for methods that read no depth."""
    renderer: RendererPreset | None
    """`panogrf.model.render_net.PRESETS` entry, for the neural methods."""
    kind: Kind

    @property
    def cache_key(self) -> tuple[RendererPreset, DepthMode]:
        """What a neural method's `SceneCache` depends on: (renderer preset, depth mode)."""
        if self.kind is not Kind.NEURAL:
            raise ValueError(f"method {self.name!r} has no renderer cache")
        assert self.renderer is not None and self.depth_mode is not None  # a neural method's
        return (self.renderer, self.depth_mode)


METHODS: dict[str, MethodSpec] = {
    m.name: m
    for m in (
        MethodSpec("panogrf", DepthMode.FULL, RendererPreset.PANOGRF, Kind.NEURAL),
        MethodSpec("no_mono", DepthMode.MVS, RendererPreset.PANOGRF, Kind.NEURAL),
        MethodSpec("no_mvs", DepthMode.MONO, RendererPreset.PANOGRF, Kind.NEURAL),
        MethodSpec("meshwarp", DepthMode.FULL, None, Kind.MESHWARP),
        MethodSpec("nearest", None, None, Kind.NEAREST),
        MethodSpec("snerf", None, None, Kind.SNERF),
    )
}


@dataclass
class Models:
    """Loaders of the shared networks: ``estimator(mode)`` and ``renderer(preset)``, on
    ``device`` (where `SourceViews` made with ``device=models.device`` put the sources)."""

    estimator: Callable[[DepthMode], DepthEstimator]
    renderer: Callable[[RendererPreset], RendererNet]
    device: torch.device = torch.device("cpu")


@dataclass
class SourceViews:
    """Posed source panoramas of one scene and what is derived from them, memoised.

    The panoramas are used as given: an exposure balance between them bought nothing in the
    leave-one-out of the depth chain (`docs/lean-chain.md`) and left.

    ``refine``: the multi-view depth is refined per scene by photometric consistency between
    the sources (`panogrf.model.refine.refine_depth`, each view against the sources the sweep
    compares it with, `panogrf.model.depth_config.compared_sources`) after the estimator; a
    few seconds per view here, paid once at preparation.

    ``nadir``: the capture rig (tripod, hand) at the bottom of every source is masked
    (`panogrf.renderer.nadir`): "auto" (detected per source), degrees of a cap around the
    nadir, a mask [V, 1, H, W] of its own, or None (the default: nothing masked). On
    construction the masks go to ``nadir_mask`` [V, 1, H, W] bool (None where no source has
    any), the one place every renderer reads them, and the masked pixels of ``images`` are
    filled from the floor around them; the estimated depth there is the floor plane fitted
    around the mask. ``nadir_mask`` given: the images are taken as already filled (a copy of
    prepared views, as `refined` makes).

    ``device``: the sources (and everything derived from them) are moved there first (None:
    where they are); every stage runs on the device of its input.
    """

    images: Tensor  # [V, 3, H, W] in [0, 1]
    c2w: Tensor  # [V, 4, 4]
    depth: dict[DepthMode, Tensor] = field(default_factory=dict)  # mode -> [V, 1, h, w]
    caches: dict[tuple[RendererPreset, DepthMode], SceneCache] = field(default_factory=dict)
    fitted: dict[str, object] = field(default_factory=dict)  # per-scene models (snerf)
    seconds: dict[str, float] = field(default_factory=dict)  # preparation time per item
    refine: RefineConfig | None = None  # per-scene depth refinement (None: none)
    nadir: NadirSetting | Tensor = None  # the rig at the nadir: "auto", degrees, a mask, None
    nadir_mask: Tensor | None = None  # [V, 1, H, W] bool, set on construction from ``nadir``
    nadir_notes: list[str] = field(default_factory=list)  # how each source's mask was found
    device: torch.device | str | None = None  # where the sources go first (None: as given)

    def __post_init__(self) -> None:
        if self.device is not None:
            self.device = torch.device(self.device)
            self.images, self.c2w = self.images.to(self.device), self.c2w.to(self.device)
            if isinstance(self.nadir, Tensor):
                self.nadir = self.nadir.to(self.device)
            if self.nadir_mask is not None:
                self.nadir_mask = self.nadir_mask.to(self.device)
        if self.nadir_mask is None and self.nadir is not None:
            start = time.perf_counter()
            mask: Tensor | None
            if isinstance(self.nadir, Tensor):
                mask, self.nadir_notes = self.nadir.bool(), ["given"] * len(self.images)
            else:
                mask, self.nadir_notes = nadir_masks(self.images, self.nadir)
            if mask is not None and mask.any():
                self.nadir_mask = mask
                self.images = inpaint_masked(self.images, mask)
            self.seconds["nadir"] = time.perf_counter() - start

    def _floor_filled(self, depth: Tensor) -> Tensor:
        """``depth`` with the masked rig's pixels on the floor plane around them."""
        return depth if self.nadir_mask is None else fill_floor_depth(depth, self.nadir_mask)

    def depth_for(self, mode: DepthMode, models: Models) -> Tensor:
        """The estimated depth [V, 1, h, w] of ``mode`` (a `DepthMode` or its value), refined
        as `refine` says; estimated once."""
        mode = DepthMode(mode)
        if mode not in self.depth:
            start = time.perf_counter()
            est = models.estimator(mode)
            small = est.working_height
            with torch.no_grad():
                out = est(_resize(self.images, small), self.c2w, mode, detail=self.images)
            depth = self._floor_filled(out.depth)
            if self.refine is not None and mode != DepthMode.MONO:
                refined = self.refined_depth(depth, mode, models)
                assert refined is not None  # None only when told to stop, and nothing tells it
                depth = self._floor_filled(refined)
            self.depth[mode] = depth
            self.seconds[f"depth:{mode}"] = time.perf_counter() - start
        return self.depth[mode]

    def refined_depth(
        self,
        depth: Tensor,
        mode: DepthMode,
        models: Models,
        should_stop: Callable[[], bool] | None = None,
    ) -> Tensor | None:
        """``depth`` [V, 1, h, w] of ``mode`` refined by `refine` (each view against its
        nearest sources among those the estimator uses); unchanged without sources. None when
        ``should_stop`` said so between steps."""
        est = models.estimator(mode)
        sources, _ = est.view_sources(self.c2w)
        if self.refine is None or not any(sources):
            return depth
        with torch.enable_grad():
            return refine_depth(
                self.images,
                self.c2w.to(depth.dtype),
                depth,
                compared_sources(est.config, self.c2w, sources),
                self.refine,
                (0.05, est.d_max),
                should_stop,
            )

    def refined(
        self,
        refine: RefineConfig,
        models: Models,
        should_stop: Callable[[], bool] | None = None,
    ) -> SourceViews | None:
        """A copy with mode full's depth (estimated here, or already) refined by ``refine``:
        the refinement's input is this depth, so a viewer can show the plain scene first. None
        when ``should_stop`` said so."""
        mode = METHODS["panogrf"].depth_mode
        assert mode is not None  # panogrf reads the depth of mode full
        out = SourceViews(
            self.images,
            self.c2w,
            refine=refine,
            nadir=self.nadir,
            nadir_mask=self.nadir_mask,
            nadir_notes=self.nadir_notes,
        )
        start = time.perf_counter()
        depth = out.refined_depth(self.depth_for(mode, models), mode, models, should_stop)
        if depth is None:
            return None
        out.depth[mode] = out._floor_filled(depth)
        out.seconds[f"refine:{mode}"] = time.perf_counter() - start
        return out

    def cache_for(self, method: MethodSpec | str, models: Models) -> SceneCache:
        """The renderer's cache of a neural ``method`` (a `MethodSpec` or its name)."""
        spec = METHODS[method] if isinstance(method, str) else method
        key = spec.cache_key
        preset, mode = key
        if key not in self.caches:
            depth = self.depth_for(mode, models)
            start = time.perf_counter()
            net = models.renderer(preset)
            with torch.no_grad():
                self.caches[key] = build_cache(net, self.images, self.c2w, depth, self.nadir_mask)
            self.seconds[f"cache:{preset}:{mode}"] = time.perf_counter() - start
        cache = self.caches[key]
        if self.nadir_mask is not None and cache.mask is None:  # e.g. read from the disk cache
            cache = self.caches[key] = cache.with_mask(self.nadir_mask)
        return cache


def _resize(images: Tensor, height: int) -> Tensor:
    from panogrf.renderer.cache import resize_erp

    return resize_erp(images, height)


def prepare(method: str, views: SourceViews, models: Models) -> None:
    """Compute (once) everything ``method`` needs that does not depend on the target pose."""
    spec = METHODS[method]
    if spec.kind is Kind.NEURAL:
        views.cache_for(spec, models)
    elif spec.depth_mode is not None:
        views.depth_for(spec.depth_mode, models)
    elif spec.kind is Kind.SNERF and "snerf" not in views.fitted:
        from panogrf.renderer.snerf import fit_snerf

        start = time.perf_counter()
        views.fitted["snerf"] = fit_snerf(views.images, views.c2w)
        views.seconds["fit:snerf"] = time.perf_counter() - start


def render_view(
    method: str,
    views: SourceViews,
    tgt_c2w: Tensor,
    height: int,
    models: Models,
    quality: Quality = Quality.FAST,
) -> Tensor:
    """The panorama [3, H, 2H] seen from ``tgt_c2w`` [4, 4], rendered by ``method``."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}: one of {sorted(METHODS)}")
    spec = METHODS[method]
    prepare(method, views, models)
    tgt_c2w = tgt_c2w.to(views.c2w)
    if spec.kind is Kind.NEAREST:
        return render_nearest(views.images, views.c2w, tgt_c2w, height)
    if spec.kind is Kind.MESHWARP:
        assert spec.depth_mode is not None  # meshwarp reads a depth
        depth = views.depth[spec.depth_mode]
        return render_meshwarp(views.images, views.c2w, depth, tgt_c2w, height)[0]
    if spec.kind is Kind.SNERF:
        from panogrf.renderer.snerf import render_snerf

        return render_snerf(cast("SNeRF", views.fitted["snerf"]), tgt_c2w, height)
    assert spec.renderer is not None  # a neural method's
    net = models.renderer(spec.renderer)
    cache = views.cache_for(spec, models).nearest(tgt_c2w, RENDER_SOURCES)
    # Above the renderer's training resolution: the network at it plus the sources' detail.
    out = render_detailed(net, cache, tgt_c2w, height, quality)
    assert out is not None  # None only when told to stop
    return out.rgb


def render_perspective_view(
    method: str,
    views: SourceViews,
    tgt_c2w: Tensor,
    width: int,
    height: int,
    fov_deg: float,
    models: Models,
    quality: Quality = Quality.FAST,
) -> Tensor | None:
    """The pinhole view [3, height, width] of a neural ``method``, casting exactly its rays;
    None for the other methods (they render a panorama that is cut, `erp_to_perspective`)."""
    spec = METHODS[method]
    if spec.kind is not Kind.NEURAL:
        return None
    prepare(method, views, models)
    assert spec.renderer is not None  # a neural method's
    net = models.renderer(spec.renderer)
    tgt = tgt_c2w.to(views.c2w)
    cache = views.cache_for(spec, models).nearest(tgt, RENDER_SOURCES)
    out = render_perspective(net, cache, tgt, width, height, fov_deg, quality)
    assert out is not None  # None only when told to stop
    return out.rgb
