"""`panogrf view SCENE`: walk through a scene in a window (or headless on EGL)."""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

from panogrf.app.errors import UserError
from panogrf.app.runtime import (
    add_prepare_options,
    add_refine_depth,
    number,
    refine_setting,
    resolve_device,
    thread_count,
)


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from None
    if not (64 <= w <= 8192 and 64 <= h <= 8192):
        raise argparse.ArgumentTypeError(f"window size out of range: {text}")
    return w, h


KEYS = (
    "Keys: W/A/S/D move, Q/E down/up, arrows or mouse drag look, [ ] speed, - = field of view, "
    "V panorama/perspective, 1 refined, 2 preview, 3 distance, 4 source views (Tab: next, "
    "J: jump there), R reset the view, K add keyframe, G go to the next keyframe, Backspace "
    "delete it, , . its transition -/+ 0.5 s, C clear keyframes, P play/stop the path (real "
    "time), O save it (camera_path.json), X screenshot, F clean 2:1 panorama, H overlay, Esc quit."
)


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "view",
        help="walk through a scene (window, or headless on EGL)",
        description=(
            "Open a scene: it is prepared once (depth estimation, feature maps; cached on disk "
            "keyed by the scene's content and the weights), then the camera moves freely: a GL "
            "preview follows every move, and when the camera stops the neural renderer refines "
            "the view at increasing resolution. " + KEYS
        ),
        epilog="example: panogrf view assets/demo",
    )
    parser.add_argument("scene", type=Path, metavar="SCENE", help="scene folder (transforms.json)")
    parser.add_argument(
        "--window",
        choices=("pyglet", "headless"),
        default="pyglet",
        help="pyglet (a window; needs a display) or headless (EGL, no display)",
    )
    parser.add_argument("--size", type=_size, default=(1024, 512), help="window size WxH")
    parser.add_argument("--start-frame", type=int, default=0, help="start at this view's pose")
    parser.add_argument("--no-refine", action="store_true", help="preview only (no network)")
    parser.add_argument(
        "--path-out",
        type=Path,
        default=Path("camera_path.json"),
        help="where O saves the camera path (default camera_path.json)",
    )
    parser.add_argument(
        "--drag-looks",
        action="store_true",
        help="dragging turns the camera with the mouse (as in games) instead of moving the "
        "image with the cursor (as in 360-degree photo viewers)",
    )
    parser.add_argument(
        "--camera-path",
        type=Path,
        default=None,
        help="start with the keyframes of this camera path (one O saved, or any nerfstudio "
        "camera_path.json; in the scene's world): P plays it, keys edit it, O saves it",
    )
    parser.add_argument(
        "--screenshot-dir",
        type=Path,
        default=Path("."),
        help="where X saves screenshots (default: here)",
    )
    parser.add_argument(
        "--frames", type=int, default=None, help="close after this many frames (headless runs)"
    )
    parser.add_argument(
        "--script",
        default="",
        help='scripted keys, e.g. "w*30,x,wait*10": hold w 30 frames, press x',
    )
    parser.add_argument(
        "--fixed-step",
        type=number(float, 0.0, 10.0, low_open=True),
        default=None,
        help="seconds of camera motion per frame (default: the wall clock)",
    )
    parser.add_argument(
        "--moving-rows",
        type=int,
        default=None,
        help="rows the GL preview's geometry is drawn at while the camera moves (default: the "
        "viewer's, ViewerSetup.moving_height; 512: full resolution); its colours are read at "
        "512 rows (see --no-sharp)",
    )
    parser.add_argument(
        "--no-sharp",
        action="store_true",
        help="show the GL preview upsampled from the rows it is drawn at while moving, and draw "
        "a still camera's at 512 rows, instead of reading the colours at 512 rows (softer while "
        "moving, cheaper per frame on a CPU rasteriser)",
    )
    parser.add_argument(
        "--threads", type=thread_count, default=0, help="torch threads (default: all)"
    )
    add_refine_depth(parser)
    add_prepare_options(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from panogrf.app.viewer.torch_threads import serial_main_thread

    if args.window == "pyglet" and not _has_display():
        raise UserError(
            "no display for a window: set DISPLAY (e.g. under Xvfb) or use --window headless"
        )
    if args.frames is not None and args.frames < 1:
        raise UserError("--frames must be at least 1")
    if args.moving_rows is not None and not 16 <= args.moving_rows <= 512:
        raise UserError("--moving-rows must be between 16 and 512")
    # The main thread only draws; the torch work runs in other threads (torch_threads).
    with serial_main_thread() as threads:
        return _session(args, args.threads or threads)


def _session(args: argparse.Namespace, threads: int) -> int:
    """`run` once the main thread is serial: ``threads`` torch threads for the others."""
    import numpy as np

    from panogrf.app.viewer.screen import refine_summary
    from panogrf.app.viewer.setup import UPSAMPLED_MOVING_ROWS, ViewerSetup
    from panogrf.app.viewer.torch_threads import off_main_thread
    from panogrf.app.viewer.window import parse_script, run_viewer
    from panogrf.app.viewer.worker import RenderWorker

    try:
        script = parse_script(args.script)
    except ValueError as exc:
        raise UserError(f"--script: {exc}") from None
    keyframes = []
    if args.camera_path is not None:  # read first: a bad file fails before minutes of work
        from panogrf.app.paths.camera_path import read_camera_path
        from panogrf.app.viewer.recording import keyframes_from_path

        try:
            keyframes = keyframes_from_path(read_camera_path(args.camera_path))
        except ValueError as exc:
            raise UserError(f"{args.camera_path}: {exc}") from None
    from panogrf.app.runtime import refuse_scene_inputs
    from panogrf.app.scene.folder import load_scene

    # O must never write over what the scene is made of (checked before minutes of work).
    refuse_scene_inputs(args.path_out, load_scene(args.scene), "--path-out")
    from panogrf.app.scene import session

    # The refined scene when it is cached; else the plain one now and the refinement in the
    # background, swapped in when done (SceneRefiner).
    prepared = off_main_thread(
        threads,
        session.prepare_scene,
        args.scene,
        args.cache_dir,
        session.default_models(resolve_device(args.device)),
        refine=refine_setting(args),
        defer_refine=True,
        use_cache=not args.no_cache,
        nadir_cap=args.nadir_cap,
    )
    scene, views, models = prepared.scene, prepared.views, prepared.models
    if not 0 <= args.start_frame < scene.num_views:
        raise UserError(f"--start-frame: the scene has frames 0..{scene.num_views - 1}")
    refiner = None
    if prepared.pending_refine is not None:
        from panogrf.app.viewer.scene_refiner import SceneRefiner

        print("refining the depth in the background; the view switches to it when done")
        refiner = SceneRefiner(prepared).start()
    worker = None
    if not args.no_refine:
        cache = off_main_thread(threads, views.cache_for, "panogrf", models)
        worker = RenderWorker(models.renderer("panogrf"), cache, threads=threads).start()
    moving = args.moving_rows or (UPSAMPLED_MOVING_ROWS if args.no_sharp else None)
    setup = ViewerSetup.from_views(
        views,
        args.start_frame,
        worker=worker,
        path_out=args.path_out,
        screenshot_dir=args.screenshot_dir,
        fixed_step=args.fixed_step,
        frames=args.frames,
        script=script,
        sharp=not args.no_sharp,
        scene_refiner=refiner,
        origin=scene.images.origin,
        drag_looks=args.drag_looks,
        keyframes=[dataclasses.replace(k, c2w=scene.images.local(k.c2w)) for k in keyframes],
        keyframes_from=str(args.camera_path),
        **({"moving_height": moving} if moving else {}),
    )
    start = time.perf_counter()
    try:
        config = run_viewer(setup, args.window, args.size)
    finally:
        if worker is not None:
            worker.stop()
        if refiner is not None:
            refiner.stop()
    times = config.frame_times
    if times:
        moving = config.moving_frame_times
        stats = [f"median frame {1000 * float(np.median(times)):.1f} ms"]
        if moving:
            stats.append(f"while moving {1000 * float(np.median(moving)):.1f} ms")
        if worker is not None:
            stats += refine_summary(config.refine_log, len(worker.levels))
        print(
            f"closed after {config.frame_count} frames in {time.perf_counter() - start:.1f} s "
            f"({', '.join(stats)})"
        )
    if worker is not None and worker.error:  # the session went on without refinement
        print(f"panogrf view: error: refinement stopped: {worker.error}", file=sys.stderr)
        return 1
    return 0


def _has_display() -> bool:
    import os

    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) or (
        sys.platform in ("darwin", "win32")
    )
