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
- `estimate_scene` (from `panogrf.app.scene.estimate`): estimate a scene's depth and write it
  as a scene folder of its own (`panogrf depth`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from panogrf.app.errors import UserError
from panogrf.app.scene.estimate import DepthRun, estimate_scene
from panogrf.model.refine import RefineConfig
from panogrf.renderer.methods import METHODS, Models, SourceViews

#: Largest panorama height (rows; width = 2x) of a render, single or along a camera path.
MAX_HEIGHT = 4096

__all__ = [
    "MAX_HEIGHT",
    "DepthRun",
    "PreparedScene",
    "default_models",
    "estimate_scene",
    "prepare_scene",
    "refine_prepared",
    "weight_files",
]


def default_models() -> Models:
    """`Models` that load the shipped weights (each network once per process)."""
    from panogrf.app.weights.networks import NETWORKS, load_depth_estimator, load_renderer

    def estimator(mode: str):
        return load_depth_estimator(NETWORKS[mode])

    return Models(estimator=estimator, renderer=load_renderer)


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
        names.append(dw.RENDERER_WEIGHTS[spec.renderer])
    return [dw.weights_path(name) for name in names]


@dataclass
class PreparedScene:
    """A scene ready to render: its files, its source views (depth and caches filled) and the
    networks that prepared it. ``pending_refine``: the per-scene refinement still to be done
    (`refine_prepared`) when the preparation was asked to defer it."""

    scene: object  # panogrf.app.scene.folder.Scene
    views: SourceViews
    models: Models
    cache: object  # panogrf.app.scene.cache.CacheResult
    cache_dir: Path | None = None
    on_disk: bool = True  # the shipped networks: the disk cache is read and written
    pending_refine: RefineConfig | None = None


def prepare_scene(
    scene_dir: Path,
    cache_dir: Path | None,
    models: Models | None = None,
    log=print,
    refine: RefineConfig | None = None,
    defer_refine: bool = False,
) -> PreparedScene:
    """Load the scene folder and prepare PanoGRF's depth and caches with ``models`` (default:
    the shipped weights), reading or writing the on-disk cache in ``cache_dir`` (default
    ``~/.cache/panogrf``); ``refine``: the per-scene depth refinement (`SourceViews.refine`).

    ``defer_refine``: unless the refined scene is cached already, prepare the plain one and
    leave the refinement to `refine_prepared` (``pending_refine``): the viewer opens on the
    plain scene and swaps the refined one in when it is done."""
    import time

    from panogrf.app.scene.cache import METHOD, CacheResult, load_cached, prepare_cached
    from panogrf.app.scene.folder import load_scene

    scene = load_scene(scene_dir, load_images=True)
    views = SourceViews(scene.images.images, scene.images.c2w, refine=refine)
    log(f"preparing {scene_dir} ({scene.num_views} views, {scene.width}x{scene.height})...")
    deferring = defer_refine and refine is not None
    on_disk = models is None
    result = files = None
    if on_disk:
        models = default_models()
        files = weight_files("panogrf")
        missing = [p.name for p in files if not p.exists()]
        if missing:
            raise UserError(f"missing weights {missing}: reproduce them with `panogrf train`")
        if deferring:
            result, _ = load_cached(views, models, cache_dir, files)
    pending = None
    if deferring and result is None:  # the plain scene now, the refined one later
        views = SourceViews(views.images, views.c2w, gains=views.gains)
        pending = refine
    if result is None and on_disk:
        result = prepare_cached(views, models, cache_dir, files)
    elif result is None:
        # Other networks than the shipped files: the disk cache (keyed by those files) is
        # neither read nor written.
        start = time.perf_counter()
        views.cache_for(METHOD, models)
        seconds = time.perf_counter() - start
        result = CacheResult(Path("-"), "computed (given networks, not cached)", seconds)
    what = "scene" if refine is None or pending else "refined scene"
    log(f"{what} {result.status} in {result.seconds:.2f} s ({result.path})")
    return PreparedScene(scene, views, models, result, cache_dir, on_disk, pending)


def refine_prepared(prepared: PreparedScene, should_stop=None, log=print) -> PreparedScene | None:
    """``prepared``'s pending refinement done: a new `PreparedScene` whose depth is the plain
    one refined and whose renderer maps are built on it (written to the disk cache when the
    networks are the shipped ones, as `prepare_scene` without deferring would). None when
    ``should_stop`` said so (nothing written)."""
    import time

    from panogrf.app.scene.cache import METHOD, CacheResult, prepare_cached

    refine = prepared.pending_refine
    if refine is None:
        return prepared
    start = time.perf_counter()
    views = prepared.views.refined(refine, prepared.models, should_stop)
    if views is None:
        return None
    if not prepared.on_disk:
        views.cache_for(METHOD, prepared.models)
        result = CacheResult(Path("-"), "computed (given networks, not cached)", 0.0)
    else:
        result = prepare_cached(views, prepared.models, prepared.cache_dir, weight_files())
    result.seconds = time.perf_counter() - start
    log(f"refined scene {result.status} in {result.seconds:.2f} s ({result.path})")
    return PreparedScene(
        prepared.scene, views, prepared.models, result, prepared.cache_dir, prepared.on_disk
    )
