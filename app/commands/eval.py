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

The options are declared once, on the fields of `EvalConfig` (`panogrf.app.options`).
"""

from __future__ import annotations

import argparse
import math
import platform
import statistics
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from panogrf.app.errors import UserError
from panogrf.app.options import add_options, from_args, option
from panogrf.app.runtime import (
    RefineOptions,
    ThreadOptions,
    prepare_options,
    refine_setting,
    refuse_scene_inputs,
    resolve_device,
)
from panogrf.renderer.methods import METHODS, Kind
from panogrf.renderer.nadir import nadir_setting
from panogrf.renderer.render import QUALITY, Quality

METRICS = ("psnr", "ws_psnr", "ssim", "lpips")


def parse_methods(text: str) -> list[tuple[str, Quality]]:
    """ "panogrf,panogrf:paper,nearest" -> [(method, quality), ...]."""
    out = []
    for item in (x.strip() for x in text.split(",")):
        if not item:
            continue
        name, _, sampling = item.partition(":")
        sampling = sampling or Quality.FAST
        if name not in METHODS:
            raise UserError(f"--methods: unknown method {name!r}; choose from {sorted(METHODS)}")
        if sampling not in QUALITY:
            raise UserError(f"--methods: unknown sampling {sampling!r} in {item!r}")
        quality = Quality(sampling)
        if quality != Quality.FAST and METHODS[name].kind is not Kind.NEURAL:
            raise UserError(f"--methods: {name} has no sampling choice ({item!r})")
        if (name, quality) in out:
            raise UserError(f"--methods lists {item!r} twice")
        out.append((name, quality))
    if not out:
        raise UserError("--methods lists no method")
    return out


def label(method: str, quality: Quality) -> str:
    if quality == Quality.FAST or METHODS[method].kind is not Kind.NEURAL:
        return method
    return f"{method}:{quality}"


@dataclass(frozen=True)
class EvalConfig:
    """What `panogrf eval` scores and where its report goes. A field made with `option` is also
    an option of the command; the settings are checked as they are built (`UserError`, one
    line naming the option)."""

    dataset: Path = option(
        help="a dataset (dataset.json), a folder of scene folders, or one scene folder; every "
        "scene has three views and the middle one is scored",
        positional=True,
        metavar="DATASET",
    )
    """A dataset, a folder of scene folders, or one scene folder."""
    out: Path = option(help="results JSON")
    """The report (JSON), written after every scene."""
    methods: str = option(
        "panogrf,meshwarp,nearest",
        "comma-separated methods, e.g. panogrf,panogrf:paper,no_mvs,snerf",
    )
    """Comma-separated methods, each optionally with a sampling (`parse_methods`)."""
    height: int | None = option(None, "render height (default: data)")
    """Rows of the renders (None: each scene's own)."""
    baselines: str | None = option(
        None, "baselines (m) to score (default: 1.0,1.5,2.0 for a dataset, all for a folder)"
    )
    """Comma-separated baselines in metres (None: 1.0, 1.5, 2.0 for a dataset, all for a
    folder)."""
    subset: str = option("", "methods run only on the first --subset-size scenes")
    """Comma-separated methods (labels or names) run on the first ``subset_size`` scenes of
    every baseline only."""
    subset_size: int = option(5, "scenes per baseline")
    """Scenes per baseline the ``subset`` methods run on."""
    limit: int | None = option(None, "at most N scenes per baseline")
    """At most this many scenes per baseline (None: all)."""
    refine: object | None = None
    """The per-scene depth refinement (`refine_setting`; None: the networks' depth only)."""

    def __post_init__(self) -> None:
        """Refuse unknown methods, baselines that are no numbers, a height outside 8 to
        `MAX_HEIGHT` rows, a ``limit`` under 1 and a negative ``subset_size``."""
        from panogrf.app.scene.session import MAX_HEIGHT

        self.method_list()
        self.baseline_list()
        if self.height is not None and not 8 <= self.height <= MAX_HEIGHT:
            raise UserError(f"--height must be between 8 and {MAX_HEIGHT}, got {self.height}")
        if self.limit is not None and self.limit < 1:
            raise UserError(f"--limit must be at least 1 scene per baseline, got {self.limit}")
        if self.subset_size < 0:
            raise UserError(f"--subset-size must be 0 or more, got {self.subset_size}")

    def method_list(self) -> list[tuple[str, str]]:
        """The (method, sampling) pairs ``methods`` names (`parse_methods`)."""
        return parse_methods(self.methods)

    def baseline_list(self) -> list[float] | None:
        """The baselines, to 0.1 m (None: the default)."""
        if self.baselines is None:
            return None
        try:
            out = [round(float(x), 1) for x in self.baselines.split(",") if x.strip()]
        except ValueError:
            raise UserError(f"--baselines: expected metres, got {self.baselines!r}") from None
        if not out:
            raise UserError(f"--baselines {self.baselines!r}: no baseline given")
        if not all(0 < b < math.inf for b in out):  # NaN too: no scene is that far apart
            raise UserError(
                f"--baselines {self.baselines}: expected metres, each at least 0.1 (scenes are "
                "matched to 0.1 m)"
            )
        return out

    def subset_names(self) -> set[str]:
        """The methods ``subset`` names (each one of ``methods``, by label or name)."""
        names = {x.strip() for x in self.subset.split(",") if x.strip()}
        known = {label(*m) for m in self.method_list()} | {m for m, _ in self.method_list()}
        if unknown := sorted(names - known):
            raise UserError(f"--subset {','.join(unknown)}: not among --methods {self.methods}")
        return names


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "eval",
        help="score methods on a test split (quality per baseline, ms per panorama)",
        description="\n\n".join(__doc__.split("\n\n")[1:3]),
        epilog=(
            "example: panogrf eval data/test --methods panogrf,meshwarp,nearest --out results.json"
        ),
    )
    add_options(parser, EvalConfig, ThreadOptions, RefineOptions, *prepare_options())
    parser.set_defaults(func=run)


