"""Sources finer than a render: read as they are, or area-averaged to twice the render's rows
(`panogrf.renderer.cache.SceneCache.at_most`, `SOURCE_ROWS_PER_ROW`).

    python lab/source_level.py --data data/hires_classic data/hires_lit ZIND_SCENES... \
        --out lab/results/source_level.json

Per scene (three views, the middle one rendered from the outer two at ``--rows``, `fast`, the
sources at their own resolution, the shipped preparation): the render with
``SOURCE_ROWS_PER_ROW = None`` (the sources as they are: before this change) and ``= 2``, both
from one prepared scene, scored against the middle view (area-resized to the render's rows).
``--net-rows 128 --sampling bicubic`` is the viewer's last refinement level. A table is
printed last.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

VARIANTS = {"as_they_are": None, "at_most_2x": 2}


def main() -> None:
    from depth_stages import middle_first, scene_folders

    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scene.session import default_models
    from panogrf.app.scoring import image_scores
    from panogrf.model.refine import PREPARE_REFINE
    from panogrf.renderer import cache as cache_module
    from panogrf.renderer.detail import DEFAULT_DETAIL, render_detailed
    from panogrf.renderer.methods import SourceViews

    parser = argparse.ArgumentParser()
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--rows", type=int, default=512)
    parser.add_argument(
        "--net-rows",
        type=int,
        default=None,
        help="the network's rows (default: the shipped detail's, 256)",
    )
    parser.add_argument("--sampling", default=None, help="bilinear or bicubic source reads")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("lab/results/source_level.json"))
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    models = default_models()
    net = models.renderer("panogrf")
    config = DEFAULT_DETAIL
    if args.net_rows:
        config = dataclasses.replace(config, net_height=args.net_rows)
    if args.sampling:
        config = dataclasses.replace(config, sampling=args.sampling)
    rows: dict[str, dict[str, list[dict]]] = {v: {} for v in VARIANTS}
    table: dict = {}
    for folder in scene_folders(args.data):
        group = folder.parent.name if (folder.parent / "dataset.json").exists() else "real"
        scene = load_scene(folder, load_images=True).images
        data = middle_first(scene, scene.images.shape[-2])  # the sources' own rows
        views = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]], refine=PREPARE_REFINE)
        cache = views.cache_for("panogrf", models)
        for name, ratio in VARIANTS.items():
            cache_module.SOURCE_ROWS_PER_ROW = ratio
            with torch.no_grad():
                out = render_detailed(net, cache, data.c2w[1].to(views.c2w), args.rows, "fast",
                                      config)  # fmt: skip
            assert out is not None
            rgb = out.rgb
            s = image_scores(rgb, data.images[1:2])
            row = {k: s[k] for k in ("ws_psnr", "ssim", "lpips")} | {"scene": str(folder)}
            rows[name].setdefault(group, []).append(row)
            print(f"{group}/{folder.name} ({data.images.shape[-2]} rows) {name:>11}: "
                  f"{s['ws_psnr']:.2f} dB LPIPS {s['lpips']:.4f}", flush=True)  # fmt: skip
        table = {
            v: {
                g: {k: statistics.fmean(r[k] for r in rs) for k in ("ws_psnr", "ssim", "lpips")}
                for g, rs in [*per.items(), ("pooled", [r for rs in per.values() for r in rs])]
            }
            for v, per in rows.items()
        }
        report = {"rows": args.rows, "detail": repr(config), "table": table, "scenes": rows}
        args.out.write_text(json.dumps(report, indent=1))
    print(f"\n{'variant':>11} " + " ".join(f"{g:>22}" for g in table["as_they_are"]))
    for v in VARIANTS:
        cells = [f"{t['ws_psnr']:6.2f} / {t['lpips']:.4f}" for t in table[v].values()]
        print(f"{v:>11} " + " ".join(f"{c:>22}" for c in cells))


if __name__ == "__main__":
    main()
