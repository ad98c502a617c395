"""Three photos prepared together: does each view need every source, or only the near ones?

    python lab/source_reach.py --data data/loo_classic data/loo_home data/loo_lit \
        --reach 1.5 [--min-near 1.0] --out lab/results/source_reach.json

For every scene all three views are prepared as `panogrf render` prepares a scene of three
photos (the depth chain, the per-scene refinement, the renderer's feature maps; timed), once
with every source in the sweep and the refinement (`all`) and once with the sources farther
than ``--reach`` times the nearest one's distance left out (`near`; with ``--min-near``,
only for the views whose nearest source is at least that far). Scored: each view's
depth L1 against the truth (synthetic scenes), the preparation seconds. Table printed last.
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
from depth_stages import scene_folders  # noqa: E402

#: Sources left out since the counter was last reset (a view's, in the sweep or refinement).
DROPPED = [0]


def within_reach(nearest_sources, reach, min_near=0.0):
    """``nearest_sources`` keeping only the sources within ``reach`` times the nearest one's
    distance, where the nearest is at least ``min_near`` metres away (all of them otherwise)."""

    def pick(c2w, sources, k):
        centres = c2w[:, :3, 3]
        out = []
        for r, src in enumerate(nearest_sources(c2w, sources, k)):
            dist = [float((centres[j] - centres[r]).norm()) for j in src]
            if not dist or min(dist) < min_near:
                out.append(src)
                continue
            kept = [j for j, d in zip(src, dist, strict=True) if d <= reach * min(dist)]
            DROPPED[0] += len(src) - len(kept)
            out.append(kept)
        return out

    return pick


def prepare(data, models, reach, min_near=0.0):
    from panogrf.model import depth, refine
    from panogrf.model.refine import PREPARE_REFINE
    from panogrf.renderer import methods
    from panogrf.renderer.methods import SourceViews

    if reach is not None:  # where the sweep and the refinement pick their sources
        depth.nearest_sources = methods.nearest_sources = within_reach(
            refine.nearest_sources, reach, min_near
        )
    try:
        t0 = time.perf_counter()
        views = SourceViews(data.images, data.c2w, refine=PREPARE_REFINE)
        views.cache_for("panogrf", models)
        return views, time.perf_counter() - t0
    finally:
        depth.nearest_sources = methods.nearest_sources = refine.nearest_sources


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--reach", type=float, default=1.5)
    parser.add_argument(
        "--min-near", type=float, default=0.0, help="only where the nearest source is this far"
    )
    parser.add_argument("--rows", type=int, default=512)
    parser.add_argument("--out", type=Path, default=Path("lab/results/source_reach.json"))
    args = parser.parse_args()
    torch.set_num_threads(2)
    import dataclasses

    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scene.session import default_models
    from panogrf.model.metrics import depth_metrics
    from panogrf.renderer.cache import resize_erp

    models = default_models("cpu")
    est = models.estimator("full")
    models.renderer("panogrf")
    rows: list[dict] = []
    for folder in scene_folders(args.data):
        data = load_scene(folder, load_images=True).images
        if data.images.shape[-2] != args.rows:
            images = resize_erp(data.images, args.rows)
            depths = data.depths
            if depths is not None:
                depths = torch.nn.functional.interpolate(depths, size=images.shape[-2:])
            data = dataclasses.replace(data, images=images, depths=depths)
        group = folder.parent.name if (folder.parent / "dataset.json").exists() else folder.name
        order = [("all", None), ("near", args.reach)]
        for name, reach in order if len(rows) % 4 == 0 else order[::-1]:  # alternate
            DROPPED[0] = 0
            views, seconds = prepare(data, models, reach, args.min_near)
            row = {"scene": str(folder), "set": group, "variant": name, "seconds": seconds}
            row["sources_left_out"] = DROPPED[0]
            if data.depths is not None:
                depth = torch.nn.functional.interpolate(
                    views.depth["full"], size=data.images.shape[-2:], mode="bilinear"
                )
                l1 = []
                for v in range(len(data.images)):
                    gt = data.depths[v, 0]
                    mask = (gt > 0) & (gt <= est.d_max)
                    l1.append(float(depth_metrics(depth[v, 0], gt, mask).l1))
                row["depth_l1"] = statistics.fmean(l1)
                row["depth_l1_views"] = l1
            rows.append(row)
            print(f"{group}/{folder.name} {name}: {row.get('depth_l1', float('nan')):.4f} m "
                  f"({seconds:.1f} s)", flush=True)  # fmt: skip
    sets = sorted({r["set"] for r in rows})
    table = {}
    for name in ("all", "near"):
        mine = [r for r in rows if r["variant"] == name]
        table[name] = {
            s: statistics.fmean(r["depth_l1"] for r in mine if r["set"] == s and "depth_l1" in r)
            for s in sets
            if any("depth_l1" in r for r in mine if r["set"] == s)
        }
        scored = [r["depth_l1"] for r in mine if "depth_l1" in r]
        table[name]["pooled"] = statistics.fmean(scored) if scored else float("nan")
        table[name]["prep_s"] = statistics.median(r["seconds"] for r in mine)
        # The scenes where `near` leaves a source out, each variant's time on them.
        cut = {r["scene"] for r in rows if r["variant"] == "near" and r["sources_left_out"]}
        on_cut = [r["seconds"] for r in mine if r["scene"] in cut]
        table[name]["prep_s_where_cut"] = statistics.median(on_cut) if on_cut else float("nan")
    report = {
        "what": "3 views prepared together: every source against the near ones",
        "reach": args.reach,
        "min_near_m": args.min_near,
        "machine": f"{platform.machine()}, {torch.get_num_threads()} torch threads, CPU",
        "rows": rows,
        "table": table,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1))
    cols = [*table["all"]]
    print("\nvariant | " + " | ".join(cols))
    for name in ("all", "near"):
        print(f"{name} | " + " | ".join(f"{table[name][c]:.4f}" for c in cols))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
