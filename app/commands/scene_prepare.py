"""`panogrf scene prepare DIR`: a scene's depth and feature maps into the cache, ahead of time.

What `panogrf view` and `panogrf render` prepare before their first pixel (the sources' depth
estimated and refined for the scene, the renderer's feature maps) is written to the same disk
cache they read (`panogrf.app.scene.session`), so that they start at once. Without
``--sources`` every view of the scene is prepared: what `view`, `render --c2w` and
`render --camera-path` use; ``--sources 0,2``: those views only, what
`render --target-frame 1 --sources 0,2` (or `--target-frame 1` on a three-view scene) uses.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from panogrf.app.errors import UserError
from panogrf.app.runtime import (
    add_prepare_options,
    add_refine_depth,
    frame_indices,
    refine_setting,
    resolve_device,
    thread_count,
)


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
    parser.add_argument("dir", type=Path, metavar="SCENE_DIR", help="scene folder")
    parser.add_argument(
        "--sources",
        type=frame_indices,
        default=None,
        help="comma-separated frames to prepare as the sources (default: every frame)",
    )
    parser.add_argument(
        "--threads", type=thread_count, default=0, help="torch threads (default: all)"
    )
    add_refine_depth(parser)
    add_prepare_options(parser, no_cache=False)
    parser.set_defaults(func=run_prepare)


def run_prepare(args: argparse.Namespace) -> int:
    from panogrf.app.scene import session
    from panogrf.app.scene.folder import load_scene
    from panogrf.renderer.methods import SourceViews
    from panogrf.renderer.nadir import nadir_setting

    if args.threads:
        torch.set_num_threads(args.threads)
    refine = refine_setting(args)
    models = session.default_models(resolve_device(args.device))
    start = time.perf_counter()
    if args.sources is None:
        prepared = session.prepare_scene(
            args.dir, args.cache_dir, models, refine=refine, log=_quiet, nadir_cap=args.nadir_cap
        )
        result, views = prepared.cache, prepared.scene.num_views
        what = f"all {views} views"
    else:
        scene = load_scene(args.dir, load_images=True)
        v = scene.num_views
        bad = [i for i in args.sources if not 0 <= i < v]
        if bad:
            raise UserError(f"--sources {bad}: the scene has frames 0..{v - 1}")
        if len(set(args.sources)) != len(args.sources):
            raise UserError(f"--sources must list distinct frames, got {args.sources}")
        data = scene.images
        views = SourceViews(
            data.images[args.sources],
            data.c2w[args.sources],
            refine=refine,
            nadir=nadir_setting(scene.metadata, args.nadir_cap),
            device=models.device,
        )
        result = session.prepare_views(views, models, cache_dir=args.cache_dir)
        what = f"sources {','.join(map(str, args.sources))}"
    if result.path == Path("-"):  # e.g. missing weights were reported before; belt and braces
        raise UserError(f"the scene was prepared but not cached: {result.status}")
    refined = "refined depth" if refine is not None else "unrefined depth"
    print(
        f"prepared {args.dir} ({what}, {refined}): scene cache {result.status} in "
        f"{time.perf_counter() - start:.2f} s ({result.path})"
    )
    if "not saved" in result.status:
        raise UserError(f"could not write the cache {result.path}: {result.status}")
    return 0


def _quiet(*_args) -> None:
    """`prepare_scene`'s log: the summary line above says it all."""
