"""`panogrf scene prepare DIR`: a scene's depth and feature maps into the cache, ahead of time.

What `panogrf view` and `panogrf render` prepare before their first pixel (the sources' depth
estimated and refined for the scene, the renderer's feature maps) is written to the same disk
cache they read (`panogrf.app.scene.session`), so that they start at once. Without
``--sources`` every view of the scene is prepared: what `view`, `render --c2w` and
`render --camera-path` use; ``--sources 0,2``: those views only, what
`render --target-frame 1 --sources 0,2` (or `--target-frame 1` on a three-view scene) uses.

The options are declared once, on the fields of `PrepareConfig` (`panogrf.app.options`).
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import dataclass
from pathlib import Path

from panogrf.app.errors import UserError
from panogrf.app.options import add_options, from_args, option
from panogrf.app.runtime import (
    RefineOptions,
    ThreadOptions,
    frame_indices,
    prepare_options,
    refine_setting,
    resolve_device,
)


@dataclass(frozen=True)
class PrepareConfig:
    """The scene `panogrf scene prepare` prepares, and which of its views as the sources. A
    field made with `option` is also an option of the command."""

    dir: Path = option(help="scene folder", positional=True, metavar="SCENE_DIR")
    """The scene folder."""
    sources: list[int] | None = option(
        None,
        "comma-separated frames to prepare as the sources (default: every frame)",
        parse=frame_indices,
    )
    """The frames prepared as the sources (None: every frame)."""


def add_prepare(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "prepare",
        help="prepare a scene ahead of time (depth, feature maps) for view and render",
        description=__doc__.split("\n\n")[1],
        epilog=(
            "examples:\n"
            "  panogrf scene prepare assets/demo            # then: panogrf view assets/demo\n"
            "  panogrf scene prepare assets/demo --sources 0,2\n"
            "  # then: panogrf render assets/demo --target-frame 1 --out mid.png"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_options(
        parser, PrepareConfig, ThreadOptions, RefineOptions, *prepare_options(no_cache=False)
    )
    parser.set_defaults(func=run_prepare)


def run_prepare(args: argparse.Namespace) -> int:
    from panogrf.app.scene import session
    from panogrf.app.scene.folder import load_scene
    from panogrf.renderer.methods import SourceViews
    from panogrf.renderer.nadir import nadir_setting

    cfg = from_args(PrepareConfig, args)
    from_args(ThreadOptions, args).apply()
    _check_cache_dir(args.cache_dir)
    refine = refine_setting(args)
    models = session.default_models(resolve_device(args.device))
    start = time.perf_counter()
    if cfg.sources is None:
        prepared = session.prepare_scene(
            cfg.dir, args.cache_dir, models, refine=refine, log=_quiet, nadir_cap=args.nadir_cap
        )
        result, views = prepared.cache, prepared.scene.num_views
        what = f"all {views} views"
    else:
        scene = load_scene(cfg.dir, load_images=True)
        v = scene.num_views
        bad = [i for i in cfg.sources if not 0 <= i < v]
        if bad:
            raise UserError(f"--sources {bad}: the scene has frames 0..{v - 1}")
        if len(set(cfg.sources)) != len(cfg.sources):
            raise UserError(f"--sources must list distinct frames, got {cfg.sources}")
        data = scene.images
        views = SourceViews(
            data.images[cfg.sources],
            data.c2w[cfg.sources],
            refine=refine,
            nadir=nadir_setting(scene.metadata, args.nadir_cap),
            device=models.device,
        )
        result = session.prepare_views(views, models, cache_dir=args.cache_dir)
        what = f"sources {','.join(map(str, cfg.sources))}"
    if result.path == Path("-"):  # e.g. missing weights were reported before; belt and braces
        raise UserError(f"the scene was prepared but not cached: {result.status}")
    # One source has no other to refine its depth against.
    alone = cfg.sources is not None and len(cfg.sources) == 1
    refined = "refined depth" if refine is not None and not alone else "unrefined depth"
    print(
        f"prepared {cfg.dir} ({what}, {refined}): scene cache {result.status} in "
        f"{time.perf_counter() - start:.2f} s ({result.path})"
    )
    if "not saved" in result.status:
        raise UserError(f"could not write the cache {result.path}: {result.status}")
    return 0


def _check_cache_dir(cache_dir: Path | None) -> None:
    """Refuse, before any work, a cache folder (None: the user's) that cannot be made or
    written: the cache is this command's one output."""
    from panogrf.app.files.atomic import check_writable
    from panogrf.app.scene.store import default_cache_dir

    folder = cache_dir or default_cache_dir()  # a file given is refused by the option's parser
    # The folder named as the user chose it: the option, or the variable behind the default.
    named = f"--cache-dir {folder}" if cache_dir else _default_origin(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{named}: cannot make it ({exc.strerror or exc})") from None
    check_writable(folder / "cache", "--cache-dir" if cache_dir else named)


def _default_origin(folder: Path) -> str:
    """The default cache folder as a message names it, with where it came from."""
    origin = "$XDG_CACHE_HOME" if os.environ.get("XDG_CACHE_HOME") else "$HOME"
    return f"the cache folder {folder} (from {origin}; --cache-dir chooses another)"


def _quiet(*_args) -> None:
    """`prepare_scene`'s log: the summary line above says it all."""
