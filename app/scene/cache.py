"""The prepared scene's entries in the store: estimated depth and the renderer's feature maps.

Preparing a scene (depth estimation, encoders) takes seconds; opening it again should not. An
entry is named by the scene's `Provenance` (every panorama's pixels and pose, the weights'
bytes, how the depth was made), so any change to either names another entry; one whose
tensors have wrong shapes or non-finite values is recomputed, never trusted
(`panogrf.app.scene.store`: the store, reading and writing). The entries are handed to the
`SourceViews` here, by the app: the store never writes into them.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from panogrf.app.scene.store import (
    DiskStore,
    Entry,
    Provenance,
    Store,
    get_or_compute,
    read_valid,
)
from panogrf.model.depth import DepthEstimate, DepthMode
from panogrf.renderer.cache import SceneCache
from panogrf.renderer.methods import METHODS, Models, SourceViews

__all__ = ["CacheResult", "build_maps", "load_cached", "prepare_cached"]

#: The method whose depth and renderer maps the cache holds.
METHOD = METHODS["panogrf"]
#: Largest plausible depth in a cache (metres): far beyond any room or street scene.
MAX_DEPTH_M = 1000.0


def content_key(
    images: torch.Tensor, c2w: torch.Tensor, weight_files: list[Path], setting: str = ""
) -> str:
    """The name of the entry of panoramas ``images`` at poses ``c2w`` prepared with
    ``weight_files`` and ``setting`` (`Provenance.key`)."""
    return Provenance.of(images, c2w, weight_files, setting).key


@dataclass
class CacheResult:
    path: Path
    status: str  # "built", "loaded" or "rebuilt: <why>"
    seconds: float


def _problem(entry: Entry, views: SourceViews, channels: int) -> str | None:
    """Why a stored scene cannot be trusted (None: it can). ``channels``: the renderer's
    feature channels; maps hold features, 6 visibility parameters and the depth."""
    depth, maps = entry.tensors.get("depth"), entry.tensors.get("maps")
    v = views.images.shape[0]
    if depth is None or maps is None:
        return "missing tensors"
    if depth.dtype != torch.float32 or maps.dtype != torch.float32:
        return f"wrong dtypes {depth.dtype}, {maps.dtype} (expected float32)"
    if depth.ndim != 4 or depth.shape[:2] != (v, 1) or depth.shape[-1] != 2 * depth.shape[-2]:
        return f"wrong depth shape {tuple(depth.shape)} (expected [{v}, 1, h, 2h])"
    if maps.shape != (v, channels + 7, *depth.shape[-2:]):
        return (
            f"wrong maps shape {tuple(maps.shape)} "
            f"(expected {(v, channels + 7, *depth.shape[-2:])})"
        )
    if not (torch.isfinite(depth).all() and torch.isfinite(maps).all()):
        return "non-finite values"
    if (depth < 0).any() or depth.max() > MAX_DEPTH_M:
        return f"depth out of range (expected 0 to {MAX_DEPTH_M:g} m)"
    if not torch.equal(maps[:, -1:], depth):
        return "maps and depth disagree"
    return None


def scene_provenance(views: SourceViews, weight_files: list[Path]) -> Provenance:
    """The provenance of ``views``' prepared scene: pixels, poses, weights and refinement, the
    nadir mask where the sources have one, and the device when not the CPU (another device's
    arithmetic gets its own entry)."""
    setting = "" if views.refine is None else f"refine {views.refine!r}"
    mask = views.nadir_mask
    if mask is not None:
        import hashlib

        mask = mask.to(torch.uint8).cpu().contiguous()
        digest = hashlib.sha256(mask.numpy().tobytes()).hexdigest()
        setting += f" nadir {tuple(mask.shape)} {digest}"
    if views.images.device.type != "cpu":
        setting += f" on {views.images.device.type}"
    return Provenance.of(views.images, views.c2w, weight_files, setting)


def _store(store: Store | None, cache_dir: Path | None) -> Store:
    return store if store is not None else DiskStore(cache_dir)


def _adopt(views: SourceViews, entry: Entry, channels: int) -> None:
    """Hand a stored scene's depth and maps to ``views``."""
    depth, maps = (entry.tensors[k].to(views.images.device) for k in ("depth", "maps"))
    views.depth[METHOD.depth_mode] = depth
    views.caches[METHOD.cache_key] = SceneCache(views.images, views.c2w, depth, maps, channels)


def load_cached(
    views: SourceViews,
    models: Models,
    cache_dir: Path | None,
    weight_files: list[Path],
    store: Store | None = None,
) -> tuple[CacheResult | None, str | None]:
    """(the loaded scene's result, None) when the store (default: the cache folder
    ``cache_dir``) holds a valid entry of ``views`` (handed to ``views``: its depth and
    renderer maps), else (None, why not: None if there is none)."""
    start = time.perf_counter()
    store = _store(store, cache_dir)
    key = scene_provenance(views, weight_files).key
    c = models.renderer(METHOD.renderer).config.feature_channels
    entry, why = read_valid(store, key, lambda e: _problem(e, views, c))
    if entry is None:
        return None, why
    _adopt(views, entry, c)
    return CacheResult(store.where(key), "loaded", time.perf_counter() - start), None


