"""`panogrf view SCENE`: walk through a scene in a window (or headless on EGL).

The options are declared once, on the fields of `ViewConfig` (`panogrf.app.options`).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from panogrf.app.errors import UserError
from panogrf.app.options import add_options, from_args, option
from panogrf.app.runtime import (
    RefineOptions,
    ThreadOptions,
    number,
    prepare_options,
    refine_setting,
    resolve_device,
)


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from None
    if not (64 <= w <= 8192 and 64 <= h <= 8192):
        raise argparse.ArgumentTypeError(f"window size {text}: each side 64 to 8192 px")
    return w, h


KEYS = (
    "Keys: W/A/S/D move, Q/E down/up, arrows or mouse drag look, [ ] speed, - = field of view, "
    "V panorama/perspective, 1 refined, 2 preview, 3 distance, 4 source views (Tab: next, "
    "J: jump there), R reset the view, K add keyframe, G go to the next keyframe, Backspace "
    "delete it, , . its transition -/+ 0.5 s, C clear keyframes, P play/stop the path (real "
    "time), O save it (camera_path.json), X screenshot, F clean 2:1 panorama, H overlay, Esc quit."
)


@dataclass(frozen=True)
class ViewConfig:
    """How `panogrf view` opens a scene. A field made with `option` is also an option of the
    command; the settings are checked as they are built (`UserError`, one line naming the
    option)."""

    scene: Path = option(help="scene folder (transforms.json)", positional=True, metavar="SCENE")
    """The scene folder."""
    window: str = option(
        "pyglet",
        "pyglet (a window; needs a display) or headless (EGL, no display)",
        choices=("pyglet", "headless"),
    )
    """``pyglet`` (a window) or ``headless`` (EGL)."""
    size: tuple[int, int] = option((1024, 512), "window size WxH", parse=_size)
    """The window's width and height in pixels."""
    start_frame: int = option(0, "start at this view's pose")
    """The frame whose pose the camera starts at."""
    no_refine: bool = option(
        False,
        "show the GL preview only: no neural refinement of the view (the scene's depth is "
        "still estimated; --no-refine-depth skips its per-scene refinement)",
    )
    """The GL preview only: no neural refinement."""
    live: str = option(
        "auto",
        "the neural view on every frame, also while the camera moves (one render behind it): "
        "on, off (the GL preview while moving, the neural view when still), or auto (on where "
        "the device is a GPU)",
        choices=("auto", "on", "off"),
    )
    """The neural view on every frame (`RenderWorker.live`): on, off or auto (a GPU)."""
    path_out: Path = option(
        Path("camera_path.json"), "where O saves the camera path (default camera_path.json)"
    )
    """Where O saves the camera path."""
    drag_looks: bool = option(
        False,
        "dragging turns the camera with the mouse (as in games) instead of moving the "
        "image with the cursor (as in 360-degree photo viewers)",
    )
    """Dragging turns the camera instead of moving the image with the cursor."""
    camera_path: Path | None = option(
        None,
        "start with the keyframes of this camera path (one O saved, or any nerfstudio "
        "camera_path.json; in the scene's world): P plays it, keys edit it, O saves it",
    )
    """A camera path whose keyframes the session starts with."""
    screenshot_dir: Path = option(Path("."), "where X saves screenshots (default: here)")
    """Where X saves screenshots."""
    frames: int | None = option(None, "close after this many frames (headless runs)")
    """Close after this many frames (None: when the user does)."""
    script: str = option("", 'scripted keys, e.g. "w*30,x,wait*10": hold w 30 frames, press x')
    """Scripted keys (`script_keys`)."""
    fixed_step: float | None = option(
        None,
        "seconds of camera motion per frame (default: the wall clock)",
        parse=number(float, 0.0, 10.0, low_open=True),
    )
    """Seconds of camera motion per frame (None: the wall clock)."""
    moving_rows: int | None = option(
        None,
        "rows the GL preview's geometry is drawn at while the camera moves (default: the "
        "viewer's, ViewerSetup.moving_height; 512: full resolution); its colours are read at "
        "512 rows (see --no-sharp)",
    )
    """Rows the preview's geometry is drawn at while moving (None: the viewer's)."""
    no_sharp: bool = option(
        False,
        "show the GL preview upsampled from the rows it is drawn at while moving, and draw "
        "a still camera's at 512 rows, instead of reading the colours at 512 rows (softer while "
        "moving, cheaper per frame on a CPU rasteriser)",
    )
    """Upsample the moving preview instead of reading its colours at 512 rows."""

    def __post_init__(self) -> None:
        """Refuse a window without a display, ``frames`` under 1, ``moving_rows`` outside 16
        to 512, a ``screenshot_dir`` that is no folder and a script that does not parse
        (`script_keys`)."""
        if self.window == "pyglet" and not _has_display():
            raise UserError(
                "no display for a window: set DISPLAY (e.g. under Xvfb) or use --window headless"
            )
        if self.window == "pyglet" and (shown := _unreachable_display()) is not None:
            raise UserError(
                f"cannot open a window on DISPLAY={shown}: no X server answers there; start "
                "one (e.g. Xvfb) or set DISPLAY to it, or use --window headless"
            )
        if self.live == "on" and self.no_refine:
            raise UserError("--live on shows the neural view: it cannot go with --no-refine")
        if self.frames is not None and self.frames < 1:
            raise UserError("--frames must be at least 1")
        if self.path_out.suffix.lower() != ".json":  # O would replace an image, a video...
            raise UserError(f"--path-out must end in .json (a camera path), got {self.path_out}")
        if self.path_out.exists() and not self.path_out.is_file():  # O would replace it
            raise UserError(f"--path-out: {self.path_out} is not a regular file")
        if self.moving_rows is not None and not 16 <= self.moving_rows <= 512:
            raise UserError("--moving-rows must be between 16 and 512")
        if not self.screenshot_dir.is_dir():  # said before the session, not at the first X
            why = "is not a folder" if self.screenshot_dir.exists() else "does not exist"
            raise UserError(f"--screenshot-dir {self.screenshot_dir}: {why}")
        self.script_keys()

    def script_keys(self) -> list[tuple[str, int]]:
        """The keys ``script`` presses (`panogrf.app.viewer.script.parse_script`)."""
        from panogrf.app.viewer.script import parse_script

        try:
            return parse_script(self.script)
        except ValueError as exc:
            raise UserError(f"--script: {exc}") from None


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
    add_options(parser, ViewConfig, ThreadOptions, RefineOptions, *prepare_options())
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from panogrf.app.viewer.torch_threads import serial_main_thread

    cfg = from_args(ViewConfig, args)
    # The main thread only draws; the torch work runs in other threads (torch_threads).
    with serial_main_thread() as threads:
        return _session(cfg, args, from_args(ThreadOptions, args).threads or threads)


