"""`panogrf demo`: a headless tour of the bundled scene (validation, geometry check, pictures).

The options are declared once, on the fields of `DemoConfig` (`panogrf.app.options`).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from panogrf.app.errors import UserError
from panogrf.app.options import add_options, from_args, option
from panogrf.app.runtime import prepare_options


@dataclass(frozen=True)
class DemoConfig:
    """Which scene `panogrf demo` tours and where its pictures go. A field made with `option`
    is also an option of the command."""

    scene: Path | None = option(None, "scene folder (default: the bundled demo)")
    """The scene folder (None: the bundled demo)."""
    out: Path = option(Path("demo_out"), "output folder (default demo_out/)")
    """The folder the pictures are written to."""


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "demo",
        help="headless demo on the bundled scene",
        description=(
            "Validate the bundled demo scene (three panoramas with depth), warp its outer views "
            "into the middle one to show that poses and depth agree, estimate depth with the "
            "shipped networks (monocular and mono-guided multi-view stereo) against the ground "
            "truth, and write a picture of the panoramas, true and estimated depth."
        ),
    )
    add_options(parser, DemoConfig, *prepare_options())
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from panogrf.app.files.images import to_uint8, write_rgb
    from panogrf.app.runtime import refuse_scene_inputs, resolve_device
    from panogrf.app.scene.consistency import reprojection_check
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.visualize import colorize_depth, stack_rows
    from panogrf.assets import path as asset_path
    from panogrf.model.depth_config import DepthMode

    cfg = from_args(DemoConfig, args)
    device = resolve_device(args.device)
    root = cfg.scene or asset_path("demo")
    scene = load_scene(root, load_images=True)
    data = scene.images
    print(f"scene: {root} ({scene.num_views} views, {scene.width}x{scene.height})")
    if data.depths is None:
        raise UserError(f"{root}: the demo needs a scene with depth maps")
    if scene.num_views < 2:
        raise UserError(f"{root}: the demo renders a view from the others: it needs two or more")
    if cfg.out.exists() and not cfg.out.is_dir():  # before the work, not after it
        raise UserError(f"--out {cfg.out}: is a file; the demo writes a folder")
    refuse_scene_inputs(cfg.out, scene, folder=True)
    from panogrf.renderer.nadir import nadir_setting

    nadir = nadir_setting(scene.metadata, args.nadir_cap)  # a bad value refused before any work
    _check_out(cfg.out)  # last: it makes the folder
    target = scene.num_views // 2
    for source in (i for i in range(scene.num_views) if i != target):
        r = reprojection_check(data.images, data.c2w, data.depths, source, target)
        print(
            f"  {scene.frames[source].name} -> {scene.frames[target].name} "
            f"({r.baseline_m:.2f} m): depth warp {r.psnr_depth_warp:.2f} dB vs rotation only "
            f"{r.psnr_rotation_only:.2f} dB on {r.covered:.0%} of the pixels"
        )
    estimates = _estimate_depth(data, args.cache_dir, not args.no_cache, device)
    rows = []
    max_depth = float(data.depths.max())
    for i in range(scene.num_views):
        rgb = to_uint8(data.images[i])
        rows += [rgb, colorize_depth(data.depths[i, 0].numpy(), max_depth)]
        rows.append(colorize_depth(estimates[DepthMode.FULL][i, 0].cpu().numpy(), max_depth))
    try:
        cfg.out.mkdir(parents=True, exist_ok=True)
        sheet = cfg.out / "demo_views.png"
        write_rgb(sheet, stack_rows(rows))
    except OSError as exc:
        raise UserError(f"cannot write to {cfg.out}: {exc.strerror or exc}") from None
    print(f"wrote {sheet} (each panorama above its true depth, then the estimated depth)")
    _novel_view(data, cfg.out, args.cache_dir, not args.no_cache, nadir, device)
    return 0


#: What the demo writes into its folder.
OUTPUTS = ("demo_views.png", "novel_view.png", "walk_preview.mp4")


def _check_out(out: Path) -> None:
    """Refuse, before the work, an ``out`` holding files the demo did not write (a folder of
    photos: `refuse_foreign_folder`) or that cannot be made or written (its folder made)."""
    from panogrf.app.files.atomic import check_writable, refuse_foreign_folder

    refuse_foreign_folder(out, "demo", _earlier_output)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"--out {out}: cannot make this folder ({exc.strerror or exc})") from None
    check_writable(out / OUTPUTS[0])


def _earlier_output(out: Path) -> bool:
    """Whether ``out`` holds only what the demo writes."""
    return all(p.name in OUTPUTS for p in out.iterdir() if not p.name.startswith("."))


def _novel_view(
    data,
    out: Path,
    cache_dir: Path | None = None,
    use_cache: bool = True,
    nadir="auto",
    device="cpu",
) -> None:
    """The middle view rendered from the outer two by PanoGRF and the baselines, scored
    against the real middle panorama; then a short preview video along the three views
    (`_walk_preview`)."""
    import time

    from panogrf.app.files.images import to_uint8, write_rgb
    from panogrf.app.scene import session
    from panogrf.app.scoring import image_scores
    from panogrf.app.visualize import stack_rows
    from panogrf.model import refine
    from panogrf.renderer.methods import SourceViews, render_view
    from panogrf.renderer.render import Quality

    models = session.default_models(device)
    v = data.images.shape[0]
    target = v // 2
    sources = [i for i in range(v) if i != target]
    # As `panogrf render` and `view` by default: the sources' depth refined for the scene.
    views = SourceViews(
        data.images[sources],
        data.c2w[sources],
        refine=refine.PREPARE_REFINE,
        nadir=nadir,
        device=models.device,
    )
    height = data.images.shape[-2]
    print(f"novel view: frame {target} rendered from frames {sources} ({2 * height}x{height}):")
    cache = session.prepare_views(views, models, "panogrf", Quality.FAST, cache_dir, use_cache)
    print(
        f"  depth of the sources, estimated and refined for the scene, and feature maps: "
        f"{cache.seconds:.2f} s (scene cache {cache.status})"
    )
    rows = [to_uint8(data.images[target])]
    for method in ("panogrf", "meshwarp", "nearest"):
        session.prepare_views(views, models, method, Quality.FAST, cache_dir, use_cache)
        start = time.perf_counter()
        rgb = render_view(method, views, data.c2w[target], height, models, Quality.FAST)
        ms = 1000 * (time.perf_counter() - start)
        s = image_scores(rgb, data.images[target : target + 1])
        print(
            f"  {method:>8}: WS-PSNR {s['ws_psnr']:.2f} dB, SSIM {s['ssim']:.3f}, "
            f"LPIPS {s['lpips']:.3f} ({ms:.0f} ms)"
        )
        rows.append(to_uint8(rgb))
    sheet = out / "novel_view.png"
    write_rgb(sheet, stack_rows(rows))
    print(f"wrote {sheet} (real middle view, then PanoGRF, meshwarp, nearest)")
    _walk_preview(data, out, models, cache_dir, use_cache, nadir)


def _walk_preview(data, out: Path, models, cache_dir: Path | None, use_cache: bool, nadir) -> None:
    """A short video of the GL preview along the scene's views, to ``out/walk_preview.mp4``."""
    from panogrf.app.files.video import FrameSink
    from panogrf.app.paths.frames import FrameRenderer
    from panogrf.app.paths.trajectory import interpolate_keyframes
    from panogrf.app.scene import session
    from panogrf.renderer.methods import SourceViews
    from panogrf.renderer.render import Quality

    height = data.images.shape[-2]
    poses = interpolate_keyframes(data.c2w.numpy().astype(np.float64), 48)
    walk = SourceViews(data.images, data.c2w, nadir=nadir, device=models.device)
    session.prepare_views(walk, models, "panogrf", Quality.PREVIEW, cache_dir, use_cache)
    frames = FrameRenderer(walk, models, Quality.PREVIEW)
    video = out / "walk_preview.mp4"
    try:
        with FrameSink(video, 24, 2 * height, height, spherical=True) as sink:
            for pose in poses:
                sink.write(frames.frame(pose, "equirectangular", 2 * height, height, 75.0))
    finally:
        frames.release()
    print(f"wrote {video} ({sink.count} frames of the GL preview walking through the views)")


