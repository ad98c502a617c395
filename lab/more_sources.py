"""Issue 56, a look: a view of a home of many photos rendered from its K nearest photos.

    python lab/more_sources.py --scene FLOOR --targets 4,21,16 --ks 2,3,4,6 \
        --out lab/results/more_sources.json

The issue's protocol renders a view from the two photos around it; a user's tour has more, and
the product prepares and renders from all of a scene's photos (`RENDER_SOURCES` None). For
each target photo of a many-photo scene (`lab/zind_floor.py`), the K photos nearest it (the
target left out) are prepared as the product prepares a scene (full depth, per-scene
refinement) and the target rendered from them (`fast`, 512 rows), then scored against it,
WS-PSNR / SSIM / LPIPS, with the share of the view no source's depth lands on
(`hole_fill.seen_weight`). A table last.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> None:
    from hole_fill import seen_weight

    from panogrf.app.scene import session
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scoring import image_scores
    from panogrf.model.refine import PREPARE_REFINE
    from panogrf.renderer.cache import resize_erp
    from panogrf.renderer.methods import SourceViews, render_view

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", type=Path, required=True)
    p.add_argument("--targets", required=True)
    p.add_argument("--ks", default="2,3,4,6")
    p.add_argument("--rows", type=int, default=512)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("lab/results/more_sources.json"))
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    models = session.default_models("cpu")
    scene = load_scene(args.scene, load_images=True).images
    images = resize_erp(scene.images, args.rows)
    c2w = scene.c2w
    ks = [int(k) for k in args.ks.split(",")]
    rows: dict[int, list[dict]] = {k: [] for k in ks}
    for t in (int(x) for x in args.targets.split(",")):
        dist = torch.linalg.vector_norm(c2w[:, :3, 3] - c2w[t, :3, 3], dim=-1)
        dist[t] = float("inf")
        order = torch.argsort(dist).tolist()
        for k in ks:
            src = sorted(order[:k])
            start = time.perf_counter()
            views = SourceViews(images[src], c2w[src], refine=PREPARE_REFINE)
            rgb = render_view("panogrf", views, c2w[t], args.rows, models, "fast")
            seconds = time.perf_counter() - start
            w = seen_weight(views.cache_for("panogrf", models), c2w[t], args.rows)
            s = image_scores(rgb, images[t : t + 1])
            row = {m: s[m] for m in ("ws_psnr", "ssim", "lpips")} | {
                "target": t, "sources": src, "unseen": float(1 - w.mean()), "seconds": seconds,
                "farthest_m": float(dist[order[k - 1]])}  # fmt: skip
            rows[k].append(row)
            print(f"target {t} K={k} {src}: unseen {row['unseen']:.0%} "
                  f"{s['ws_psnr']:.2f} / {s['ssim']:.3f} / {s['lpips']:.3f} ({seconds:.0f} s)",
                  flush=True)  # fmt: skip
        args.out.write_text(json.dumps({"rows": {str(k): r for k, r in rows.items()}}, indent=1))
    print(f"\n{'K':>3} {'unseen':>7} {'WS-PSNR':>8} {'SSIM':>6} {'LPIPS':>6} {'s':>5}")
    for k, rs in rows.items():
        m = {f: statistics.fmean(r[f] for r in rs) for f in ("unseen", "ws_psnr", "ssim", "lpips",
                                                              "seconds")}  # fmt: skip
        print(
            f"{k:>3} {m['unseen']:>7.1%} {m['ws_psnr']:>8.2f} {m['ssim']:>6.3f} "
            f"{m['lpips']:>6.3f} {m['seconds']:>5.0f}"
        )


if __name__ == "__main__":
    main()