def _keyframes(cfg: ViewConfig) -> list:
    """The keyframes of ``cfg.camera_path`` (none without one), read before minutes of work;
    a bad file refused in one line."""
    if cfg.camera_path is None:
        return []
    from panogrf.app.paths.camera_path import read_camera_path
    from panogrf.app.viewer.recording import keyframes_from_path

    try:
        return keyframes_from_path(read_camera_path(cfg.camera_path))
    except ValueError as exc:
        raise UserError(f"{cfg.camera_path}: {exc}") from None


def _session(cfg: ViewConfig, args: argparse.Namespace, threads: int) -> int:
    """`run` once the main thread is serial: ``threads`` torch threads for the others."""
    from panogrf.app.runtime import refuse_scene_inputs
    from panogrf.app.scene import session
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.viewer.setup import UPSAMPLED_MOVING_ROWS, ViewerSetup
    from panogrf.app.viewer.torch_threads import off_main_thread
    from panogrf.app.viewer.window import run_viewer

    script = cfg.script_keys()
    keyframes = _keyframes(cfg)
    # O must never write over what the scene is made of (checked before minutes of work).
    refuse_scene_inputs(cfg.path_out, load_scene(cfg.scene), "--path-out")
    # The refined scene when it is cached; else the plain one now and the refinement in the
    # background, swapped in when done (SceneRefiner).
    prepared = off_main_thread(
        threads,
        session.prepare_scene,
        cfg.scene,
        args.cache_dir,
        session.default_models(resolve_device(args.device)),
        refine=refine_setting(args),
        defer_refine=True,
        use_cache=not args.no_cache,
        nadir_cap=args.nadir_cap,
    )
    scene, views = prepared.scene, prepared.views
    if not 0 <= cfg.start_frame < scene.num_views:
        raise UserError(f"--start-frame: the scene has frames 0..{scene.num_views - 1}")
    refiner, worker = _background(cfg, prepared, threads)
    moving = cfg.moving_rows or (UPSAMPLED_MOVING_ROWS if cfg.no_sharp else None)
    setup = ViewerSetup.from_views(
        views,
        cfg.start_frame,
        worker=worker,
        path_out=cfg.path_out,
        screenshot_dir=cfg.screenshot_dir,
        fixed_step=cfg.fixed_step,
        frames=cfg.frames,
        script=script,
        sharp=not cfg.no_sharp,
        scene_refiner=refiner,
        origin=scene.images.origin,
        drag_looks=cfg.drag_looks,
        keyframes=[dataclasses.replace(k, c2w=scene.images.local(k.c2w)) for k in keyframes],
        keyframes_from=str(cfg.camera_path),
        **({"moving_height": moving} if moving else {}),
    )
    start = time.perf_counter()
    try:
        config = run_viewer(setup, cfg.window, cfg.size)
    finally:
        if worker is not None:
            worker.stop()
        if refiner is not None:
            refiner.stop()
    return _closed(config, worker, start)