def _any_scored(rows: dict) -> bool:
    return any(scores for per_b in rows.values() for scores in per_b.values())


def run(args: argparse.Namespace) -> int:
    from panogrf.app.files.atomic import check_writable
    from panogrf.app.scene import session
    from panogrf.app.scene.datasets import triplets_by_baseline
    from panogrf.app.scene.folder import load_scene

    cfg = from_args(EvalConfig, args, refine=refine_setting(args))
    methods, subset = cfg.method_list(), cfg.subset_names()
    from_args(ThreadOptions, args).apply()
    check_writable(cfg.out)  # before the work: an hour of rendering must not end unwritable
    nadir_setting(None, args.nadir_cap)  # a bad --nadir-cap is refused before any scene
    index = Path(cfg.dataset) / "dataset.json"
    if Path(cfg.out).resolve() == index.resolve():
        raise UserError(f"--out {cfg.out}: is the dataset's own index; choose another file")
    skipped: list[dict] = []  # broken scenes: reported, the others scored
    scenes, baselines = triplets_by_baseline(cfg.dataset, cfg.baseline_list(), cfg.limit, skipped)
    for broken in skipped if scenes else ():  # with none left, the error says why
        print(f"skipping {broken['why']}", flush=True)
    if not scenes:
        reasons = [broken["why"] for broken in skipped]
        why = reasons[0] if len(reasons) == 1 else f"{len(reasons)} skipped, the first: "
        raise UserError(
            f"{cfg.dataset}: no scene can be scored"
            + (f" ({why}{reasons[0] if len(reasons) > 1 else ''})" if reasons else "")
        )
    for _, folder in scenes:  # the report must not replace a scene's own file
        refuse_scene_inputs(cfg.out, load_scene(folder))
    models = session.default_models(resolve_device(args.device))
    rows = {label(*m): {b: [] for b in baselines} for m in methods}
    seen: dict[float, int] = {b: 0 for b in baselines}
    start_all = time.perf_counter()
    for n, (b, folder) in enumerate(scenes, 1):
        try:
            index = seen[b]
            seen[b] += 1
            line = [f"[{n}/{len(scenes)}] {folder.name} ({b} m)"]
            for name, scores in _score_scene(cfg, args, models, folder, index):
                rows[name][b].append(scores)
                line.append(f"{name} {scores['ws_psnr']:.2f}")
            print("  ".join(line), flush=True)
        except (UserError, OSError) as exc:  # a scene that breaks: reported, the others scored
            why = f"{exc.strerror}" if isinstance(exc, OSError) and exc.strerror else str(exc)
            print(f"[{n}/{len(scenes)}] {folder.name}: skipped ({why})", flush=True)
            skipped.append({"scene": str(folder), "why": why})
            for per_b in rows.values():  # a half-scored scene counts for no method
                per_b[b] = [r for r in per_b[b] if r["scene"] != folder.name]
        if _any_scored(rows):  # an earlier report is replaced only by one with scores
            _write(cfg, _report(cfg, methods, subset, rows, skipped, start_all), final=False)
    if not _any_scored(rows):
        why = skipped[0]["why"] if skipped else "no method gave a score"
        raise UserError(f"{cfg.dataset}: no scene could be scored ({why}); {cfg.out} unchanged")
    report = _report(cfg, methods, subset, rows, skipped, start_all)
    print(format_table(report["results"], baselines))
    _write(cfg, report)
    print(f"wrote {cfg.out}")
    if skipped:
        print(f"{len(skipped)} scene(s) skipped: " + "; ".join(x["scene"] for x in skipped))
        return 1
    return 0


