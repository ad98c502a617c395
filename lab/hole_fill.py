"""Issue 56, a look: what no source sees, filled from what they see instead of the network's guess.

    python lab/hole_fill.py --data data/loo_classic data/loo_home data/loo_lit \
        ZIND_SCENES/floor_01_complete_room_06_* --out lab/results/hole_fill.json

For each validation scene the view nearest both others is rendered from the other two
(`fast`, 512 rows, the shipped preparation), as `benchmarks/depth_stages.py` does. The
sources' depth maps are splatted into the target at 256 rows (`model.splat.proxy_depth`): a
pixel no source's point lands on, after a 5-pixel closing of the covered mask (cracks of the
splat), is one no source sees. The variant `fill` replaces those pixels of the render by a
push-pull fill of the covered ones (box-blurred mask, 9 px at 512 rows, so no seam), instead
of the network's colour there. WS-PSNR and LPIPS of both, per set and pooled; a table last.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import torch
import torch.nn.functional as F

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))


def push_pull(rgb: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """[3, H, W] filled where ``weight`` [H, W] (0-1) is low from ever coarser averages."""
    levels = [(rgb * weight, weight)]
    while min(levels[-1][1].shape) > 2:
        c, m = levels[-1]
        levels.append((F.avg_pool2d(c[None], 2)[0], F.avg_pool2d(m[None, None], 2)[0, 0]))
    c, m = levels[-1]
    fill = (c.sum((1, 2)) / m.sum().clamp(min=1e-6))[:, None, None].expand_as(c)
    for c, m in reversed(levels):
        up = F.interpolate(fill[None], size=m.shape, mode="bilinear", align_corners=False)[0]
        fill = c + (1 - m) * up
    return fill


def seen_weight(cache, c2w: torch.Tensor, rows: int) -> torch.Tensor:
    """Where some source sees the target's surface, [rows, 2 rows] in 0-1."""
    from panogrf.model.splat import proxy_depth

    d = F.interpolate(cache.depth, size=(rows // 2, rows), mode="nearest")
    covered = proxy_depth(d, cache.c2w, c2w.to(d.dtype), rows // 2, rows).covered.float()
    closed = -F.max_pool2d(-F.max_pool2d(covered[None, None], 5, 1, 2), 5, 1, 2)
    m = F.interpolate(closed, size=(rows, 2 * rows), mode="bilinear", align_corners=False)
    return F.avg_pool2d(m, 9, 1, 4)[0, 0]


def middle_views(paths: list[Path], rows: int, models):
    """Per scene of ``paths`` (folders or datasets): (folder, its set's name, the scene with
    the view nearest both others in the middle, that view rendered from the outer two as the
    product does (`fast`), where the sources see it (`seen_weight`))."""
    from depth_stages import middle_first, scene_folders

    from panogrf.app.scene.folder import load_scene
    from panogrf.model.refine import PREPARE_REFINE
    from panogrf.renderer.methods import SourceViews, render_view

    for folder in scene_folders(paths):
        group = folder.parent.name if (folder.parent / "dataset.json").exists() else "real"
        data = middle_first(load_scene(folder, load_images=True).images, rows)
        views = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]], refine=PREPARE_REFINE)
        rgb = render_view("panogrf", views, data.c2w[1], rows, models, "fast")
        w = seen_weight(views.cache_for("panogrf", models), data.c2w[1], rows)
        yield folder, group, data, rgb, w


def main() -> None:
    from panogrf.app.scene import session
    from panogrf.app.scoring import image_scores

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, nargs="+", required=True)
    p.add_argument("--rows", type=int, default=512)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("lab/results/hole_fill.json"))
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    models = session.default_models("cpu")
    rows: dict[str, dict[str, list[dict]]] = {"shipped": {}, "fill": {}}
    for folder, group, data, rgb, w in middle_views(args.data, args.rows, models):
        filled = w * rgb + (1 - w) * push_pull(rgb, w)
        unseen = float(1 - w.mean())
        for name, img in (("shipped", rgb), ("fill", filled)):
            s = image_scores(img, data.images[1:2])
            row = {"scene": str(folder), "ws_psnr": s["ws_psnr"], "lpips": s["lpips"]}
            rows[name].setdefault(group, []).append(row | {"unseen": unseen})
        a, b = rows["shipped"][group][-1], rows["fill"][group][-1]
        print(f"{folder.name}: unseen {unseen:.1%}, shipped {a['ws_psnr']:.2f} / {a['lpips']:.3f}"
              f", fill {b['ws_psnr']:.2f} / {b['lpips']:.3f}", flush=True)  # fmt: skip
    table = {
        name: {
            g: {k: statistics.fmean(r[k] for r in rs) for k in ("ws_psnr", "lpips", "unseen")}
            for g, rs in (groups | {"pooled": [r for rs in groups.values() for r in rs]}).items()
        }
        for name, groups in rows.items()
    }
    args.out.write_text(json.dumps({"table": table, "rows": rows}, indent=1))
    print(f"\n{'set':12} | {'unseen':>6} | {'shipped':>15} | {'fill':>15}")
    for g in table["shipped"]:
        a, b = table["shipped"][g], table["fill"][g]
        print(f"{g:12} | {a['unseen']:6.1%} | {a['ws_psnr']:6.2f} / {a['lpips']:.4f} | "
              f"{b['ws_psnr']:6.2f} / {b['lpips']:.4f}")  # fmt: skip


if __name__ == "__main__":
    main()