def _background(cfg: ViewConfig, prepared, threads: int) -> tuple:
    """The threads that work behind the window, started: the depth refinement of the
    ``prepared`` scene, where one is pending, and the render worker (none with
    ``--no-refine``), each None where not started."""
    from panogrf.app.viewer.torch_threads import off_main_thread
    from panogrf.app.viewer.worker import LEVELS, LIVE_LEVELS, RenderWorker
    from panogrf.model.render_net import RendererPreset

    refiner = None
    if prepared.pending_refine is not None:
        from panogrf.app.viewer.scene_refiner import SceneRefiner

        print("refining the depth in the background; the view switches to it when done")
        refiner = SceneRefiner(prepared).start()
    worker = None
    if not cfg.no_refine:
        views, models = prepared.views, prepared.models
        cache = off_main_thread(threads, views.cache_for, "panogrf", models)
        live = cfg.live == "on" or (cfg.live == "auto" and models.device.type == "cuda")
        levels = LIVE_LEVELS if live else LEVELS
        net = models.renderer(RendererPreset.PANOGRF)
        worker = RenderWorker(net, cache, levels, threads=threads, live=live).start()
    return refiner, worker


def _closed(config, worker, start: float) -> int:
    """Print how a viewer session that began at ``start`` (`time.perf_counter`) went: its
    frame times and, with a render ``worker``, its refinements; 1 where the worker or a
    write (a screenshot, the camera path) failed."""
    import numpy as np

    from panogrf.app.viewer.screen import refine_summary

    times = config.frame_times
    if times:
        moving = config.moving_frame_times
        stats = [f"median frame {1000 * float(np.median(times)):.1f} ms"]
        if moving:
            stats.append(f"while moving {1000 * float(np.median(moving)):.1f} ms")
        if worker is not None and worker.live and moving:
            stats.append(f"the neural view on {config.neural_moving_frames} of them")
        if worker is not None:
            stats += refine_summary(config.refine_log, len(worker.levels))
        print(
            f"closed after {config.frame_count} frames in {time.perf_counter() - start:.1f} s "
            f"({', '.join(stats)})"
        )
    if worker is not None and worker.error:  # the session went on without refinement
        print(f"panogrf view: error: refinement stopped: {worker.error}", file=sys.stderr)
        return 1
    if config.failed_writes:  # said when they failed; a script must see it in the status
        n = config.failed_writes
        print(f"panogrf view: error: {n} write{'s' if n > 1 else ''} failed", file=sys.stderr)
        return 1
    return 0


def _unreachable_display() -> str | None:
    """``$DISPLAY`` when it names an X display that cannot be opened (as the window would
    open it, with libX11's XOpenDisplay, before minutes of preparation); None when it opens
    or there is no libX11 to ask."""
    import ctypes
    import ctypes.util
    import os

    shown = os.environ.get("DISPLAY")
    lib = ctypes.util.find_library("X11") if shown and sys.platform == "linux" else None
    if shown is None or lib is None:
        return None
    x11 = ctypes.cdll.LoadLibrary(lib)
    x11.XOpenDisplay.restype = ctypes.c_void_p
    x11.XOpenDisplay.argtypes = [ctypes.c_char_p]
    x11.XCloseDisplay.argtypes = [ctypes.c_void_p]
    handle = x11.XOpenDisplay(shown.encode())
    if not handle:
        return shown
    x11.XCloseDisplay(handle)
    return None


def _has_display() -> bool:
    import os

    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) or (
        sys.platform in ("darwin", "win32")
    )