def _score_scene(cfg: EvalConfig, args: argparse.Namespace, models, folder: Path, index: int):
    """Each method's scores on the scene in ``folder`` (the ``index``-th of its baseline), as
    (label, scores) pairs, one as each is scored."""
    from panogrf.app.scene import session
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scoring import image_scores
    from panogrf.renderer.methods import SourceViews, render_view

    scene = load_scene(folder, load_images=True)
    data = scene.images
    height = cfg.height or scene.height
    views = SourceViews(
        data.images[[0, 2]],
        data.c2w[[0, 2]],
        refine=cfg.refine,
        nadir=nadir_setting(scene.metadata, args.nadir_cap),
        device=models.device,
    )
    subset = cfg.subset_names()
    for method, quality in cfg.method_list():
        name = label(method, quality)
        if (name in subset or method in subset) and index >= cfg.subset_size:
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
        timing = {"render_ms": ms, "prepare_s": prep, "prepared": new, "cache": cache.status}
        yield name, scores | timing | {"scene": folder.name}


def _report(cfg: EvalConfig, methods, subset, rows, skipped, start_all) -> dict:
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
        "dataset": str(cfg.dataset),
        "height": cfg.height or "dataset's",
        "refine_depth": cfg.refine is not None,
        "methods": [label(*m) for m in methods],
        "subset": {"methods": sorted(subset), "scenes_per_baseline": cfg.subset_size},
        "results": results,
        "per_scene": {k: {str(b): v for b, v in per_b.items()} for k, per_b in rows.items()},
        "machine": f"{platform.machine()}, {torch.get_num_threads()} torch threads, CPU",
        "seconds": round(time.perf_counter() - start_all, 1),
        "skipped": skipped,
    }
    return report


def _write(cfg: EvalConfig, report: dict, final: bool = True) -> None:
    """``report`` to ``--out``, atomically: after every scene (what was scored survives a
    later failure) and at the end."""
    from panogrf.app.files.atomic import json_text, nan_to_null, write_json_atomic

    report = nan_to_null(report)  # a metric undefined at this size (LPIPS below 31 rows)
    try:
        write_json_atomic(cfg.out, report)
    except OSError as exc:  # e.g. the disk filled up meanwhile: the results go to stdout
        if not final:
            return
        print(json_text(report))
        raise UserError(
            f"cannot write {cfg.out} ({exc.strerror or exc}); the results are printed above"
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
