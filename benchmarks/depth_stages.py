"""Leave-one-out of the depth chain: what each stage buys in the chain as it ships, and its cost.

    python benchmarks/depth_stages.py --data data/loo_classic data/loo_home data/loo_lit \
        REAL_SCENE_DIRS... [--variants shipped,-refine,...] [--threads 2] \
        [--out lab/results/depth_stages.json]

``--data``: dataset folders (with ``dataset.json``) or scene folders of three views. For every
scene and every variant the outer two views are prepared from nothing, as `panogrf render`
prepares a scene (exposure balance, the depth chain, the per-scene refinement, the renderer's
feature maps: timed together, "prep s"); the middle view (the one nearest both others) is
rendered by PanoGRF (``fast``, at the scene's rows, at most ``--rows``) and scored (WS-PSNR,
SSIM, LPIPS); where the scene has true depth, the outer views' depth is scored (L1 in metres,
overall and by band of elevation, pooled).

Variants (``VARIANTS``): ``shipped`` (mode full with every stage); ``-X``: the shipped chain
without stage X (or with its simplest replacement); ``mvs``: the MVS-only member (the unguided
network, its sweep and median, the refinement); ``mvs-bare``: the unguided network alone;
``mono``: the monocular network alone. Prints a table per dataset and pooled, writes JSON.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import subprocess
import time
from contextlib import contextmanager
from pathlib import Path

import torch

#: name -> (depth mode, estimator attributes, SourceViews keywords, what it leaves out)
VARIANTS: dict[str, tuple[str, dict, dict, str]] = {
    "shipped": ("full", {}, {}, "every stage"),
    # "-exposure" (the sources' exposure balance, `SourceViews(balance=False)`) was measured at
    # 0994b38 (`depth_stages_cpu.json`, `depth_stages_gpu.json`): it bought nothing and left.
    "-canonical": (
        "full",
        {"canonical": False},
        {},
        "the unguided pass that fixes the world's scale (and the scale back)",
    ),
    "-fusion": (
        "full",
        {"fuse": False},
        {},
        "the unguided hypothesis in the sweep (and with it the selector and the blend)",
    ),
    "-selector": ("full", {"selector": None}, {}, "the learned selector: the photometric rule"),
    "-median": ("full", {"median": 1}, {}, "the 7x7 median after the sweep"),
    "-blend": ("full", {"blend": None}, {}, "the learned blend with the monocular depth"),
    "-sweep": (
        "full",
        {"sweep": None},
        {},
        "the photometric sweep (and the fusion, the median and the blend it carries)",
    ),
    "-refine": ("full", {}, {"refine": None}, "the per-scene refinement"),
    "mvs": ("mvs", {}, {}, "the monocular network and everything mode full adds"),
    "mvs-refine": ("mvs", {}, {"refine": None}, "MVS-only without the refinement"),
    "mvs-bare": ("mvs", {"sweep": None}, {"refine": None}, "the unguided network alone"),
    "mono": ("mono", {}, {"refine": None}, "the monocular network alone"),
}


def _cheaper_variants() -> dict[str, tuple[str, dict, dict, str]]:
    """Cheaper settings of the shipped stages (not stages left out): fewer sweep candidates
    over the same span (``sweepN``), fewer refinement steps (``refineC+F``: C at half the rows,
    F at the full rows), and the two together (``sweepN,refineC+F`` as one name)."""
    import dataclasses

    from panogrf.model.depth_config import DEFAULT_SWEEP
    from panogrf.model.refine import PREPARE_REFINE

    sweeps = {
        n: {"fusion_sweep": dataclasses.replace(DEFAULT_SWEEP, candidates=n)} for n in (16, 12)
    }
    refines = {
        (c, f): {"refine": dataclasses.replace(PREPARE_REFINE, coarse=c, iterations=f)}
        for c, f in ((30, 10), (20, 10))
    }
    out = {
        "undamped": (
            "full",
            {},
            {"refine": dataclasses.replace(PREPARE_REFINE, damping=0.0)},
            "the refinement's Adam damping (torch's epsilon instead)",
        )
    }
    for n, attrs in sweeps.items():
        out[f"sweep{n}"] = ("full", attrs, {}, f"the sweep with {n} candidates")
    for (c, f), kw in refines.items():
        out[f"refine{c}+{f}"] = ("full", {}, kw, f"the refinement with {c} + {f} steps")
    for n, attrs in sweeps.items():
        for (c, f), kw in refines.items():
            out[f"sweep{n}+refine{c}+{f}"] = ("full", attrs, kw, f"sweep{n} and refine{c}+{f}")
    return out


VARIANTS |= _cheaper_variants()


def scene_folders(paths: list[Path]) -> list[Path]:
    out = []
    for p in paths:
        index = p / "dataset.json"
        if index.exists():
            out += [p / e["folder"] for e in json.loads(index.read_text())["scenes"]]
        else:
            out.append(p)
    return out


@contextmanager
def estimator_as(models, mode: str, estimator):
    """``models`` giving ``estimator`` for ``mode``, as before after."""
    old = models.estimator

    def pick(m):
        return estimator if m == mode else old(m)

    models.estimator = pick
    try:
        yield models
    finally:
        models.estimator = old


def middle_first(data, rows: int):
    """``data`` with its images (and depths) at ``rows`` rows and its views reordered so that
    the one nearest both others (the smallest largest distance) is in the middle."""
    import dataclasses

    from panogrf.renderer.cache import resize_erp

    centres = data.c2w[:, :3, 3]
    far = torch.cdist(centres[None], centres[None])[0].amax(1)
    mid = int(far.argmin())
    order = [v for v in range(3) if v != mid]
    order = [order[0], mid, order[1]]
    images = data.images[order]
    depths = None if data.depths is None else data.depths[order]
    if images.shape[-2] != rows:
        images = resize_erp(images, rows)
        if depths is not None:
            depths = torch.nn.functional.interpolate(depths, size=images.shape[-2:], mode="nearest")
    return dataclasses.replace(data, images=images, c2w=data.c2w[order], depths=depths)


def run_variant(name, data, models, rows: int):
    """(row of scores and seconds, depth band sums) of variant ``name`` on one scene."""
    from panogrf.app.scoring import image_scores
    from panogrf.model.metrics import depth_l1_by_band, depth_metrics
    from panogrf.model.refine import PREPARE_REFINE
    from panogrf.renderer.methods import METHODS, MethodSpec, SourceViews, render_view

    mode, attrs, view_kw, _ = VARIANTS[name]
    kw = {"refine": PREPARE_REFINE} | view_kw
    est = models.estimator(mode)
    spec = MethodSpec("panogrf", mode, "panogrf", METHODS["panogrf"].kind)
    with estimator_as(models, mode, est.configured(**attrs)):
        t0 = time.perf_counter()
        views = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]], device=models.device, **kw)
        views.cache_for(spec, models)
        if models.device.type == "cuda":
            torch.cuda.synchronize(models.device)
        seconds = time.perf_counter() - t0
    if mode != "full":  # render_view reads the method's own depth mode: alias it
        views.depth["full"] = views.depth[mode]
        views.caches[("panogrf", "full")] = views.caches[("panogrf", mode)]
    rgb = render_view("panogrf", views, data.c2w[1], rows, models, "fast")
    scores = image_scores(rgb, data.images[1:2])
    row = {k: scores[k] for k in ("ws_psnr", "ssim", "lpips")} | {"seconds": seconds}
    bands: dict[str, list[float]] = {}
    if data.depths is not None:
        depth = torch.nn.functional.interpolate(
            views.depth[mode].cpu(),
            size=data.images.shape[-2:],
            mode="bilinear",
            align_corners=False,
        )
        d_max = est.d_max
        l1s = []
        for k, v in enumerate((0, 2)):
            gt = data.depths[v, 0]
            mask = (gt > 0) & (gt <= d_max)
            l1s.append(float(depth_metrics(depth[k, 0], gt, mask).l1))
            for key, (total, count) in depth_l1_by_band(depth[k, 0], gt, mask).items():
                acc = bands.setdefault(key, [0.0, 0])
                acc[0] += total
                acc[1] += count
        row["depth_l1"] = statistics.fmean(l1s)
    return row, bands


def summarise(rows: list[dict]) -> dict:
    out = {"n": len(rows)}
    for k in ("ws_psnr", "ssim", "lpips", "depth_l1"):
        vals = [r[k] for r in rows if k in r]
        if vals:
            out[k] = statistics.fmean(vals)
    out["seconds_median"] = statistics.median(r["seconds"] for r in rows)
    return out


def write_report(args, names, results, bands, models, start) -> tuple[dict, list[str]]:
    """The report so far (tables pooled per set and overall), written to ``args.out``."""
    from panogrf.app.files.atomic import write_json_atomic

    groups = sorted({g for per in results.values() for g in per})
    table = {
        name: {g: summarise(per[g]) for g in groups if g in per}
        | {"pooled": summarise([r for rs in per.values() for r in rs])}
        for name, per in results.items()
    }
    band_l1 = {
        name: {k: total / count for k, (total, count) in b.items() if count}
        for name, b in bands.items()
    }
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True
        )
        commit = commit.stdout.strip()
    except OSError:  # no git where it runs
        commit = "unknown"
    report = {
        "what": "leave-one-out of the depth chain: middle view from the outer two, fast",
        "data": [str(p) for p in args.data],
        "variants": {n: VARIANTS[n][3] for n in names},
        "table": table,
        "depth_l1_by_band_synthetic": band_l1,
        "rows": results,
        "machine": f"{platform.machine()}, {torch.get_num_threads()} torch threads, "
        + (torch.cuda.get_device_name() if models.device.type == "cuda" else "CPU"),
        "seconds": round(time.perf_counter() - start, 1),
        "commit": commit,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out, report)
    return report, groups


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--threads", type=int, default=0)
    parser.add_argument("--rows", type=int, default=512, help="larger scenes are resized to it")
    parser.add_argument("--device", default="cpu", help="cpu, cuda or auto (default cpu)")
    parser.add_argument("--out", type=Path, default=Path("lab/results/depth_stages.json"))
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    names = [n.strip() for n in args.variants.split(",") if n.strip()]
    unknown = [n for n in names if n not in VARIANTS]
    if unknown:
        raise SystemExit(f"unknown variants {unknown}: have {list(VARIANTS)}")

    from panogrf.app.runtime import resolve_device
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scene.session import default_models

    models = default_models(resolve_device(args.device))
    for mode in {VARIANTS[n][0] for n in names}:  # loaded before anything is timed
        models.estimator(mode)
    models.renderer("panogrf")
    results: dict[str, dict[str, list[dict]]] = {n: {} for n in names}
    bands: dict[str, dict[str, list[float]]] = {n: {} for n in names}
    start = time.perf_counter()
    folders = scene_folders(args.data)
    sets = {}
    for folder in folders:
        group = folder.parent.name if (folder.parent / "dataset.json").exists() else "real"
        sets[str(folder)] = group
        data = load_scene(folder, load_images=True).images
        rows = min(args.rows, data.images.shape[-2])
        data = middle_first(data, rows)
        for name in names:
            row, b = run_variant(name, data, models, rows)
            row["scene"] = str(folder)
            results[name].setdefault(group, []).append(row)
            if group != "real":
                for key, (total, count) in b.items():
                    acc = bands[name].setdefault(key, [0.0, 0])
                    acc[0] += total
                    acc[1] += count
            depth = f" depth {row['depth_l1']:.3f} m" if "depth_l1" in row else ""
            print(
                f"{group}/{folder.name} {name:>11}: {row['ws_psnr']:.2f} dB "
                f"LPIPS {row['lpips']:.3f}{depth} ({row['seconds']:.1f} s)",
                flush=True,
            )
        write_report(args, names, results, bands, models, start)  # kept if the run stops

    report, groups = write_report(args, names, results, bands, models, start)
    table, band_l1 = report["table"], report["depth_l1_by_band_synthetic"]
    print(f"\n{len(folders)} scenes; {report['machine']}; wrote {args.out}")
    print("\ndepth L1 (m) by band of elevation, synthetic sets pooled:")
    keys = sorted({k for b in band_l1.values() for k in b}, key=lambda k: -int(k.split("_")[1]))
    print(f"{'variant':>11} | " + " | ".join(f"{k[3:]:>8}" for k in keys))
    for name, b in band_l1.items():
        print(f"{name:>11} | " + " | ".join(f"{b.get(k, float('nan')):8.3f}" for k in keys))
    print("\nWS-PSNR / SSIM / LPIPS / depth L1 m, and the median preparation seconds:")
    print(f"{'variant':>11} | " + " | ".join(f"{g:>30}" for g in [*groups, "pooled"]) + " | prep s")
    for name, per in table.items():
        cells = []
        for g in [*groups, "pooled"]:
            t = per.get(g)
            if t is None:
                cells.append(f"{'-':>30}")
                continue
            d = f"{t['depth_l1']:.3f}" if "depth_l1" in t else "  -  "
            cells.append(f"{t['ws_psnr']:6.2f} / {t['ssim']:.3f} / {t['lpips']:.3f} / {d}")
        print(f"{name:>11} | " + " | ".join(cells) + f" | {per['pooled']['seconds_median']:6.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
