"""On-disk cache of a prepared scene: estimated depth and the renderer's feature maps.

Preparing a scene (depth estimation, encoders) takes seconds; opening it again should not.
The cache file is keyed by the scene's content (every panorama's pixels and pose) and by the
weights (their bytes), so any change to either makes a different key. A file that cannot be
read, belongs to another key, or holds wrong shapes or non-finite values is rebuilt, never
trusted. Files are written to a temporary name and renamed, so an interrupted write never
leaves a broken cache under the real name.
"""

from __future__ import annotations

import hashlib
import os
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from panogrf.app.files.atomic import atomic_output
from panogrf.renderer.cache import SceneCache
from panogrf.renderer.methods import METHODS, Models, SourceViews

FORMAT = "panogrf-scene-cache-7"  # 6: no exposure balance of the sources; 7: a checksum
#: The method whose depth and renderer maps the cache holds.
METHOD = METHODS["panogrf"]
#: Largest plausible depth in a cache (metres): far beyond any room or street scene.
MAX_DEPTH_M = 1000.0


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/panogrf`` or ``~/.cache/panogrf``."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "panogrf"


def content_key(
    images: torch.Tensor, c2w: torch.Tensor, weight_files: list[Path], setting: str = ""
) -> str:
    """SHA-256 (hex, 32 chars) of the pixels, the poses, the weight files' bytes and
    ``setting`` (how the depth was made, when not the default: e.g. a per-scene refinement)."""
    h = hashlib.sha256(FORMAT.encode())
    if setting:
        h.update(setting.encode())
    h.update(str(tuple(images.shape)).encode())
    h.update((images.clamp(0, 1) * 255).round().to(torch.uint8).cpu().numpy().tobytes())
    h.update(c2w.to(torch.float64).cpu().numpy().tobytes())
    for path in weight_files:
        h.update(path.name.encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:32]


def _checksum(tensors: dict[str, torch.Tensor]) -> str:
    """SHA-256 of the tensors' names, shapes and bytes (in name order): written with the cache,
    checked on every load, so changed numbers are never shown as the scene."""
    h = hashlib.sha256()
    for name in sorted(tensors):
        t = tensors[name].detach().cpu().contiguous()
        h.update(f"{name} {tuple(t.shape)} {t.dtype}".encode())
        h.update(t.view(torch.uint8).numpy().tobytes() if t.numel() else b"")
    return h.hexdigest()


@dataclass
class CacheResult:
    path: Path
    status: str  # "built", "loaded" or "rebuilt: <why>"
    seconds: float


def _problem(tensors: dict, key: str, views: SourceViews, channels: int) -> str | None:
    """Why a loaded cache cannot be trusted (None: it can). ``channels``: the renderer's
    feature channels; maps hold features, 6 visibility parameters and the depth."""
    meta_key = tensors.get("__key__")
    if meta_key is None:
        return "no key"
    if meta_key.dtype != torch.uint8 or meta_key.ndim != 1:
        return "malformed key"
    if bytes(meta_key.tolist()).decode(errors="replace") != key:
        return "stale (another scene or other weights)"
    depth, maps = tensors.get("depth"), tensors.get("maps")
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


def _cache_path(views: SourceViews, cache_dir: Path | None, weight_files: list[Path]):
    """(key, file) of ``views``' cache: keyed by the pixels, poses, weights and refinement."""
    cache_dir = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    setting = "" if views.refine is None else f"refine {views.refine!r}"
    mask = getattr(views, "nadir_mask", None)  # sources masked at the nadir: keyed by the mask
    if mask is not None:
        mask = mask.to(torch.uint8).cpu().contiguous()
        digest = hashlib.sha256(mask.numpy().tobytes()).hexdigest()
        setting += f" nadir {tuple(mask.shape)} {digest}"
    if views.images.device.type != "cpu":  # another device's arithmetic: its own entry
        setting += f" on {views.images.device.type}"
    key = content_key(views.images, views.c2w, weight_files, setting)
    return key, cache_dir / f"{key}.safetensors"


def load_cached(
    views: SourceViews, models: Models, cache_dir: Path | None, weight_files: list[Path]
) -> tuple[CacheResult | None, str | None]:
    """(the loaded cache's result, None) when a valid cache of ``views`` is on disk (``views``
    filled with its depth and renderer maps), else (None, why not: None if there is none)."""
    import time

    start = time.perf_counter()
    loaded, why = _load(views, models, *_cache_path(views, cache_dir, weight_files))
    if loaded is not None:
        loaded.seconds = time.perf_counter() - start
    return loaded, why


