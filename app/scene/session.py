"""The library layer under the commands: the shipped networks and a prepared scene.

Commands (`panogrf render`, `eval`, `view`, `demo`, `bench`), benchmarks and tests call these
instead of each other's modules:

- `default_models`: `Models` that load the shipped weights (or ``$PANOGRF_WEIGHTS``). Tests
  inject other networks by passing their own `Models` where a function takes ``models``, or by
  replacing this function (``monkeypatch.setattr(session, "default_models", ...)``).
- `weight_files`: every weights file a method's preparation reads, which is what a cached
  preparation must be keyed by.
- `prepare_scene`: load a scene folder and prepare it (depth and renderer caches, from the
  on-disk cache when valid) with the given `Models`.
- `prepare_views`: prepare given `SourceViews` (a subset of a scene's views, say) for a
  method: from or into the same on-disk cache where the method reads what it holds (PanoGRF's
  depth and feature maps), computed otherwise. `render`, `eval`, `bench` and `demo` prepare
  through it, `view` and `scene prepare` through `prepare_scene`: one cache for all.
- `estimate_scene` (from `panogrf.app.scene.estimate`): estimate a scene's depth and write it
  as a scene folder of its own (`panogrf depth`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from panogrf.app.scene.cache import CacheResult
from panogrf.app.scene.estimate import DepthRun, estimate_scene
from panogrf.app.scene.store import DiskStore, Store
from panogrf.model.depth_config import DepthMode
from panogrf.model.refine import RefineConfig
from panogrf.model.render_net import RendererPreset
from panogrf.renderer.methods import METHODS, Models, SourceViews
from panogrf.renderer.render import Quality

if TYPE_CHECKING:
    from panogrf.app.scene.folder import Scene

#: Largest panorama height (rows; width = 2x) of a render, single or along a camera path.
MAX_HEIGHT = 4096

__all__ = [
    "MAX_HEIGHT",
    "DepthRun",
    "PreparedScene",
    "ShippedModels",
    "default_models",
    "estimate_scene",
    "prepare_scene",
    "prepare_views",
    "refine_prepared",
    "weight_files",
]


class ShippedModels(Models):
    """`Models` that load the weights files (`weight_files`): the only networks whose
    preparations the disk cache, keyed by those files, may hold. Any other `Models` (a test's,
    a training's) is prepared afresh and never cached."""


def default_models(device: torch.device | str = "cpu") -> Models:
    """`Models` that load the shipped weights onto ``device`` (each network once per process
    and device)."""
    from panogrf.app.weights.networks import NETWORKS, load_depth_estimator, load_renderer

    device = torch.device(device)
    if device.type == "cuda":
        # TF32 convolutions move the estimated depth by 2-4 mm against the CPU's; in float32
        # it is the CPU's within 1e-5 m (lab/results/gpu_parity.json). The networks are
        # small: the GPU's time goes to launches, not to this arithmetic.
        torch.backends.cudnn.allow_tf32 = False
        torch.backends.cuda.matmul.allow_tf32 = False

    def estimator(mode: DepthMode):
        return load_depth_estimator(NETWORKS[mode], str(device))

    def renderer(preset: RendererPreset):
        return load_renderer(preset, str(device))

    return ShippedModels(estimator=estimator, renderer=renderer, device=device)


def weight_files(method: str = "panogrf") -> list[Path]:
    """The weights files ``method``'s preparation reads: the monocular network, every MVS
    network its depth mode loads (mode full also runs the unguided network and the selector
    for the fusion) and its renderer."""
    from panogrf.app.weights import networks as dw

    spec = METHODS[method]
    names = []
    if spec.depth_mode is not None:
        names += dw.depth_weight_files(spec.depth_mode).values()
    if spec.renderer is not None:
        names.append(dw.renderer_file(spec.renderer))
    return [dw.weights_path(name) for name in names]


@dataclass(frozen=True)
class PreparedScene:
    """A scene ready to render: its files, its source views (depth and caches filled), the
    networks that prepared it and where its preparation is kept. Immutable: the per-scene
    refinement (`refine_prepared`) makes a new one."""

    scene: Scene
    views: SourceViews
    models: Models
    cache: CacheResult
    """Where the preparation came from or went ("loaded", "built", "not cached: why", ...)."""
    store: Store | None = None
    """The store the preparation is read from and put in; None: none (networks other than the
    shipped files, or ``use_cache=False``)."""
    pending_refine: RefineConfig | None = None
    """The per-scene refinement still to be done (`refine_prepared`) when the preparation was
    asked to defer it."""


def prepare_scene(
    scene_dir: Path,
    cache_dir: Path | None,
    models: Models | None = None,
    log=print,
    refine: RefineConfig | None = None,
    defer_refine: bool = False,
    use_cache: bool = True,
    nadir_cap=None,
    store: Store | None = None,
) -> PreparedScene:
    """Load the scene folder and prepare PanoGRF's depth and caches with ``models`` (default:
    the shipped weights), reading or writing the on-disk cache in ``cache_dir`` (default
    ``~/.cache/panogrf``); ``refine``: the per-scene depth refinement (`SourceViews.refine`).

    ``nadir_cap``: the ``--nadir-cap`` value (`panogrf.renderer.nadir.nadir_setting`: else the
    scene's transforms.json setting, else "auto"): the tripod or hand at the bottom of every
    source is masked and never painted into another view.

    ``defer_refine``: unless the refined scene is cached already, prepare the plain one and
    leave the refinement to `refine_prepared` (``pending_refine``): the viewer opens on the
    plain scene and swaps the refined one in when it is done. ``use_cache=False``: the disk
    cache is neither read nor written (nor is it for networks other than the shipped ones,
    `ShippedModels`). The whole is a progress stage around the inner ones."""
    from panogrf.app.scene.folder import load_scene
    from panogrf.model.progress import stage
    from panogrf.renderer.nadir import nadir_setting

    scene = load_scene(scene_dir, load_images=True)  # a bad scene: its error before any stage
    nadir = nadir_setting(scene.metadata, nadir_cap)  # and a bad nadir setting's
    with stage(PREPARING, 1) as progress:
        if use_cache and store is None:
            store = DiskStore(cache_dir)
        prepared = _prepare_scene(
            scene, scene_dir, store if use_cache else None, models, log, refine, defer_refine, nadir
        )
        progress.advance()
    return prepared


#: The progress stage around a whole preparation (its inner stages: depth estimation's,
#: the refinement, the feature maps): it speaks up between them.
PREPARING = "preparing the scene"


def _prepare_scene(scene, scene_dir, store, models, log, refine, defer_refine, nadir=None):
    """`prepare_scene`'s work, on the loaded ``scene``, kept in ``store`` (None: nowhere)."""
    import time

    from panogrf.app.scene.cache import CacheResult, build_maps, load_cached, prepare_cached

    if models is None:
        models = default_models()
    views = SourceViews(
        scene.images.images, scene.images.c2w, refine=refine, nadir=nadir, device=models.device
    )
    log(f"preparing {scene_dir} ({scene.num_views} views, {scene.width}x{scene.height})...")
    deferring = defer_refine and refine is not None
    kept = store if isinstance(models, ShippedModels) else None
    _check_shipped(models, "panogrf")
    result = None
    if kept is not None and deferring:
        result, _ = load_cached(views, models, None, weight_files("panogrf"), kept)
    pending = None
    if deferring and result is None:  # the plain scene now, the refined one later
        views = SourceViews(
            views.images,
            views.c2w,
            nadir=views.nadir,
            nadir_mask=views.nadir_mask,
            nadir_notes=views.nadir_notes,
        )
        pending = refine
    if result is None and kept is not None:
        result = prepare_cached(views, models, None, weight_files("panogrf"), kept)
    elif result is None:
        # Other networks than the shipped files: the store (keyed by those files) is neither
        # read nor written.
        start = time.perf_counter()
        build_maps(views, models)
        seconds = time.perf_counter() - start
        why = "given networks" if store is not None else "--no-cache"
        result = CacheResult(Path("-"), f"computed ({why}, not cached)", seconds)
    what = "scene" if refine is None or pending else "refined scene"
    log(f"{what} {result.status} in {result.seconds:.2f} s ({result.path})")
    return PreparedScene(scene, views, models, result, kept, pending)


def refine_prepared(prepared: PreparedScene, should_stop=None, log=print) -> PreparedScene | None:
    """``prepared``'s pending refinement done: a new `PreparedScene` whose depth is the plain
    one refined and whose renderer maps are built on it (put in the store when it has one, as
    `prepare_scene` without deferring would). None when ``should_stop`` said so (nothing
    written)."""
    import time

    from panogrf.app.scene.cache import CacheResult, build_maps, prepare_cached

    refine = prepared.pending_refine
    if refine is None:
        return prepared
    start = time.perf_counter()
    views = prepared.views.refined(refine, prepared.models, should_stop)
    if views is None:
        return None
    if prepared.store is None:
        build_maps(views, prepared.models)
        result = CacheResult(Path("-"), "computed (not cached)", 0.0)
    else:
        result = prepare_cached(views, prepared.models, None, weight_files(), prepared.store)
    result.seconds = time.perf_counter() - start
    log(f"refined scene {result.status} in {result.seconds:.2f} s ({result.path})")
    return replace(prepared, views=views, cache=result, pending_refine=None)


def _check_shipped(models: Models, method: str) -> None:
    """The weights files ``method`` reads, checked before any work (there, complete, finite:
    `panogrf.app.weights.networks.check_weights`) when ``models`` load them."""
    if isinstance(models, ShippedModels):
        from panogrf.app.weights.networks import check_weights

        check_weights(weight_files(method))


def uses_cache(method: str, quality: Quality = Quality.FAST) -> bool:
    """Whether ``method`` at ``quality`` reads what the scene cache holds: PanoGRF's depth
    (mode full, refined as the views say) and its feature maps. The GL preview and meshwarp
    draw that depth, the renderer presets other than PanoGRF's build their own maps on it;
    the other depth modes and the baselines without depth are prepared afresh."""
    spec = METHODS[method]
    return quality == Quality.PREVIEW or spec.depth_mode == METHODS["panogrf"].depth_mode


def prepare_views(
    views: SourceViews,
    models: Models,
    method: str = "panogrf",
    quality: Quality = Quality.FAST,
    cache_dir: Path | None = None,
    use_cache: bool = True,
    store: Store | None = None,
) -> CacheResult:
    """Compute (once) what ``method`` at ``quality`` needs of ``views`` before the first
    pixel, every stage showing its progress (`panogrf.model.progress`). Where the method reads
    what the scene cache holds (`uses_cache`) and the networks are the shipped ones
    (`ShippedModels`), PanoGRF's depth and feature maps come from ``store`` (default: the
    cache folder ``cache_dir``, itself by default ``~/.cache/panogrf``) when it holds a valid
    entry, and are put there otherwise; ``use_cache=False`` neither reads nor writes it.
    Returns the cache's `CacheResult` (its ``status``: "loaded", "built", "rebuilt: why", or
    "not cached: why").
    The whole is a progress stage around the inner ones."""
    from panogrf.model.progress import stage

    with stage(PREPARING, 1) as progress:
        if use_cache and store is None:
            store = DiskStore(cache_dir)
        result = _prepare_views(views, models, method, quality, store if use_cache else None)
        progress.advance()
    return result


def _prepare_views(views, models, method, quality, store):
    """`prepare_views`' work, kept in ``store`` (None: nowhere)."""
    import time

    from panogrf.app.scene.cache import CacheResult, build_maps, prepare_cached
    from panogrf.model.progress import stage
    from panogrf.renderer.methods import Kind, prepare

    start = time.perf_counter()
    spec = METHODS[method]
    _check_shipped(models, method)
    if uses_cache(method, quality):  # its depth and maps are PanoGRF's
        _check_shipped(models, "panogrf")
    result = None
    if not uses_cache(method, quality):
        why = f"not cached: {method} does not read PanoGRF's depth"
    elif store is None:
        why = "not cached: --no-cache"
    elif not isinstance(models, ShippedModels):
        why = "not cached: given networks"
    else:
        result = prepare_cached(views, models, None, weight_files("panogrf"), store)
    if quality == Quality.PREVIEW:
        views.depth_for(METHODS["panogrf"].depth_mode, models)
    elif spec.kind is Kind.NEURAL:
        build_maps(views, models, spec)
    elif spec.kind is Kind.SNERF and "snerf" not in views.fitted:
        with stage("fitting S-NeRF", 1) as progress:
            prepare(method, views, models)
            progress.advance()
    else:
        prepare(method, views, models)
    if result is None:
        result = CacheResult(Path("-"), why, 0.0)
    result.seconds = time.perf_counter() - start
    return result