def build_maps(views: SourceViews, models: Models, method=METHOD) -> SceneCache:
    """``views``' renderer cache of a neural ``method``: its depth (the estimator's stages show
    their progress) and then its feature maps, a stage of their own."""
    from panogrf.model.progress import stage

    if method.cache_key not in views.caches:
        views.depth_for(method.depth_mode, models)
        with stage("feature maps", 1) as progress:
            views.cache_for(method, models)
            progress.advance()
    return views.cache_for(method, models)


def prepare_cached(
    views: SourceViews,
    models: Models,
    cache_dir: Path | None,
    weight_files: list[Path],
    store: Store | None = None,
) -> CacheResult:
    """Fill ``views`` with the depth and renderer cache of the method: from the store (default:
    the cache folder ``cache_dir``) when it holds a valid entry, else computed (depth already
    in ``views`` is used as it is) and put."""
    start = time.perf_counter()
    store = _store(store, cache_dir)
    key = scene_provenance(views, weight_files).key
    c = models.renderer(METHOD.renderer).config.feature_channels

    def compute() -> Entry:
        cache = build_maps(views, models)
        return Entry({"depth": cache.depth, "maps": cache.maps})

    fetched = get_or_compute(store, key, compute, lambda e: _problem(e, views, c))
    if fetched.status == "loaded":
        _adopt(views, fetched.entry, c)
    return CacheResult(fetched.where, fetched.status, time.perf_counter() - start)


# -- the depth of `panogrf depth` and the demo's depth check --------------------------------------
def estimate_key(images: torch.Tensor, c2w: torch.Tensor, estimator, mode: DepthMode) -> str | None:
    """The cache key of ``estimator``'s depth of mode ``mode`` on the panoramas as given (no
    exposure balance, no refinement, at their resolution: what `panogrf depth` writes), or
    None when the estimator was not loaded from weights files (`weight_files` attribute, set
    by `panogrf.app.weights.networks.load_depth_estimator`): networks of a test or of a
    training are never cached under the files' key."""
    from panogrf.app.weights import networks as dw

    loaded = getattr(estimator, "weight_files", None)
    if not loaded:
        return None
    files = [dw.weights_path(name) for name in dw.depth_weight_files(mode).values()]
    if not set(files) <= set(loaded) or not all(p.exists() for p in files):
        return None
    device = next(estimator.parameters()).device.type
    return content_key(images, c2w, files, f"estimate {mode} on {device}")


def estimate_cached(
    estimator,
    images: torch.Tensor,
    c2w: torch.Tensor,
    mode: DepthMode,
    cache_dir: Path | None,
    store: Store | None = None,
):
    """``estimator(images, c2w, mode)`` (a `DepthEstimate` on the CPU), from the store (default:
    the cache folder ``cache_dir``) when it holds a valid entry, else estimated and put;
    (estimate, `CacheResult`). Nothing is read or put for an estimator not loaded from the
    weights files (`estimate_key`)."""
    start = time.perf_counter()
    key = estimate_key(images, c2w, estimator, mode)
    if key is None:
        est = estimator(images, c2w, mode)
        return est, CacheResult(
            Path("-"), "computed (given networks, not cached)", time.perf_counter() - start
        )
    v, _, h, w = images.shape

    def compute() -> Entry:
        est = estimator(images, c2w, mode)
        tensors = {
            "depth": est.depth.float(),
            "mono_depth": est.mono.float(),
            "out_of_range": est.out_of_range.to(torch.uint8),
        }
        sources = json.dumps([list(map(int, s)) for s in est.sources])
        return Entry(tensors, {"sources": sources, "warnings": json.dumps(list(est.warnings))})

    fetched = get_or_compute(
        _store(store, cache_dir), key, compute, lambda e: _estimate_problem(e, v, h, w)
    )
    t, meta = fetched.entry.tensors, fetched.entry.meta
    est = DepthEstimate(
        t["depth"].cpu(),
        t["mono_depth"].cpu(),
        t["out_of_range"].cpu().bool(),
        [list(map(int, s)) for s in json.loads(meta["sources"])],
        list(json.loads(meta["warnings"])),
    )
    return est, CacheResult(fetched.where, fetched.status, time.perf_counter() - start)


def _estimate_problem(entry: Entry, v: int, h: int, w: int) -> str | None:
    """Why a stored depth estimate cannot be trusted (None: it can)."""
    depth, mono, far = (entry.tensors.get(k) for k in ("depth", "mono_depth", "out_of_range"))
    if depth is None or mono is None or far is None:
        return "missing tensors"
    for name, t in (("depth", depth), ("mono_depth", mono), ("out_of_range", far)):
        if tuple(t.shape) != (v, 1, h, w):
            return f"wrong {name} shape {tuple(t.shape)} (expected {(v, 1, h, w)})"
    if depth.dtype != torch.float32 or mono.dtype != torch.float32:
        return "wrong dtypes"
    if not (torch.isfinite(depth).all() and torch.isfinite(mono).all()):
        return "non-finite values"
    if (depth < 0).any() or depth.max() > MAX_DEPTH_M:
        return f"depth out of range (expected 0 to {MAX_DEPTH_M:g} m)"
    try:
        sources, warnings = json.loads(entry.meta["sources"]), json.loads(entry.meta["warnings"])
    except (KeyError, TypeError, ValueError):
        return "malformed sources or warnings"
    if not isinstance(sources, list) or len(sources) != v or not isinstance(warnings, list):
        return "malformed sources or warnings"
    try:
        if any(not isinstance(s, list) or any(not 0 <= int(j) < v for j in s) for s in sources):
            return "malformed sources"
    except (TypeError, ValueError):
        return "malformed sources"
    return None