def _load(
    views: SourceViews, models: Models, key: str, path: Path
) -> tuple[CacheResult | None, str | None]:
    """`load_cached` with the cache's key and file already computed (the key hashes the
    weight files' bytes: done once per preparation)."""
    if not path.exists():
        return None, None
    c = models.renderer(METHOD.renderer).config.feature_channels
    try:
        tensors = load_file(str(path))
        with safe_open_metadata(path) as meta:
            stored = meta.get("sha256")
        why = _problem(tensors, key, views, c)
        if why is None and stored != _checksum(tensors):
            why = "checksum mismatch (the file was changed)"
        tensors = {k: t.to(views.images.device) for k, t in tensors.items()}
    except (SafetensorError, OSError, ValueError, RuntimeError) as exc:
        why = f"unreadable ({type(exc).__name__})"
    if why is not None:
        return None, why
    views.depth[METHOD.depth_mode] = tensors["depth"]
    views.caches[METHOD.cache_key] = SceneCache(
        views.images, views.c2w, tensors["depth"], tensors["maps"], c
    )
    return CacheResult(path, "loaded", 0.0), None


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
    views: SourceViews, models: Models, cache_dir: Path | None, weight_files: list[Path]
) -> CacheResult:
    """Fill ``views`` with the depth and renderer cache of the method, from disk when a valid
    cache exists, else by computing them (depth already in ``views`` is used as it is) and
    writing the cache, atomically."""
    import time

    start = time.perf_counter()
    key, path = _cache_path(views, cache_dir, weight_files)
    loaded, why = _load(views, models, key, path)
    if loaded is not None:
        loaded.seconds = time.perf_counter() - start
        return loaded
    cache = build_maps(views, models)
    tensors = {
        "depth": cache.depth.cpu().contiguous(),
        "maps": cache.maps.cpu().contiguous(),
        "__key__": torch.tensor(list(key.encode()), dtype=torch.uint8),
    }
    status = "built" if why is None else f"rebuilt: {why}"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_output(path) as tmp:
            meta = {"format": FORMAT, "sha256": _checksum(tensors)}
            save_file(tensors, str(tmp), metadata=meta)
    # A read-only or full disk (safetensors reports it as its own error) costs the cache only.
    except (OSError, SafetensorError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
        status += f" (not saved: {reason})"
    return CacheResult(path, status, time.perf_counter() - start)


# -- the depth of `panogrf depth` and the demo's depth check --------------------------------------
def estimate_key(images: torch.Tensor, c2w: torch.Tensor, estimator, mode: str) -> str | None:
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
    estimator, images: torch.Tensor, c2w: torch.Tensor, mode: str, cache_dir: Path | None
):
    """``estimator(images, c2w, mode)`` (a `DepthEstimate` on the CPU), from the cache when a
    valid one is there, else estimated and written; (estimate, `CacheResult`). Nothing is read
    or written for an estimator not loaded from the weights files (`estimate_key`)."""
    import json
    import time

    from panogrf.model.depth import DepthEstimate

    start = time.perf_counter()
    key = estimate_key(images, c2w, estimator, mode)
    if key is None:
        est = estimator(images, c2w, mode)
        return est, CacheResult(
            Path("-"), "computed (given networks, not cached)", time.perf_counter() - start
        )
    cache_dir = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    path = cache_dir / f"{key}.safetensors"
    v, _, h, w = images.shape
    why = None
    if path.exists():
        try:
            tensors = load_file(str(path))
            with safe_open_metadata(path) as meta:
                sources = json.loads(meta["sources"])
                warnings = json.loads(meta["warnings"])
            why = _estimate_problem(tensors, key, v, h, w, sources, warnings)
        except (SafetensorError, OSError, ValueError, RuntimeError, KeyError, TypeError) as exc:
            why = f"unreadable ({type(exc).__name__})"
        if why is None:
            est = DepthEstimate(
                tensors["depth"],
                tensors["mono_depth"],
                tensors["out_of_range"].bool(),
                [list(map(int, s)) for s in sources],
                list(warnings),
            )
            return est, CacheResult(path, "loaded", time.perf_counter() - start)
    est = estimator(images, c2w, mode)
    tensors = {
        "depth": est.depth.float().cpu().contiguous(),
        "mono_depth": est.mono.float().cpu().contiguous(),
        "out_of_range": est.out_of_range.cpu().to(torch.uint8).contiguous(),
        "__key__": torch.tensor(list(key.encode()), dtype=torch.uint8),
    }
    metadata = {
        "format": FORMAT,
        "sources": json.dumps([list(map(int, s)) for s in est.sources]),
        "warnings": json.dumps(list(est.warnings)),
    }
    status = "built" if why is None else f"rebuilt: {why}"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_output(path) as tmp:
            save_file(tensors, str(tmp), metadata=metadata)
    except (OSError, SafetensorError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
        status += f" (not saved: {reason})"
    return est, CacheResult(path, status, time.perf_counter() - start)


@contextmanager
def safe_open_metadata(path: Path):
    """The metadata (str -> str) of a safetensors file."""
    from safetensors import safe_open

    with safe_open(str(path), framework="pt") as f:
        yield f.metadata() or {}


def _estimate_problem(tensors, key, v, h, w, sources, warnings) -> str | None:
    """Why a loaded depth estimate cannot be trusted (None: it can)."""
    meta_key = tensors.get("__key__")
    if meta_key is None or meta_key.dtype != torch.uint8 or meta_key.ndim != 1:
        return "no key"
    if bytes(meta_key.tolist()).decode(errors="replace") != key:
        return "stale (another scene or other weights)"
    depth, mono, far = (tensors.get(k) for k in ("depth", "mono_depth", "out_of_range"))
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
    if not isinstance(sources, list) or len(sources) != v or not isinstance(warnings, list):
        return "malformed sources or warnings"
    if any(not isinstance(s, list) or any(not 0 <= int(j) < v for j in s) for s in sources):
        return "malformed sources"
    return None
