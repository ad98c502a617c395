"""Posing methods side by side on scene folders with true poses: success rate, errors, time.

    python benchmarks/poses_real.py --set zind=/data/zind_scenes --set m3d=/data/m3d_scene \
        --methods colmap,colmap-nolevel --out lab/results/poses_real.json

Every scene folder (two or more panoramas, true poses in transforms.json) is posed from its
pixels alone by each method; errors need no alignment (`panogrf.app.poses.errors`): per pair
the relative rotation error and the translation direction error (degrees), per scene the scale
error of the first-to-last distance after `make_metric` with the true camera heights when the
scene has a floor at y = 0 (every true height > 0.5 m), else with the true first-to-last
distance (then the 0-1 distance is scored). A scene counts as posed when every view is.
Methods:
- ``colmap``: the product's path (`panogrf.app.poses.colmap`): SIFT on cube faces, pooled
  matching between panoramas, COLMAP's verification, the level-camera search for the pairs it
  cannot verify (`panogrf.app.poses.upright`), guided matching, mapping and bundle adjustment.
- ``colmap-nolevel``: the same without the level-camera search.
The home-made pipeline it replaced (SIFT cube faces, RANSAC on bearings, incremental
registration, scipy adjustment; ``app/poses/estimate.py`` until this round) was measured side by
side before it was removed: ``lab/results/poses_real_before.json``.
The table is printed last; the JSON keeps every scene's row.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from panogrf.app.files.images import read_rgb, write_json_atomic
from panogrf.app.poses import errors as er
from panogrf.app.poses.scale import make_metric
from panogrf.app.scene.folder import load_scene


def pose(method: str, images: list[np.ndarray]):
    """(c2w [V, 4, 4], registered [V], points [P, 3], report lines)."""
    if method in ("colmap", "colmap-nolevel"):
        from panogrf.app.poses.colmap import ColmapConfig, estimate_poses_colmap

        cfg = ColmapConfig(num_threads=2)
        if method == "colmap-nolevel":  # without the search for level cameras
            cfg = ColmapConfig(num_threads=2, level_search=None)
        est = estimate_poses_colmap(images, cfg)
        notes = [
            f"{p.i}-{p.j}: {p.matches} matches, {p.inliers} inliers"
            + ("" if p.level_search is None else f", grown from the level search {p.level_search}")
            for p in est.pairs
        ]
        return est.c2w, est.registered, est.points, notes
    raise SystemExit(f"unknown method {method}")


def run_scene(folder: Path, method: str) -> dict:
    scene = load_scene(folder)
    true = scene.c2w
    images = [read_rgb(f.image_path) for f in scene.frames]
    start = time.perf_counter()
    c2w, registered, points, notes = pose(method, images)
    row: dict = {
        "scene": folder.name,
        "views": len(images),
        "size": list(images[0].shape[:2]),
        "baseline_m": float(np.linalg.norm(true[0, :3, 3] - true[-1, :3, 3])),
        "seconds": time.perf_counter() - start,
        "registered": int(registered.sum()),
        "pairs": notes,
    }
    if not registered.all():
        row["failed"] = f"{int(registered.sum())} of {len(images)} views posed"
        keep = np.flatnonzero(registered)
        if len(keep) >= 2:  # what was posed must still be right
            pairs = er.pair_errors(c2w[keep], true[keep])
            row["posed_rotation_deg"] = [p["rotation_deg"] for p in pairs]
            row["posed_translation_deg"] = [p["translation_deg"] for p in pairs]
            row["failed"] += (
                f" (those: rot {max(row['posed_rotation_deg']):.3f}, "
                f"dir {max(row['posed_translation_deg']):.3f})"
            )
        return row
    pairs = er.pair_errors(c2w, true)
    row["rotation_deg"] = [p["rotation_deg"] for p in pairs]
    row["translation_deg"] = [p["translation_deg"] for p in pairs]
    heights = true[:, 1, 3]
    try:
        if np.all(heights > 0.5):
            metric = make_metric(c2w, points, heights=heights)
            row["scale_error"] = er.scale_error(metric.c2w, true)
            row["scale_from"] = "true camera heights"
            row["metric_c2w"] = metric.c2w.tolist()
        else:
            metric = make_metric(c2w, points, distance=(0, len(true) - 1, row["baseline_m"]))
            row["scale_error"] = er.scale_error(metric.c2w, true, 0, 1)
            row["scale_from"] = "true first-to-last distance"
            row["metric_c2w"] = metric.c2w.tolist()
    except Exception as exc:  # noqa: BLE001 - a failure to count, with its reason
        row["scale_failed"] = str(exc)
    return row


def render_check(folder: Path, est_c2w: np.ndarray, height: int, models) -> dict:
    """The middle view of a triplet rendered (PanoGRF, fast) from the outer two with the true
    poses and with the estimated metric ones (the estimated scene's own frame), both scored
    against the real middle photo: WS-PSNR and LPIPS."""
    import torch

    from panogrf.app.scoring import image_scores
    from panogrf.renderer.methods import SourceViews, prepare, render_view

    scene = load_scene(folder, load_images=True)
    data = scene.images
    out = {}
    for name, c2w in (("true", data.c2w), ("estimated", torch.from_numpy(est_c2w).to(data.c2w))):
        views = SourceViews(data.images[[0, 2]], c2w[[0, 2]])
        prepare("panogrf", views, models)
        rgb = render_view("panogrf", views, c2w[1], height, models, "fast")
        gt = torch.nn.functional.interpolate(
            data.images[1:2], size=(height, 2 * height), mode="area"
        )
        scores = image_scores(rgb, gt)
        out[name] = {"ws_psnr": scores["ws_psnr"], "lpips": scores.get("lpips")}
    return out


def summary(rows: list[dict]) -> dict:
    ok = [r for r in rows if "failed" not in r]
    out = {
        "scenes": len(rows),
        "posed": len(ok),
        "views_posed": sum(r["registered"] for r in rows),
        "views": sum(r["views"] for r in rows),
        "seconds_median": statistics.median(r["seconds"] for r in rows),
    }
    partial = [x for r in rows for x in r.get("posed_rotation_deg", [])]
    if partial:
        out["partial_rotation_deg_max"] = max(partial)
        out["partial_translation_deg_max"] = max(
            x for r in rows for x in r.get("posed_translation_deg", [])
        )
    if ok:
        out.update(
            rotation_deg_median=statistics.median(x for r in ok for x in r["rotation_deg"]),
            translation_deg_median=statistics.median(x for r in ok for x in r["translation_deg"]),
            scale_error_median=statistics.median(r["scale_error"] for r in ok if "scale_error" in r)
            if any("scale_error" in r for r in ok)
            else float("nan"),
            scale_failed=sum("scale_failed" in r for r in ok),
            rotation_deg_max=max(x for r in ok for x in r["rotation_deg"]),
            translation_deg_max=max(x for r in ok for x in r["translation_deg"]),
        )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--set",
        action="append",
        required=True,
        metavar="NAME=DIR",
        help="a scene folder, or a folder of scene folders; repeat for more sets",
    )
    parser.add_argument("--methods", default="colmap")
    parser.add_argument("--out", type=Path, default=Path("lab/results/poses_real.json"))
    parser.add_argument(
        "--render",
        type=int,
        default=0,
        metavar="ROWS",
        help="also render each posed triplet's middle view at this height (0: no render check)",
    )
    args = parser.parse_args()
    import torch

    torch.set_num_threads(2)
    sets = {}
    for item in args.set:
        name, _, folder = item.partition("=")
        folder = Path(folder)
        if (folder / "transforms.json").exists():
            sets[name] = [folder]
        else:
            sets[name] = sorted(p.parent for p in folder.glob("*/transforms.json"))
    methods = args.methods.split(",")
    models = None
    rows: dict = {m: {s: [] for s in sets} for m in methods}
    for s, folders in sets.items():
        for folder in folders:
            for m in methods:
                row = run_scene(folder, m)
                rows[m][s].append(row)
                state = row.get("failed") or (
                    f"rot {max(row['rotation_deg']):.3f} dir {max(row['translation_deg']):.3f} "
                    + (
                        f"scale {100 * row['scale_error']:.1f}%"
                        if "scale_error" in row
                        else f"scale failed: {row['scale_failed']}"
                    )
                )
                print(f"{m:>10} {s}/{folder.name} {row['seconds']:.1f} s  {state}", flush=True)
                if args.render and row.get("metric_c2w") and row["views"] == 3:
                    if models is None:
                        from panogrf.app.scene.session import default_models

                        models = default_models()
                    row["render"] = render_check(
                        folder, np.array(row["metric_c2w"]), args.render, models
                    )
                    r = row["render"]
                    print(
                        f"{'':>10} render: WS-PSNR true {r['true']['ws_psnr']:.2f}, estimated "
                        f"{r['estimated']['ws_psnr']:.2f} dB",
                        flush=True,
                    )
    result = {
        "what": "poses from panoramas against the truth (relative errors, no alignment)",
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, CPU, 2 threads",
        "summary": {m: {s: summary(r) for s, r in by.items()} for m, by in rows.items()},
        "rows": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out, result)
    lines = [
        f"{'method':<10} {'set':<8} {'posed':>7} {'views':>7} {'rot med':>8} {'dir med':>8} "
        f"{'rot max':>8} {'dir max':>8} {'scale %':>8} {'no scale':>8} {'s/scene':>8}"
    ]
    for m, by in result["summary"].items():
        for s, x in by.items():
            tail = (
                f"{x['rotation_deg_median']:8.3f} {x['translation_deg_median']:8.3f} "
                f"{x['rotation_deg_max']:8.2f} {x['translation_deg_max']:8.2f} "
                f"{100 * x['scale_error_median']:8.1f} {x['scale_failed']:>8}"
                if "rotation_deg_median" in x
                else f"{'-':>8} {'-':>8} {'-':>8} {'-':>8} {'-':>8} {'-':>8}"
            )
            lines.append(
                f"{m:<10} {s:<8} {x['posed']:>3}/{x['scenes']:<3} "
                f"{x['views_posed']:>3}/{x['views']:<3} {tail} {x['seconds_median']:8.1f}"
            )
    for m, by in rows.items():
        renders = [r["render"] for rs in by.values() for r in rs if "render" in r]
        if renders:
            deltas = [r["estimated"]["ws_psnr"] - r["true"]["ws_psnr"] for r in renders]
            lines.append(
                f"{m}: render check on {len(renders)} triplets ({args.render} rows), WS-PSNR "
                f"estimated - true poses: median {statistics.median(deltas):+.2f} dB, worst "
                f"{min(deltas):+.2f} dB"
            )
    print(f"wrote {args.out}")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
