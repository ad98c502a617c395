"""A home of many photos: which sources should a view's depth and a render read?

    python lab/many_views.py --scene FLOOR_SCENE --every 4 --renders 2,3,4,all \
        --depth 2,all --depth-targets 2 --out lab/results/many_views.json

A scene of many panoramas (e.g. every capture of a ZInD floor, `lab/zind_floor.py`). For every
``--every``-th view as the target, the other views are prepared as `panogrf scene prepare`
prepares them (the depth chain, the per-scene refinement, the renderer's feature maps; timed),
each view's multi-view stereo reading its ``--depth`` nearest sources (``all``: every other
view, as the product did), and the target is rendered at 512 rows (`fast`) from its
``--renders`` nearest sources; scored against the held-out photo (WS-PSNR, SSIM, LPIPS) and
timed. The depth variants other than the first run on the first ``--depth-targets`` targets
only (every source costs minutes a scene). Table printed last.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
from depth_stages import estimator_as  # noqa: E402


def _count(text: str) -> int | str | None:
    """``all`` (None), a count of nearest sources, or ``seenX``: the sources that see at least
    a share X of what the target sees (`seen_sources`)."""
    if text == "all":
        return None
    return text if text.startswith("seen") else int(text)


def seen_sources(cache, c2w, share: float, rows: int = 64, keep: int = 2, tol: float = 0.05):
    """Indices of the sources of ``cache`` that see at least ``share`` of what a camera at
    ``c2w`` sees, and always its ``keep`` nearest.

    What the camera sees: every source's depth (at ``rows``) splatted into it, the nearest
    surface per pixel. A source sees a point of it where the point's distance from the source
    is within ``tol`` (relative) of the source's own depth at the point's pixel."""
    import torch.nn.functional as F

    from panogrf.model.erp import erp_to_world, world_to_erp
    from panogrf.model.splat import splat_zbuffer

    h, w = rows, 2 * rows
    depth = F.interpolate(cache.depth, size=(h, w), mode="nearest")[:, 0]  # [V, h, w]
    surface = splat_zbuffer(depth[:, None], cache.c2w, c2w, h, w)
    valid = surface.reshape(-1) > 0
    points = erp_to_world(surface, c2w)[valid]  # [N, 3]
    uv, dist = world_to_erp(points[None], cache.c2w, h, w)  # [V, N, 2], [V, N]
    u = torch.remainder(uv[..., 0].round().long(), w)
    v = uv[..., 1].round().long().clamp(0, h - 1)
    own = depth[torch.arange(len(depth))[:, None], v, u]
    seen = ((dist - own).abs() < tol * own).float().mean(1)  # [V]
    near = torch.argsort((cache.centres - c2w[:3, 3]).norm(dim=-1))[:keep]
    chosen = (seen >= share).clone()
    chosen[near] = True
    return torch.nonzero(chosen).squeeze(1).tolist()


def subset(cache, c2w, k):
    """The cache a render reads: every source, the ``k`` nearest, or those that see enough."""
    if isinstance(k, str):
        return cache.select(seen_sources(cache, c2w, float(k[4:])))
    return cache.nearest(c2w, k)


def prepare(images, c2w, models, mvs_sources):
    """The views prepared with each view's MVS reading its ``mvs_sources`` nearest."""
    from panogrf.model.refine import PREPARE_REFINE
    from panogrf.renderer.methods import SourceViews

    est = models.estimator("full").configured(mvs_sources=mvs_sources)
    with estimator_as(models, "full", est):
        t0 = time.perf_counter()
        views = SourceViews(images, c2w, refine=PREPARE_REFINE)
        cache = views.cache_for("panogrf", models)
        seconds = time.perf_counter() - t0
    return cache, seconds


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scene", type=Path, required=True)
    parser.add_argument("--every", type=int, default=4)
    parser.add_argument("--renders", default="2,3,4,all")
    parser.add_argument("--depth", default="2,all")
    parser.add_argument("--depth-targets", type=int, default=2)
    parser.add_argument("--rows", type=int, default=512)
    parser.add_argument("--out", type=Path, default=Path("lab/results/many_views.json"))
    args = parser.parse_args()
    torch.set_num_threads(2)
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scene.session import default_models
    from panogrf.app.scoring import image_scores
    from panogrf.renderer.cache import resize_erp
    from panogrf.renderer.detail import render_detailed

    models = default_models("cpu")
    net = models.renderer("panogrf")
    scene = load_scene(args.scene, load_images=True).images
    images = (
        resize_erp(scene.images, args.rows) if scene.images.shape[-2] > args.rows else scene.images
    )
    c2w = scene.c2w
    v = images.shape[0]
    renders = [_count(x) for x in args.renders.split(",")]
    depths = [_count(x) for x in args.depth.split(",")]
    rows: list[dict] = []
    for n, target in enumerate(range(0, v, args.every)):
        others = [i for i in range(v) if i != target]
        for d, mvs in enumerate(depths):
            if d and n >= args.depth_targets:
                continue
            cache, seconds = prepare(images[others], c2w[others], models, mvs)
            for k in renders:
                t0 = time.perf_counter()
                sub = subset(cache, c2w[target], k)
                with torch.no_grad():
                    out = render_detailed(net, sub, c2w[target], args.rows, "fast")
                render_s = time.perf_counter() - t0
                s = image_scores(out.rgb, images[target : target + 1])
                near = float((sub.centres - c2w[target, :3, 3]).norm(dim=-1).min())
                row = {
                    "target": target,
                    "mvs_sources": mvs or "all",
                    "render_sources": k or "all",
                    "sources_read": sub.num_views,
                    "prepare_s": seconds,
                    "render_s": render_s,
                    "nearest_m": near,
                } | {m: s[m] for m in ("ws_psnr", "ssim", "lpips")}
                rows.append(row)
                print(
                    f"target {target:2d} mvs {row['mvs_sources']!s:>3} "
                    f"render {row['render_sources']!s:>3}: "
                    f"{s['ws_psnr']:.2f} dB SSIM {s['ssim']:.3f} LPIPS {s['lpips']:.3f}  "
                    f"prep {seconds:.1f} s render {render_s:.2f} s ({sub.num_views} sources)",
                    flush=True,
                )
            args.out.write_text(json.dumps({"machine": platform.node(), "rows": rows}, indent=1))
    head = ("mvs", "render", "targets", "WS-PSNR", "SSIM", "LPIPS", "prep s", "render s")
    print("\n" + " ".join(f"{h:>8}" for h in head))
    for mvs in depths:
        shared = {r["target"] for r in rows if r["mvs_sources"] == (mvs or "all")}
        for k in renders:
            sel = [
                r
                for r in rows
                if r["mvs_sources"] == (mvs or "all") and r["render_sources"] == (k or "all")
            ]
            if not sel:
                continue
            mean = {m: statistics.fmean(r[m] for r in sel) for m in ("ws_psnr", "ssim", "lpips")}
            print(
                f"{mvs or 'all'!s:>8} {k or 'all'!s:>8} {len(shared):>8} {mean['ws_psnr']:8.2f} "
                f"{mean['ssim']:8.3f} {mean['lpips']:8.3f} "
                f"{statistics.median(r['prepare_s'] for r in sel):8.1f} "
                f"{statistics.median(r['render_s'] for r in sel):8.2f}"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
