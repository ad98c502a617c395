"""The benchmark behind `panogrf bench`: quality, time, memory and the hard cases of every setting.

1. Quality: the middle view of ``scenes`` test triplets per baseline, rendered from the outer
   two at ``height`` rows by every setting and scored (WS-PSNR, LPIPS, PSNR, SSIM).
2. Time and memory: on the first triplet, every setting renders once more at ``time_height``
   rows (512 x 1024 by default), timed, with its peak memory. A setting whose render at
   ``height`` predicts more than ``time_budget`` seconds at ``time_height`` (times the pixel
   ratio) is not rendered again: its time is that prediction, marked ``time_scaled``.
3. The real triplet(s) under ``real``, if given, scored like 1.
4. The sweep and the hard cases (`panogrf.app.bench.cases`) at ``case_height`` rows, every
   render checked for NaN, inf and emptiness (`image_problems`).
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from panogrf.app.bench.cases import CASES, SWEEP_BASELINES, make_cases
from panogrf.app.bench.settings import (
    VIEWER_DEFAULTS,
    GLContext,
    PeakMemory,
    Setting,
    depth_networks,
    parameters,
    prepare_setting,
    release_scene,
    render_setting,
)
from panogrf.app.errors import UserError
from panogrf.app.options import flag_of, option
from panogrf.app.runtime import metres_list, number
from panogrf.model.refine import RefineConfig
from panogrf.renderer.methods import Models, SourceViews
from panogrf.renderer.render import Quality

METRICS = ("ws_psnr", "lpips", "psnr", "ssim")


def names(text: str) -> tuple[str, ...]:
    """``--cases a, b`` -> ("a", "b") (argparse type): comma-separated names, blanks dropped."""
    return tuple(name.strip() for name in text.split(",") if name.strip())


@dataclass(frozen=True)
class BenchConfig:
    """What `run_bench` measures. A field made with `option` is also an option of `panogrf
    bench` (`panogrf.app.options`); the settings are checked as they are built (`UserError`,
    one line naming the option)."""

    data: Path = option(
        help="a dataset (dataset.json), a folder of triplet scene folders, or one scene folder",
        positional=True,
        metavar="DATASET_OR_SCENES",
    )
    """A dataset, a folder of triplet scene folders, or one scene folder."""
    settings: tuple[Setting, ...]
    """The settings to chart (`panogrf.app.bench.settings.SETTINGS`)."""
    scenes: int = option(1, "triplets per baseline (default {default})")
    """Triplets per baseline for the quality."""
    baselines: tuple[float, ...] | None = option(
        None,
        "baselines (m) to score (default: 1.0,1.5,2.0 for a dataset, all for a folder)",
        parse=metres_list,
    )
    """Baselines (m) of the quality; None: 1.0, 1.5, 2.0 for a dataset, all for a folder."""
    height: int = option(256, "rows of the quality renders")
    """Rows of the quality renders."""
    time_height: int = option(512, "rows of the timed render (default {default})")
    """Rows of the timed render (the chart's x axis)."""
    time_budget: float = option(
        30.0,
        "seconds: a setting predicted slower at --time-height is not rendered there; its "
        "time is predicted from the --height render (marked * in the table)",
        parse=number(float, 0.0, low_open=True),
    )
    """Seconds above which a timed render is predicted from the quality render instead."""
    real: Path | None = None
    """A dataset of real triplets, charted as its own marker (None: none)."""
    case_height: int = option(128, "rows of the sweep and hard cases")
    """Rows of the sweep's and the hard cases' renders."""
    sweep: tuple[float, ...] = option(
        SWEEP_BASELINES,
        f"sweep baselines in m (default {','.join(f'{b:g}' for b in SWEEP_BASELINES)}; "
        "'' for none)",
        parse=metres_list,
    )
    """Baselines (m) of the stability sweep (empty: no sweep)."""
    sweep_scenes: int = option(
        5, "synthetic scenes per sweep baseline: the sweep's mean and spread (default {default})"
    )
    """Scenes per baseline of the sweep: its mean and spread."""
    cases: tuple[str, ...] = option(
        CASES,
        f"hard cases for the gallery (default all: {','.join(CASES)}; '' for none)",
        parse=names,
    )
    """Hard cases for the gallery (empty: none)."""
    refine: RefineConfig | None = None
    """The per-scene depth refinement of every depth-reading setting (the CLI's default)."""
    cache_dir: Path | None = None
    """The scene cache's folder (`panogrf.app.scene.session.prepare_views`; None: default)."""
    use_cache: bool = True
    """Read and write the scene cache for the test triplets' PanoGRF depth and maps."""

    def __post_init__(self) -> None:
        """Refuse heights outside 8 to `MAX_HEIGHT` rows, no scene, a sweep of more than 100
        scenes, no setting and an unknown case."""
        from panogrf.app.scene.session import MAX_HEIGHT

        for name in ("height", "time_height", "case_height"):
            rows = getattr(self, name)
            if not 8 <= rows <= MAX_HEIGHT:
                flag = flag_of(BenchConfig, name)
                raise UserError(f"{flag} must be between 8 and {MAX_HEIGHT}, got {rows}")
        if self.scenes < 1:
            raise UserError(f"--scenes must be at least 1, got {self.scenes}")
        if not 1 <= self.sweep_scenes <= 100:
            raise UserError(f"--sweep-scenes must be between 1 and 100, got {self.sweep_scenes}")
        if not self.settings:
            raise UserError("--settings / --skip leave no setting to run")
        unknown = [c for c in self.cases if c not in CASES]
        if unknown:
            raise UserError(f"--cases: unknown {unknown}; choose from {','.join(CASES)}")


@dataclass
class Rendered:
    """One render of one setting, scored."""

    scores: dict[str, float]
    seconds: float
    image: Tensor | None = None  # [3, H, W], kept for the gallery
    problems: list[str] = field(default_factory=list)


def image_problems(rgb: Tensor, height: int) -> list[str]:
    """What is wrong with a render [3, H, 2H] (empty: nothing): wrong shape, NaN or inf, or
    empty (every pixel the same colour)."""
    out = []
    if tuple(rgb.shape) != (3, height, 2 * height):
        out.append(f"shape {tuple(rgb.shape)}, expected {(3, height, 2 * height)}")
    if rgb.numel() == 0:
        return out + ["no pixels"]
    if not bool(torch.isfinite(rgb).all()):
        out.append("NaN or inf")
    elif float(rgb.amax() - rgb.amin()) == 0.0:
        out.append(f"empty: every pixel {float(rgb.flatten()[0]):.3f}")
    return out


def _score(rgb: Tensor, truth: Tensor) -> dict[str, float]:
    from panogrf.app.scoring import image_scores

    return image_scores(rgb.nan_to_num(0.0), truth)


def _render(setting, views, c2w, height, models, gl) -> tuple[Tensor, float]:
    t0 = time.perf_counter()
    rgb = render_setting(setting, views, c2w, height, models, gl)
    if rgb.is_cuda:  # the GPU's work done, not only queued
        torch.cuda.synchronize(rgb.device)
    return rgb, time.perf_counter() - t0


def _mean(items: list[dict[str, float]]) -> dict[str, float]:
    out = {}
    for m in METRICS:
        vals = [x[m] for x in items if x.get(m) is not None and math.isfinite(x[m])]
        out[m] = statistics.fmean(vals) if vals else math.nan
    return out | {"n": len(items)}


def _sweep(cases, case_out, setting: str) -> dict[str, dict[str, float]]:
    """The sweep of ``setting``: per baseline (metres, as text) the mean of its scenes' scores
    and the spread of WS-PSNR and LPIPS (``_min``, ``_max``, ``_std`` over the scenes)."""
    by_b: dict[str, list[dict[str, float]]] = {}
    for c in cases:
        if c.name.startswith("sweep"):
            by_b.setdefault(f"{c.baseline:g}", []).append(case_out[c.name][setting].scores)
    out = {}
    for b, items in by_b.items():
        out[b] = _mean(items)
        for m in ("ws_psnr", "lpips"):
            vals = [x[m] for x in items if x.get(m) is not None and math.isfinite(x[m])]
            out[b][f"{m}_min"] = min(vals) if vals else math.nan
            out[b][f"{m}_max"] = max(vals) if vals else math.nan
            out[b][f"{m}_std"] = statistics.pstdev(vals) if vals else math.nan
    return out


def _timing(setting, views, c2w, cfg, models, gl, seconds_at_height) -> dict:
    """Seconds and peak memory of one render at ``cfg.time_height``."""
    scale = (cfg.time_height / cfg.height) ** 2
    if seconds_at_height * scale > cfg.time_budget and cfg.time_height != cfg.height:
        with PeakMemory() as mem:
            render_setting(setting, views, c2w, cfg.height, models, gl)
        return {
            "seconds": seconds_at_height * scale,
            "time_scaled": True,
            "peak_mib": mem.mib,
            "peak_at_height": cfg.height,
        }
    if setting.method == "gl":  # the first frame at a size makes its render targets
        render_setting(setting, views, c2w, cfg.time_height, models, gl)
    with PeakMemory() as mem:
        _, sec = _render(setting, views, c2w, cfg.time_height, models, gl)
    return {"seconds": sec, "time_scaled": False, "peak_mib": mem.mib}


def _prepare_cached(setting: Setting, views: SourceViews, models: Models, cfg) -> None:
    """The PanoGRF depth and maps a setting reads, from or into the scene cache (the same as
    `panogrf render` and `view` use; nothing for a setting that does not read them)."""
    from panogrf.app.scene import session

    method, quality = (
        ("panogrf", Quality.PREVIEW)
        if setting.method == "gl"
        else (
            setting.method,
            setting.quality,
        )
    )
    if session.uses_cache(method, quality):
        session.prepare_views(views, models, method, quality, cfg.cache_dir, cfg.use_cache)


def _triplet_views(folder: Path, refine=None, device=None) -> tuple[SourceViews, Tensor, Tensor]:
    from panogrf.app.scene.folder import load_scene

    d = load_scene(folder, load_images=True).images
    views = SourceViews(d.images[[0, 2]], d.c2w[[0, 2]], refine=refine, device=device)
    return views, d.c2w[1], d.images[1:2]


def run_bench(cfg: BenchConfig, models: Models, log: Callable[[str], None] = print) -> dict:
    """Measure every setting of ``cfg``; returns the report `write_outputs` writes."""
    from panogrf.app.scene.datasets import scene_folders, triplets_by_baseline

    triplets, baselines = triplets_by_baseline(
        cfg.data, list(cfg.baselines) if cfg.baselines else None, cfg.scenes
    )
    real = [(None, f) for f in scene_folders(cfg.real)[0]] if cfg.real is not None else []
    gl = GLContext()
    per: dict[str, dict] = {
        s.name: {"baselines": {}, "real": [], "prepare_s": []} for s in cfg.settings
    }
    try:
        for n, (b, folder) in enumerate(triplets + real):
            views, c2w, truth = _triplet_views(folder, cfg.refine, models.device)
            line = [f"[{n + 1}/{len(triplets) + len(real)}] {folder.name} ({b or 'real'} m)"]
            for s in cfg.settings:
                t0 = time.perf_counter()
                _prepare_cached(s, views, models, cfg)
                prepare_setting(s, views, models, gl)
                prep = time.perf_counter() - t0
                rgb, sec = _render(s, views, c2w, cfg.height, models, gl)
                scores = _score(rgb, truth)
                if b is None:
                    per[s.name]["real"].append(scores)
                else:
                    per[s.name]["baselines"].setdefault(str(b), []).append(scores)
                    per[s.name]["prepare_s"].append(prep)
                if n == 0:
                    per[s.name]["timing"] = _timing(s, views, c2w, cfg, models, gl, sec)
                line.append(f"{s.name} {scores['ws_psnr']:.2f}")
            release_scene(views)
            log("  ".join(line))
        cases = (
            make_cases(cfg.case_height, cfg.cases, cfg.sweep, cfg.sweep_scenes)
            if cfg.cases or cfg.sweep
            else []
        )
        case_out: dict[str, dict[str, Rendered]] = {}
        for case in cases:
            views = SourceViews(case.images, case.c2w, refine=cfg.refine, device=models.device)
            case_out[case.name] = {}
            for s in cfg.settings:
                rgb, sec = _render(s, views, case.target_c2w, cfg.case_height, models, gl)
                r = Rendered(
                    _score(rgb, case.target), sec, rgb, image_problems(rgb, cfg.case_height)
                )
                if case.name.startswith("sweep"):
                    r.image = None
                case_out[case.name][s.name] = r
            release_scene(views)
            log(
                f"{case.name}: "
                + "  ".join(
                    f"{k} {v.scores['ws_psnr']:.2f}" for k, v in case_out[case.name].items()
                )
            )
    finally:
        gl.release()
    return _report(cfg, baselines, per, cases, case_out, models)


def _report(cfg, baselines, per, cases, case_out, models) -> dict:
    from panogrf.app.bench.frontier import pareto_front

    results = {}
    for s in cfg.settings:
        p = per[s.name]
        by_b = {k: _mean(v) for k, v in p["baselines"].items()}
        all_items = [x for v in p["baselines"].values() for x in v]
        results[s.name] = {
            "method": s.method,
            "quality": s.quality if s.method != "gl" else f"{s.mesh_rows} mesh rows",
            "params": parameters(s, models),
            **p["timing"],
            "prepare_s_median": statistics.median(p["prepare_s"]) if p["prepare_s"] else math.nan,
            "baselines": by_b,
            "mean": _mean(all_items),
            "real": _mean(p["real"]) if p["real"] else None,
            "sweep": _sweep(cases, case_out, s.name),
            "cases": {
                c.name: case_out[c.name][s.name].scores
                | {"problems": case_out[c.name][s.name].problems}
                for c in cases
                if not c.name.startswith("sweep")
            },
        }
    names = list(results)
    xs = [results[n]["seconds"] for n in names]
    fronts = {
        m: [names[i] for i in pareto_front(xs, [sign * results[n]["mean"][m] for n in names])]
        for m, sign in (("ws_psnr", 1), ("lpips", -1))
    }
    problems = {
        f"{c}/{s}": r.problems
        for c, per_s in case_out.items()
        for s, r in per_s.items()
        if r.problems
    }
    return {
        "what": "every method and setting: the middle view of test triplets from the outer two "
        "(quality), seconds and peak memory per panorama, a baseline sweep and hard cases",
        "config": {
            "data": str(cfg.data),
            "scenes_per_baseline": cfg.scenes,
            "baselines": baselines,
            "height": cfg.height,
            "time_height": cfg.time_height,
            "time_budget_s": cfg.time_budget,
            "real": None if cfg.real is None else str(cfg.real),
            "case_height": cfg.case_height,
            "sweep": list(cfg.sweep),
            "sweep_scenes": cfg.sweep_scenes,
            "cases": list(cfg.cases),
            "refine_depth": None if cfg.refine is None else repr(cfg.refine),
        },
        "results": results,
        "depth_chain": _depth_chain(results, models),
        "frontier": fronts,
        "viewer_defaults": {d: d in fronts["ws_psnr"] for d in VIEWER_DEFAULTS if d in results},
        "problems": problems,
        "machine": f"{torch.get_num_threads()} torch thread(s), CPU; shared with other jobs",
        "_gallery": [(c, case_out[c.name]) for c in cases if not c.name.startswith("sweep")],
    }


def _depth_chain(results: dict, models: Models) -> dict:
    """The shipped depth chain's networks and a scene's preparation for PanoGRF (the first
    PanoGRF setting measured: depth, refinement and feature maps are the same for each)."""
    neural = [n for n, r in results.items() if r["method"] == "panogrf"]
    prep = results[neural[0]]["prepare_s_median"] if neural else None
    return {"networks": depth_networks(models), "prepare_s_median": prep, "setting": neural[:1]}


def _u8(x: Tensor) -> np.ndarray:
    from panogrf.app.files.images import to_uint8

    return to_uint8(x.nan_to_num(0.0))
