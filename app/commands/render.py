"""`panogrf render SCENE --out OUT`: novel views of a scene, one panorama or a whole video.

The target is a frame of the scene (``--target-frame``; that frame is then never used as a
source, and where it has an image the render is scored against it), any pose (``--c2w``,
16 numbers, camera-to-world row-major, OpenGL frame, metres), or a nerfstudio camera path
(``--camera-path``), rendered headless to an H.264 MP4 or a folder of PNG frames.

The options are declared once, on the fields of `RenderConfig` (`panogrf.app.options`).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from panogrf.app.errors import UserError
from panogrf.app.files.atomic import check_writable, nan_to_null
from panogrf.app.options import add_options, from_args, option
from panogrf.app.runtime import (
    RefineOptions,
    ThreadOptions,
    frame_indices,
    prepare_options,
    refine_setting,
    refuse_scene_inputs,
    resolve_device,
)
from panogrf.app.scene import session
from panogrf.app.scene.pose_check import MAX_POSITION_M
from panogrf.app.scene.session import MAX_HEIGHT
from panogrf.model.depth_config import DepthMode
from panogrf.renderer.methods import METHODS, Kind
from panogrf.renderer.nadir import nadir_setting
from panogrf.renderer.render import QUALITY, Quality

#: Largest frame of a camera path (columns x rows): a 2:1 panorama of `MAX_HEIGHT` rows.
MAX_FRAME = (2 * MAX_HEIGHT, MAX_HEIGHT)


def parse_c2w(text: str) -> np.ndarray:
    """16 numbers (row-major 4x4 camera-to-world) -> a validated rigid [4, 4] float64."""
    try:
        values = [float(x) for x in text.translate(str.maketrans("[](),;", "      ")).split()]
    except ValueError:
        raise UserError(f"--c2w: expected 16 numbers, got {text!r}") from None
    if len(values) != 16:
        raise UserError(f"--c2w: expected 16 numbers, got {len(values)}")
    m = np.array(values, dtype=np.float64).reshape(4, 4)
    if not np.isfinite(m).all():
        raise UserError("--c2w: the matrix has NaN or infinite entries")
    rot = m[:3, :3]
    if not np.allclose(m[3], [0, 0, 0, 1], atol=1e-6):
        raise UserError(f"--c2w: the last row must be 0 0 0 1, got {m[3].tolist()}")
    off, det = np.abs(rot.T @ rot - np.eye(3)).max(), np.linalg.det(rot)
    if off > 1e-4 or det < 0:  # a rotation typed to 3 decimals is off by about 1e-3
        why = f"max |R^T R - I| = {off:.2g}, det {det:.3g}; rotations to 6 decimals, no scale"
        raise UserError(f"--c2w: the upper-left 3x3 is not a rotation ({why})")
    if np.abs(m[:3, 3]).max() > MAX_POSITION_M:
        raise UserError(f"--c2w: the position is farther than {MAX_POSITION_M:g} m from the origin")
    return m


@dataclass(frozen=True)
class RenderConfig:
    """What `panogrf render` renders and where it goes. A field made with `option` is also an
    option of the command; the settings are checked as they are built (`UserError`, one line
    naming the option)."""

    scene: Path = option(help="scene folder (transforms.json)", positional=True, metavar="SCENE")
    """The scene folder."""
    out: Path = option(
        help="output image (.png, .jpg); with --camera-path a video (.mp4) or a folder"
    )
    """The panorama (.png, .jpg); with a camera path a video (.mp4) or a folder of frames."""
    target_frame: int | None = option(None, "render the pose of this frame", one_of="target")
    """The frame whose pose is rendered (held out of the sources)."""
    c2w: str | None = option(
        None, "render this pose: 16 numbers, row-major camera-to-world", one_of="target"
    )
    """The pose rendered: 16 numbers (`parse_c2w`)."""
    camera_path: Path | None = option(
        None,
        "render every camera of a nerfstudio camera_path.json to --out (.mp4 or folder)",
        one_of="target",
    )
    """A nerfstudio camera path rendered to ``out``."""
    sources: list[int] | None = option(
        None,
        "comma-separated source frames (default: every frame but the target)",
        parse=frame_indices,
    )
    """The source frames (None: every frame but the target)."""
    height: int | None = option(
        None, "output height; width = 2x (default: the scene's, at most 4096)"
    )
    """Rows of the panorama (None: the scene's, at most `MAX_HEIGHT`)."""
    method: str = option("panogrf", "default panogrf", choices=tuple(sorted(METHODS)))
    """The method (`panogrf.renderer.methods.METHODS`)."""
    quality: Quality = option(
        None,
        "preview (GL depth-mesh warp), draft (neural, 3 + 1 samples: the viewer's first "
        "refinement), fast (depth-guided neural, 8 + 4, default) or paper (neural, 64 + 64 "
        "samples); the neural methods only",
        choices=(Quality.PREVIEW, *sorted(QUALITY)),
    )
    """The sampling, or ``preview`` (the GL depth-mesh warp); given as None: fast."""
    json: bool = option(False, "print the summary as JSON")
    """Print the summary as JSON."""

    def __post_init__(self) -> None:
        """Refuse anything but exactly one target, a camera path with a size or sources of
        its own, an output that is no .png or .jpg (no camera path) or cannot be written
        (`check_writable`), the preview with another method, a quality given to a method that
        does not sample (not neural), a height outside 8 to `MAX_HEIGHT` rows and a ``c2w``
        that is no rigid pose (`parse_c2w`)."""
        given = [x is not None for x in (self.target_frame, self.c2w, self.camera_path)]
        if sum(given) != 1:
            raise UserError("give one of --target-frame, --c2w and --camera-path")
        if self.camera_path is not None:
            if self.sources is not None or self.height is not None:
                raise UserError(
                    "--camera-path takes its size from the path; drop --height/--sources"
                )
        else:
            if self.out.suffix.lower() not in (".png", ".jpg", ".jpeg"):
                raise UserError(f"--out must be a .png or .jpg file, got {self.out}")
            check_writable(self.out)  # a folder of that name, a read-only place: before any work
        if self.quality is None:  # not given: the default, whatever the method
            object.__setattr__(self, "quality", Quality.FAST)
        elif self.quality == Quality.PREVIEW and self.method != "panogrf":
            raise UserError(
                "--quality preview is the GL depth-mesh preview: use it without --method"
            )
        elif self.method in METHODS and METHODS[self.method].kind is not Kind.NEURAL:
            raise UserError(
                f"--quality {self.quality} does nothing for --method {self.method} (only the "
                "neural methods sample): drop --quality"
            )
        if self.height is not None and not 8 <= self.height <= MAX_HEIGHT:
            raise UserError(f"--height must be between 8 and {MAX_HEIGHT}, got {self.height}")
        if self.c2w is not None:
            parse_c2w(self.c2w)


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "render",
        help="render a novel panorama of a scene",
        description=(
            "Render the panorama seen from a frame of the scene (--target-frame, held out of "
            "the sources) or from any pose (--c2w) with PanoGRF or a baseline. The sources' "
            "depth and feature maps are prepared once and cached on disk (shared with view, "
            "eval, bench, demo and scene prepare; --cache-dir, --no-cache). With a target frame "
            "that has an image, prints PSNR, WS-PSNR, SSIM and LPIPS against it."
        ),
        epilog=(
            "examples:\n"
            "  panogrf render assets/demo --out mid.png --target-frame 1 --sources 0,2\n"
            '  panogrf render assets/demo --out p.png --c2w "1 0 0 0.3 0 1 0 1.5 0 0 1 0 '
            '0 0 0 1" --height 256 --quality paper\n'
            "  panogrf render assets/demo --camera-path path.json --out tour.mp4 --quality preview"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_options(parser, RenderConfig, ThreadOptions, RefineOptions, *prepare_options())
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    cfg = from_args(RenderConfig, args)
    from_args(ThreadOptions, args).apply()
    if cfg.camera_path is not None:
        return run_path(cfg, args)
    return run_pose(cfg, args)


def _source_frames(cfg: RenderConfig, frames: int) -> list[int]:
    """The source frames of a scene of ``frames`` views: ``cfg.sources``, else every frame
    but the target (none: refused); refused in one line where out of range, holding the target
    frame or repeating one."""
    v, target = frames, cfg.target_frame
    if target is not None and not 0 <= target < v:
        raise UserError(f"--target-frame {target}: the scene has frames 0..{v - 1}")
    sources = cfg.sources if cfg.sources is not None else [i for i in range(v) if i != target]
    if not sources and cfg.sources is None:
        raise UserError(f"the scene has only {v} view: nothing to render frame {target} from")
    bad = [i for i in sources if not 0 <= i < v]
    if bad:
        raise UserError(f"--sources {bad}: the scene has frames 0..{v - 1}")
    if target is not None and target in sources:
        raise UserError(f"--sources must not contain the target frame {target}")
    if len(set(sources)) != len(sources) or not sources:
        raise UserError(f"--sources must list distinct frames, got {sources}")
    return sources


def _source_views(args: argparse.Namespace, scene, sources: list[int] | None = None):
    """The `SourceViews` of frames ``sources`` of ``scene`` (None: all) as the preparation
    options in ``args`` ask (device, depth refinement, nadir cap), and the networks
    (`default_models`)."""
    from panogrf.renderer.methods import SourceViews

    images, c2w = scene.images.images, scene.images.c2w
    models = session.default_models(resolve_device(args.device))
    views = SourceViews(
        images if sources is None else images[sources],
        c2w if sources is None else c2w[sources],
        refine=refine_setting(args),
        nadir=nadir_setting(scene.metadata, args.nadir_cap),
        device=models.device,
    )
    return views, models


def run_pose(cfg: RenderConfig, args: argparse.Namespace) -> int:
    """``--target-frame`` or ``--c2w``: one panorama, scored against the target frame's."""
    from panogrf.app.files.images import to_uint8, write_rgb
    from panogrf.app.paths.frames import FrameRenderer
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scoring import SCORE_ROWS, image_scores
    from panogrf.model.progress import stage

    scene = load_scene(cfg.scene, load_images=True)
    refuse_scene_inputs(cfg.out, scene)
    sources = _source_frames(cfg, scene.num_views)
    data = scene.images
    # Poses of the scene's world, in double precision: the renderer takes them relative to the
    # scene's origin (`SceneImages.origin`), so map-grid coordinates keep their millimetres.
    target = cfg.target_frame
    tgt = scene.c2w[target] if target is not None else parse_c2w(cfg.c2w)
    height = cfg.height or min(scene.height, MAX_HEIGHT)  # a 16K scene: 4096 rows unless asked
    views, models = _source_views(args, scene, sources)
    start = time.perf_counter()
    frames = FrameRenderer(views, models, cfg.quality, cfg.method, data.origin)
    try:
        frames.check_height(height)
        cache = session.prepare_views(
            views, models, cfg.method, cfg.quality, args.cache_dir, not args.no_cache
        )
        frames.prepare()
        prep = time.perf_counter() - start
        if target is None:  # a pose of one's own: warned as a camera path's frame
            _warn_pose(tgt, scene.c2w[sources], views)
        start = time.perf_counter()
        with stage("rendering", 1) as progress:
            rgb = frames.panorama(tgt, height)
            progress.advance()
        seconds = time.perf_counter() - start
    finally:
        frames.release()
    try:
        with stage(f"writing {cfg.out.name}", 1) as progress:
            write_rgb(cfg.out, to_uint8(rgb))
            progress.advance()
    except OSError as exc:
        raise UserError(f"cannot write {cfg.out}: {exc.strerror or exc}") from None
    summary = {
        "out": str(cfg.out),
        "method": cfg.method,
        "quality": cfg.quality,
        "size": [2 * height, height],  # width x height
        "sources": sources,
        "prepare_s": round(prep, 3),
        "cache": {"status": cache.status, "path": str(cache.path)},
        "render_ms": round(1000 * seconds, 1),
    }
    if target is not None:
        summary["target_frame"] = target
        summary["metrics"] = image_scores(rgb, data.images[target : target + 1])
        summary["ssim_lpips_rows"] = min(height, SCORE_ROWS)
    _print_summary(cfg, summary, prep, seconds)
    return 0


def _print_summary(cfg: RenderConfig, summary: dict, prep: float, seconds: float) -> None:
    """Print a render's ``summary`` (`run_pose`; ``prep`` and ``seconds``: the preparation's
    and the render's time): as JSON with ``--json``, else in words."""
    if cfg.json:  # a score below its minimum size (NaN) as null
        print(json.dumps(nan_to_null(summary), indent=2, allow_nan=False))
        return
    from panogrf.app.scoring import SCORE_ROWS

    width, height = summary["size"]
    print(
        f"wrote {cfg.out} ({width}x{height}, {cfg.method}, {cfg.quality}): "
        f"prepared in {prep:.2f} s (scene cache {summary['cache']['status']}), rendered in "
        f"{1000 * seconds:.0f} ms"
    )
    if "metrics" in summary:
        m = summary["metrics"]
        scored = "" if height <= SCORE_ROWS else f" (SSIM, LPIPS at {2 * SCORE_ROWS}x{SCORE_ROWS})"
        scored = " (n/a: too few rows for SSIM or LPIPS)" if math.isnan(m["lpips"]) else scored
        print(
            f"vs frame {cfg.target_frame}: PSNR {m['psnr']:.2f} dB, "
            f"WS-PSNR {m['ws_psnr']:.2f} dB, SSIM {m['ssim']:.4f}, LPIPS {m['lpips']:.4f}{scored}"
        )


def _warn_pose(tgt: np.ndarray, sources: np.ndarray, views) -> None:
    """The warnings a camera path's frame gets, for one ``--c2w`` pose [4, 4] (issue 57, S2):
    far from every source, or behind the surface its nearest source sees. On stderr: stdout
    may be ``--json``."""
    from panogrf.app.scene import coverage as cv

    if cv.uncovered(tgt[None], sources)[0]:
        far = float(cv.nearest_source_distance(tgt[None], sources)[0])
        print(
            f"warning: the --c2w pose is {far:.2f} m from the nearest source, outside the region "
            f"the sources cover ({cv.covered_radius(sources):.2f} m): expect holes and stretched "
            "geometry",
            file=sys.stderr,
        )
    if DepthMode.FULL in views.depth:
        depth = views.depth[DepthMode.FULL][:, 0].double().cpu().numpy()
        hit = cv.behind_surface(tgt[:3, 3], sources, depth)
        if hit is not None:
            k, dist, surface = hit
            print(
                f"warning: the --c2w pose is behind a surface (inside an object or beyond a "
                f"wall): {dist:.2f} m from source {k}, whose surface there is {surface:.2f} m away",
                file=sys.stderr,
            )


def _check_path_size(path, name: Path) -> None:
    """Refuse, in one line, a path whose frames are too small or too large to render."""
    w, h = path.render_width, path.render_height
    if path.camera_type == "equirectangular" and w != 2 * h:
        raise UserError(
            f"{name}: an equirectangular path needs render_width = 2 x render_height, got {w}x{h}"
        )
    if w > MAX_FRAME[0] or h > MAX_FRAME[1] or min(w, h) < 8:
        raise UserError(
            f"{name}: frames of {w}x{h} are out of range: render_width up to {MAX_FRAME[0]}, "
            f"render_height up to {MAX_FRAME[1]} (as --height of single renders), both at least 8"
        )


def run_path(cfg: RenderConfig, args: argparse.Namespace) -> int:
    """``--camera-path``: every camera of the path to a video or a folder of frames."""
    from panogrf.app.files.video import FrameSink
    from panogrf.app.paths.camera_path import duration_note, read_camera_path
    from panogrf.app.paths.frames import FrameRenderer, erp_height_for, render_camera_path
    from panogrf.app.scene.coverage import inside_warning, path_warning
    from panogrf.app.scene.folder import load_scene
    from panogrf.model.progress import stage

    path = read_camera_path(cfg.camera_path)
    if note := duration_note(path):
        print(note, flush=True)
    _check_path_size(path, cfg.camera_path)
    spherical = path.camera_type == "equirectangular"
    sink = FrameSink(cfg.out, path.fps, path.render_width, path.render_height, spherical)
    scene = load_scene(cfg.scene, load_images=True)
    refuse_scene_inputs(cfg.out, scene, folder=cfg.out.suffix.lower() != ".mp4")
    data = scene.images
    views, models = _source_views(args, scene)
    if warning := path_warning(np.asarray(path.poses, dtype=np.float64), scene.c2w):
        print(warning, flush=True)
    frames = FrameRenderer(views, models, cfg.quality, cfg.method, data.origin)
    start = time.perf_counter()
    try:
        erp_rows = max(
            erp_height_for(path.camera_type, path.render_width, path.render_height, float(fov))
            for fov in path.fov
        )
        frames.check_height(erp_rows, f"{cfg.camera_path}: panoramas of")
        cache = session.prepare_views(
            views, models, cfg.method, cfg.quality, args.cache_dir, not args.no_cache
        )
        frames.prepare()
        prep = time.perf_counter() - start
        if DepthMode.FULL in views.depth:  # the estimated depth says where the surfaces are
            depth = views.depth[DepthMode.FULL][:, 0].double().cpu().numpy()
            inside = inside_warning(np.asarray(path.poses, np.float64), scene.c2w, depth)
            if inside:
                print(inside, flush=True)
        start = time.perf_counter()
        with sink, stage("rendering frames", len(path)) as bar:
            render_camera_path(frames, path, sink, progress=lambda _: bar.advance())
    except OSError as exc:
        raise UserError(f"cannot write {cfg.out}: {exc.strerror or exc}") from None
    finally:
        frames.release()
    seconds = time.perf_counter() - start
    what = "video" if sink.is_video else "frames"
    print(
        f"wrote {cfg.out} ({what}: {sink.count} frames, {path.render_width}x"
        f"{path.render_height}, {path.camera_type}, {cfg.quality}): prepared in {prep:.2f} s "
        f"(scene cache {cache.status}), "
        f"{1000 * seconds / max(sink.count, 1):.0f} ms per frame"
    )
    return 0
