"""Settings of the per-scene depth refinement: quality against cost, on validation scenes.

    python benchmarks/refine_depth.py --data data/val_refine_classic data/val_refine_home \
        --settings "none|shipped|coarse=30,iterations=30" [--threads 2] \
        [--out lab/results/refine_depth.json]

For every scene folder of the datasets (three views): mode full's depth of the outer two views
is estimated once; then, per setting, it is refined (`panogrf.model.refine.refine_depth`, each
view against the other, timed), scored against the true depth (L1 in metres, at the images'
resolution) and the middle view is rendered from the outer two by PanoGRF (``fast`` sampling,
512 rows) and scored. A setting is ``none`` (no refinement), ``shipped`` (`PREPARE_REFINE`) or
``field=value,...`` replacing fields of `PREPARE_REFINE`. Prints mean WS-PSNR, SSIM, LPIPS, depth
L1, the median refinement seconds per scene and its ratio to ``shipped`` in the same run, and
writes JSON. ``--mono-shift``: the depth is estimated with the monocular network out of its
domain (every view blended with the next scene's, `mono_out_of_domain`, seeded per scene), as
on a real capture unlike our rooms. Settings are chosen on validation scenes generated from the
train split's generator with seeds no training used, never on the test split or the real
triplet.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import statistics
import subprocess
import time
from pathlib import Path

import torch

KEYS = ("ws_psnr", "ssim", "lpips", "depth_l1")


def scenes(root: Path) -> list[Path]:
    index = json.loads((root / "dataset.json").read_text())
    return [root / entry["folder"] for entry in index["scenes"]]


def parse_setting(text: str):
    """``none`` -> None, ``shipped`` -> `PREPARE_REFINE`, ``a=1,b=2`` -> it with those fields."""
    from panogrf.model.refine import PREPARE_REFINE

    text = text.strip()
    if text == "none":
        return None
    if text == "shipped":
        return PREPARE_REFINE
    fields = {f.name: f for f in dataclasses.fields(PREPARE_REFINE)}
    changes = {}
    for item in text.split(","):
        name, _, value = item.partition("=")
        name = name.strip()
        if name not in fields:
            raise SystemExit(f"unknown RefineConfig field {name!r} (have {sorted(fields)})")
        kind = type(getattr(PREPARE_REFINE, name))
        changes[name] = kind(value)
    return dataclasses.replace(PREPARE_REFINE, **changes)


def depth_l1(depth: torch.Tensor, data, d_max: float) -> float:
    """Mean L1 (m) of the outer views' depth [2, 1, h, w] against their truth."""
    from panogrf.model.metrics import depth_metrics

    up = torch.nn.functional.interpolate(
        depth, size=data.images.shape[-2:], mode="bilinear", align_corners=False
    )
    values = []
    for k, v in enumerate((0, 2)):
        gt = data.depths[v, 0]
        values.append(float(depth_metrics(up[k, 0], gt, (gt > 0) & (gt <= d_max)).l1))
    return statistics.fmean(values)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--settings", default="none|shipped", help="'|'-separated settings")
    parser.add_argument("--height", type=int, default=512, help="render rows")
    parser.add_argument("--threads", type=int, default=0)
    parser.add_argument(
        "--mono-shift",
        action="store_true",
        help="estimate the depth with the monocular network out of its domain",
    )
    parser.add_argument(
        "--metric-world",
        action="store_true",
        help="the MVS networks and the sweep in the metric world, not the canonical one "
        "(`DepthConfig.canonical` off)",
    )
    parser.add_argument("--out", type=Path, default=Path("lab/results/refine_depth.json"))
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)

    from panogrf.app.files.atomic import write_json_atomic
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scene.session import default_models
    from panogrf.app.scoring import image_scores
    from panogrf.app.train.augment import mono_out_of_domain
    from panogrf.model.depth import DepthMode
    from panogrf.renderer.cache import resize_erp
    from panogrf.renderer.methods import SourceViews, prepare, render_view

    names = [s.strip() for s in args.settings.split("|") if s.strip()]
    settings = {name: parse_setting(name) for name in names}
    models = default_models()
    if args.metric_world:
        metric = models.estimator("full").configured(canonical=False)
        models = dataclasses.replace(
            models,
            estimator=lambda mode, full=models.estimator: metric if mode == "full" else full(mode),
        )
    d_max = models.estimator("full").d_max
    rows: dict[str, list[dict]] = {name: [] for name in names}
    start = time.perf_counter()
    folders = [f for root in args.data for f in scenes(root)]
    for i, folder in enumerate(folders):
        data = load_scene(folder, load_images=True).images
        plain = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]])
        if args.mono_shift:  # the estimate made here with the stage, as `depth_for` makes it
            partner = load_scene(folders[(i + 1) % len(folders)], load_images=True).images
            gen = torch.Generator().manual_seed(i)
            est = models.estimator("full")
            stage = mono_out_of_domain(partner.images[[0, 2]], gen)
            small = resize_erp(plain.images, est.working_height)
            with torch.no_grad():
                out = est(small, plain.c2w, "full", detail=plain.images, mono_stages=[stage])
            plain.depth[DepthMode.FULL] = out.depth
        plain.depth_for("full", models)
        for name, config in settings.items():
            # The library's own path (`SourceViews.refined`, as `panogrf view` takes it).
            t0 = time.perf_counter()
            views = plain if config is None else plain.refined(config, models)
            seconds = time.perf_counter() - t0
            depth = views.depth["full"]
            prepare("panogrf", views, models)
            rgb = render_view("panogrf", views, data.c2w[1], args.height, models, "fast")
            scores = image_scores(rgb, data.images[1:2])
            row = {k: scores[k] for k in KEYS[:3]}
            row |= {"depth_l1": depth_l1(depth, data, d_max), "seconds": seconds}
            row["data"] = str(folder.parent)
            rows[name].append(row)
            print(
                f"{folder.parent.name}/{folder.name} {name:>28}: WS-PSNR {row['ws_psnr']:.2f} "
                f"LPIPS {row['lpips']:.3f} depth {row['depth_l1']:.3f} m ({seconds:.2f} s)",
                flush=True,
            )

    table = {
        name: {k: statistics.fmean(r[k] for r in rs) for k in KEYS}
        | {"seconds_median": statistics.median(r["seconds"] for r in rs), "n": len(rs)}
        for name, rs in rows.items()
    }
    by_data = {
        name: {
            str(root): {
                k: statistics.fmean(r[k] for r in rs if r["data"] == str(root)) for k in KEYS
            }
            for root in args.data
        }
        for name, rs in rows.items()
    }
    shipped = table.get("shipped", {}).get("seconds_median")
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    report = {
        "what": "per-scene depth refinement settings; middle view from the outer two, fast",
        "data": [str(p) for p in args.data],
        "height": args.height,
        "mono_shift": args.mono_shift,
        "canonical": models.estimator("full").canonical,
        "settings": {name: repr(config) for name, config in settings.items()},
        "table": table,
        "by_data": by_data,
        "machine": f"{platform.machine()}, {torch.get_num_threads()} torch threads, CPU",
        "seconds": round(time.perf_counter() - start, 1),
        "commit": commit.stdout.strip(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out, report)
    print(f"\n{len(folders)} scenes, {args.height} rows, {report['machine']}; wrote {args.out}")
    print(
        f"{'setting':>28} | WS-PSNR |  SSIM  | LPIPS  | depth L1 m | refine s (median) | x shipped"
    )
    for name, t in table.items():
        ratio = f"{t['seconds_median'] / shipped:.2f}" if shipped and settings[name] else "-"
        print(
            f"{name:>28} | {t['ws_psnr']:7.2f} | {t['ssim']:.4f} | {t['lpips']:.4f} | "
            f"{t['depth_l1']:10.4f} | {t['seconds_median']:17.2f} | {ratio:>9}"
        )
    if len(args.data) > 1:
        print("\nmean per dataset, WS-PSNR / LPIPS / depth L1 m:")
        for name, sets in by_data.items():
            cells = [
                f"{Path(d).name} {t['ws_psnr']:.2f} / {t['lpips']:.4f} / {t['depth_l1']:.4f}"
                for d, t in sets.items()
            ]
            print(f"{name:>28} | " + " | ".join(cells))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
