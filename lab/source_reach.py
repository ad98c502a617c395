"""Three photos prepared together: does each view need every source, or only the near ones?

    python lab/source_reach.py --data data/loo_classic data/loo_home data/loo_lit \
        --reach 1.5 [--min-near 1.0] --out lab/results/source_reach.json

For every scene all three views are prepared as `panogrf render` prepares a scene of three
photos (the depth chain, the per-scene refinement, the renderer's feature maps; timed), once
with every source in the sweep and the refinement (`all`: `DepthConfig.far_from` infinite)
and once with the sources farther than ``--reach`` times the nearest one's distance left out
(`near`: ``far_factor``) for the views whose nearest source is at least ``--min-near``
metres away (``far_from``; 0: every view). Scored: each view's
depth L1 against the truth (synthetic scenes), the preparation seconds. Table printed last.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
from depth_stages import estimator_as, scene_folders  # noqa: E402


def compared(est, c2w, sources) -> int:
    """How many sources ``est`` leaves out of what the sweep and refinement compare."""
    from panogrf.model.depth_config import compared_sources

    kept = compared_sources(est.config, c2w, sources)
    every = compared_sources(est.configured(far_from=math.inf).config, c2w, sources)
    return sum(map(len, every)) - sum(map(len, kept))


def prepare(data, models, reach, min_near=0.0):
    """The three views prepared with every source (``reach`` None) or the near ones."""
    from panogrf.model.refine import PREPARE_REFINE
    from panogrf.renderer.methods import SourceViews

    est = models.estimator("full")
    if reach is None:
        est = est.configured(far_from=math.inf)
    else:
        est = est.configured(far_from=min_near, far_factor=reach)
    with estimator_as(models, "full", est):
        t0 = time.perf_counter()
        views = SourceViews(data.images, data.c2w, refine=PREPARE_REFINE)
        views.cache_for("panogrf", models)
        seconds = time.perf_counter() - t0
    return views, seconds, compared(est, data.c2w, est.view_sources(data.c2w)[0])


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
            views, seconds, left_out = prepare(data, models, reach, args.min_near)
            row = {"scene": str(folder), "set": group, "variant": name, "seconds": seconds}
            row["sources_left_out"] = left_out
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
