"""`panogrf eval DATASET`: novel-view quality and speed of every method on a test split.

DATASET is a dataset made by ``panogrf dataset make`` (its ``dataset.json`` lists the scenes),
any folder holding scene folders (each with a ``transforms.json`` and three views), or a single
scene folder.

For every scene (three panoramas on a line) the middle view is rendered from the first and the
last (the paper's protocol) by each method and scored against the real middle view: PSNR,
WS-PSNR, SSIM and LPIPS, averaged per baseline (first-to-last distance). Timing per method:
the pose-independent preparation once per scene (depth estimation, feature caches, per-scene
fits; read from the scene cache where an earlier run prepared the same sources, --no-cache
to time it afresh) and the render itself, in milliseconds per panorama (median over scenes).

A method is a name from `panogrf.renderer.methods.METHODS`, optionally with a sampling for the
neural ones: ``panogrf:paper`` (64 + 64 samples) or ``panogrf:fast`` (depth-guided, the
default). Slow methods can run on the first N scenes of every baseline only (``--subset``).
"""

from __future__ import annotations

import argparse
import math
import platform
import statistics
import time
from pathlib import Path

import torch

from panogrf.app.errors import UserError
from panogrf.app.runtime import (
    add_prepare_options,
    add_refine_depth,
    refine_setting,
    refuse_scene_inputs,
    resolve_device,
    thread_count,
)
from panogrf.renderer.methods import METHODS, Kind
from panogrf.renderer.nadir import nadir_setting
from panogrf.renderer.render import QUALITY

METRICS = ("psnr", "ws_psnr", "ssim", "lpips")


def parse_methods(text: str) -> list[tuple[str, str]]:
    """ "panogrf,panogrf:paper,nearest" -> [(method, quality), ...]."""
    out = []
    for item in (x.strip() for x in text.split(",")):
        if not item:
            continue
        name, _, quality = item.partition(":")
        quality = quality or "fast"
        if name not in METHODS:
            raise UserError(f"--methods: unknown method {name!r}; choose from {sorted(METHODS)}")
        if quality not in QUALITY:
            raise UserError(f"--methods: unknown sampling {quality!r} in {item!r}")
        if quality != "fast" and METHODS[name].kind is not Kind.NEURAL:
            raise UserError(f"--methods: {name} has no sampling choice ({item!r})")
        out.append((name, quality))
    if not out:
        raise UserError("--methods lists no method")
    return out