def _estimate_depth(
    data, cache_dir: Path | None = None, use_cache: bool = True, device="cpu"
) -> dict:
    """Depth of every view by mode, with its error against the ground truth printed."""
    import time

    from panogrf.app.scene.cache import estimate_cached
    from panogrf.app.weights.networks import NETWORKS, load_depth_estimator
    from panogrf.model.depth_config import DepthMode
    from panogrf.model.metrics import depth_metrics

    estimator = load_depth_estimator(NETWORKS[DepthMode.FULL], str(device))
    images, c2w = data.images.to(device), data.c2w.to(device)
    print("depth estimation (each view uses the others as sources), error vs ground truth:")
    out = {}
    for mode in (DepthMode.MONO, DepthMode.FULL):
        start = time.perf_counter()
        if use_cache:  # shared with `panogrf depth` (the same estimate of the same views)
            est, cache = estimate_cached(estimator, images, c2w, mode, cache_dir)
            how = "" if cache.status == "built" else f", {cache.status}"
        else:
            est, how = estimator(images, c2w, mode), ""
        depth = est.depth.cpu()
        seconds = time.perf_counter() - start
        errors = []
        for i in range(depth.shape[0]):
            gt = data.depths[i, 0]
            valid = (gt > 0) & (gt <= estimator.d_max)
            errors.append(depth_metrics(depth[i, 0], gt, valid))
        l1 = sum(e.l1 for e in errors) / len(errors)
        rmse = sum(e.rmse for e in errors) / len(errors)
        print(f"  {mode:>4}: L1 {l1:.3f} m, RMSE {rmse:.3f} m ({seconds:.2f} s for all views{how})")
        out[mode] = depth
    return out