def label(method: str, quality: str) -> str:
    if quality == "fast" or METHODS[method].kind is not Kind.NEURAL:
        return method
    return f"{method}:{quality}"


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "eval",
        help="score methods on a test split (quality per baseline, ms per panorama)",
        description="\n\n".join(__doc__.split("\n\n")[1:3]),
        epilog=(
            "example: panogrf eval data/test --methods panogrf,meshwarp,nearest --out results.json"
        ),
    )
    parser.add_argument(
        "dataset",
        type=Path,
        metavar="DATASET",
        help="a dataset (dataset.json), a folder of scene folders, or one scene folder; every "
        "scene has three views and the middle one is scored",
    )
    parser.add_argument(
        "--methods",
        default="panogrf,meshwarp,nearest",
        help="comma-separated methods, e.g. panogrf,panogrf:paper,no_mvs,snerf",
    )
    parser.add_argument("--out", type=Path, required=True, help="results JSON")
    parser.add_argument("--height", type=int, default=None, help="render height (default: data)")
    parser.add_argument(
        "--baselines",
        default=None,
        help="baselines (m) to score (default: 1.0,1.5,2.0 for a dataset, all for a folder)",
    )
    parser.add_argument(
        "--subset", default="", help="methods run only on the first --subset-size scenes"
    )
    parser.add_argument("--subset-size", type=int, default=5, help="scenes per baseline")
    parser.add_argument("--limit", type=int, default=None, help="at most N scenes per baseline")
    parser.add_argument(
        "--threads", type=thread_count, default=0, help="torch threads (default: all)"
    )
    add_refine_depth(parser)
    add_prepare_options(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from panogrf.app.files.atomic import check_output
    from panogrf.app.scene import session
    from panogrf.app.scene.datasets import triplets_by_baseline
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scene.session import MAX_HEIGHT
    from panogrf.app.scoring import image_scores
    from panogrf.renderer.methods import SourceViews, render_view

    methods = parse_methods(args.methods)
    subset = {x.strip() for x in args.subset.split(",") if x.strip()}
    try:
        baselines = (
            None
            if args.baselines is None
            else [round(float(x), 1) for x in args.baselines.split(",") if x.strip()]
        )
    except ValueError:
        raise UserError(f"--baselines: expected metres, got {args.baselines!r}") from None
    if args.height is not None and not 8 <= args.height <= MAX_HEIGHT:
        raise UserError(f"--height must be between 8 and {MAX_HEIGHT}, got {args.height}")
    if args.limit is not None and args.limit < 1:
        raise UserError(f"--limit must be at least 1 scene per baseline, got {args.limit}")
    if args.subset_size < 0:
        raise UserError(f"--subset-size must be 0 or more, got {args.subset_size}")
    if args.threads:
        torch.set_num_threads(args.threads)
    check_output(args.out)  # before the work: an hour of rendering must not end unwritable
    skipped: list[dict] = []  # broken scenes: reported, the others scored
    scenes, baselines = triplets_by_baseline(args.dataset, baselines, args.limit, skipped)
    for broken in skipped:
        print(f"skipping {broken['why']}", flush=True)
    if not scenes:
        raise UserError(f"{args.dataset}: no scene can be scored")
    for _, folder in scenes:  # the report must not replace a scene's own file
        refuse_scene_inputs(args.out, load_scene(folder))
    models = session.default_models(resolve_device(args.device))
    rows = {label(*m): {b: [] for b in baselines} for m in methods}
    seen: dict[float, int] = {b: 0 for b in baselines}
    start_all = time.perf_counter()
    for n, (b, folder) in enumerate(scenes, 1):
        try:
            scene = load_scene(folder, load_images=True)
            data = scene.images
            height = args.height or scene.height
            views = SourceViews(
                data.images[[0, 2]],
                data.c2w[[0, 2]],
                refine=refine_setting(args),
                nadir=nadir_setting(scene.metadata, args.nadir_cap),
                device=models.device,
            )
            index = seen[b]
            seen[b] += 1
            line = [f"[{n}/{len(scenes)}] {folder.name} ({b} m)"]
            for method, quality in methods:
                name = label(method, quality)
                if (name in subset or method in subset) and index >= args.subset_size:
                    continue
                before = dict(views.seconds)
                t0 = time.perf_counter()
                cache = session.prepare_views(
                    views, models, method, quality, args.cache_dir, not args.no_cache
                )
                prep = time.perf_counter() - t0
                t0 = time.perf_counter()
                rgb = render_view(method, views, data.c2w[1], height, models, quality)
                ms = 1000 * (time.perf_counter() - t0)
                scores = image_scores(rgb, data.images[1:2])
                new = {k: v for k, v in views.seconds.items() if k not in before}
                rows[name][b].append(
                    scores
                    | {
                        "render_ms": ms,
                        "prepare_s": prep,
                        "prepared": new,
                        "cache": cache.status,
                        "scene": folder.name,
                    }
                )
                line.append(f"{name} {scores['ws_psnr']:.2f}")
            print("  ".join(line), flush=True)
        except (UserError, OSError) as exc:  # a scene that breaks: reported, the others scored
            why = f"{exc.strerror}" if isinstance(exc, OSError) and exc.strerror else str(exc)
            print(f"[{n}/{len(scenes)}] {folder.name}: skipped ({why})", flush=True)
            skipped.append({"scene": str(folder), "why": why})
            for per_b in rows.values():  # a half-scored scene counts for no method
                per_b[b] = [r for r in per_b[b] if r["scene"] != folder.name]
        _write(args, _report(args, methods, subset, rows, skipped, start_all), final=False)
    report = _report(args, methods, subset, rows, skipped, start_all)
    print(format_table(report["results"], baselines))
    _write(args, report)
    print(f"wrote {args.out}")
    if skipped:
        print(f"{len(skipped)} scene(s) skipped: " + "; ".join(x["scene"] for x in skipped))
        return 1
    return 0


def _report(args, methods, subset, rows, skipped, start_all) -> dict:
    """The report of the scenes scored so far."""
    results = {}
    for name, per_b in rows.items():
        results[name] = {}
        for b, items in per_b.items():
            if not items:
                continue
            results[name][str(b)] = _means(items)
            results[name][str(b)]["scenes"] = len(items)
            results[name][str(b)]["render_ms_median"] = statistics.median(
                x["render_ms"] for x in items
            )
            results[name][str(b)]["prepare_s_median"] = statistics.median(
                x["prepare_s"] for x in items
            )
    report = {
        "what": "middle view of each test triplet rendered from the first and last views",
        "dataset": str(args.dataset),
        "height": args.height or "dataset's",
        "refine_depth": bool(args.refine_depth),
        "methods": [label(*m) for m in methods],
        "subset": {"methods": sorted(subset), "scenes_per_baseline": args.subset_size},
        "results": results,
        "per_scene": {k: {str(b): v for b, v in per_b.items()} for k, per_b in rows.items()},
        "machine": f"{platform.machine()}, {torch.get_num_threads()} torch threads, CPU",
        "seconds": round(time.perf_counter() - start_all, 1),
        "skipped": skipped,
    }
    return report


def _write(args, report: dict, final: bool = True) -> None:
    """``report`` to ``--out``, atomically: after every scene (what was scored survives a
    later failure) and at the end."""
    from panogrf.app.files.atomic import json_text, nan_to_null, write_json_atomic

    report = nan_to_null(report)  # a metric undefined at this size (LPIPS below 31 rows)
    try:
        write_json_atomic(args.out, report)
    except OSError as exc:  # e.g. the disk filled up meanwhile: the results go to stdout
        if not final:
            return
        print(json_text(report))
        raise UserError(
            f"cannot write {args.out} ({exc.strerror or exc}); the results are printed above"
        ) from None


def _means(items: list[dict]) -> dict:
    """Each metric's mean over the scenes where it is defined (SSIM and LPIPS are not below
    their minimum sizes); ``undefined``: how many scenes each mean left out, where any."""
    out, left_out = {}, {}
    for m in METRICS:
        values = [x[m] for x in items if x[m] is not None and math.isfinite(x[m])]
        out[m] = statistics.fmean(values) if values else math.nan
        if len(values) < len(items):
            left_out[m] = len(items) - len(values)
    if left_out:
        out["undefined"] = left_out
    return out


def format_table(results: dict, baselines: list[float]) -> str:
    """The results as a text table: a row per baseline and method."""
    head = (
        f"{'baseline':>8}  {'method':<16} {'n':>3} {'PSNR':>7} {'WS-PSNR':>8} {'SSIM':>7} "
        f"{'LPIPS':>7} {'ms/pano':>9}"
    )
    lines = [head, "-" * len(head)]
    for b in baselines:
        for name, per_b in results.items():
            r = per_b.get(str(b))
            if r is None:
                continue
            lines.append(
                f"{b:8.1f}  {name:<16} {r['scenes']:3d} {r['psnr']:7.2f} {r['ws_psnr']:8.2f} "
                f"{r['ssim']:7.4f} {r['lpips']:7.4f} {r['render_ms_median']:9.0f}"
            )
            for m, n in r.get("undefined", {}).items():
                lines.append(f"{'':8}  {name:<16} {m}: {n} scene(s) too small to score, left out")
    return "\n".join(lines)
