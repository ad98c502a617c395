"""Poses from plain panoramas against the truth: synthetic test scenes and the real dev triplet.

    python benchmarks/poses.py --data data/test --count 20 --real data/real/m3d_00000007 \
        --render 6 --out benchmarks/results/poses.json

For every scene (three panoramas on a line, true poses in transforms.json) the poses are
estimated from the pixels alone (`panogrf.app.poses.estimate`), made upright and metric with the
true camera heights (synthetic: the y of each true pose, the floor is at y = 0) or, on the real
triplet where the height is unknown, with the true first-to-last distance (1.0 m). Errors need
no alignment (`panogrf.app.poses.errors`): per pair the relative rotation error and the
translation direction error (degrees), per scene the first-to-last distance error (%). A scene
fails when a view cannot be posed; failures are counted with their reason and kept out of the
medians. ``--render N``: on the first N posed synthetic scenes the middle view is rendered by
PanoGRF from the outer two with the estimated poses (the estimated scene's own frame) and with
the true ones, both scored against the real middle view (WS-PSNR).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from panogrf.app.files.images import read_rgb, write_json_atomic
from panogrf.app.poses import errors as er
from panogrf.app.poses.estimate import estimate_poses
from panogrf.app.poses.scale import make_metric
from panogrf.app.scene.folder import load_scene


def run_scene(folder: Path, mode: str) -> dict:
    scene = load_scene(folder)
    true = scene.c2w
    images = [read_rgb(f.image_path) for f in scene.frames]
    t0 = time.perf_counter()
    est = estimate_poses(images)
    row: dict = {
        "scene": folder.name,
        "baseline_m": float(np.linalg.norm(true[0, :3, 3] - true[-1, :3, 3])),
    }
    if not est.registered.all():
        row["seconds"] = time.perf_counter() - t0
        failed = [p for p in est.pairs if not p.ok]
        row["failed"] = "; ".join(
            [n for n, ok in zip(est.view_notes, est.registered, strict=True) if not ok]
            + [f"pair {p.i}-{p.j}: {p.reason}" for p in failed]
        )
        return row
    try:
        if mode == "height":
            metric = make_metric(est.c2w, est.points, heights=true[:, 1, 3])
        else:
            metric = make_metric(
                est.c2w, est.points, distance=(0, len(true) - 1, row["baseline_m"])
            )
    except Exception as exc:  # noqa: BLE001 - a failure to count, with its reason
        row["seconds"] = time.perf_counter() - t0
        row["failed"] = str(exc)
        return row
    row["seconds"] = time.perf_counter() - t0
    pairs = er.pair_errors(metric.c2w, true)
    row["rotation_deg"] = [p["rotation_deg"] for p in pairs]
    row["translation_deg"] = [p["translation_deg"] for p in pairs]
    # With --distance the first-to-last distance is exact by construction; the middle one is not.
    row["scale_error"] = er.scale_error(metric.c2w, true, 0, 1 if mode == "distance" else -1)
    row["failed_pairs"] = [f"{p.i}-{p.j}: {p.reason}" for p in est.pairs if not p.ok]
    row["residual_deg"] = est.residual_deg
    row["c2w"] = metric.c2w.tolist()
    row["report"] = metric.lines
    return row


def render_pair(folder: Path, est_c2w: np.ndarray, models) -> dict:
    from panogrf.app.scoring import image_scores
    from panogrf.renderer.methods import SourceViews, prepare, render_view

    scene = load_scene(folder, load_images=True)
    data = scene.images
    out = {}
    for name, c2w in (("true", data.c2w), ("estimated", torch.from_numpy(est_c2w).to(data.c2w))):
        views = SourceViews(data.images[[0, 2]], c2w[[0, 2]])
        prepare("panogrf", views, models)
        rgb = render_view("panogrf", views, c2w[1], scene.height, models, "fast")
        out[name] = image_scores(rgb, data.images[1:2])["ws_psnr"]
    return out


def summary(rows: list[dict]) -> dict:
    ok = [r for r in rows if "failed" not in r]
    if not ok:
        return {"scenes": len(rows), "failed": len(rows)}
    return {
        "scenes": len(rows),
        "posed": len(ok),
        "failed": len(rows) - len(ok),
        "rotation_deg_median": statistics.median(x for r in ok for x in r["rotation_deg"]),
        "translation_deg_median": statistics.median(x for r in ok for x in r["translation_deg"]),
        "scale_error_median": statistics.median(r["scale_error"] for r in ok),
        "rotation_deg_max": max(x for r in ok for x in r["rotation_deg"]),
        "translation_deg_max": max(x for r in ok for x in r["translation_deg"]),
        "scale_error_max": max(r["scale_error"] for r in ok),
        "seconds_median": statistics.median(r["seconds"] for r in rows),
        "failed_pairs": sum(len(r["failed_pairs"]) for r in ok),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=Path("data/test"))
    parser.add_argument("--count", type=int, default=20, help="synthetic scenes (1.0-2.0 m)")
    parser.add_argument("--baselines", default="1.0,1.5,2.0")
    parser.add_argument("--real", type=Path, default=Path("data/real/m3d_00000007"))
    parser.add_argument("--render", type=int, default=0, help="scenes for the render check")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/poses.json"))
    args = parser.parse_args()
    torch.set_num_threads(1)
    baselines = {round(float(b), 1) for b in args.baselines.split(",")}
    folders = []
    for entry in json.loads((args.data / "dataset.json").read_text())["scenes"]:
        if round(entry["baseline_m"], 1) in baselines and len(folders) < args.count:
            folders.append(args.data / entry["folder"])
    rows = []
    for folder in folders:
        row = run_scene(folder, "height")
        rows.append(row)
        state = row.get("failed") or (
            f"rot {max(row['rotation_deg']):.3f} dir {max(row['translation_deg']):.3f} "
            f"scale {100 * row['scale_error']:.2f}%"
        )
        print(
            f"{folder.name} ({row['baseline_m']:.1f} m) {row['seconds']:.1f} s  {state}", flush=True
        )
    real = None
    if args.real and (args.real / "transforms.json").exists():
        real = run_scene(args.real, "distance")
        print(f"real {args.real.name}: {real.get('failed') or 'posed'} ({real['seconds']:.1f} s)")
    renders = []
    if args.render:
        from panogrf.app.scene.session import default_models

        models = default_models()
        for row, folder in zip(rows, folders, strict=True):
            if len(renders) >= args.render:
                break
            if "failed" in row:
                continue
            scores = render_pair(folder, np.array(row["c2w"]), models)
            renders.append(
                {"scene": folder.name, **scores, "delta_db": scores["estimated"] - scores["true"]}
            )
            print(
                f"render {folder.name}: WS-PSNR true {scores['true']:.2f}, "
                f"estimated {scores['estimated']:.2f}",
                flush=True,
            )
    synth = summary(rows)
    result = {
        "what": "poses estimated from panoramas vs the truth (no alignment: relative errors)",
        "synthetic": synth,
        "real": None
        if real is None
        else {
            **summary([real]),
            "scale_from": "true first-to-last distance 1.0 m (--distance 0,2=1.0); "
            "scale error is of the 0-1 distance",
        },
        "render": renders,
        "per_scene": [{k: v for k, v in r.items() if k != "c2w"} for r in rows]
        + ([] if real is None else [{k: v for k, v in real.items() if k != "c2w"}]),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, 1 torch thread, CPU",
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out, result)
    lines = [
        f"{'set':<22} {'posed':>7} {'rot deg':>8} {'dir deg':>8} {'scale %':>8} {'s/scene':>8}",
    ]
    for name, s in (("synthetic (height)", synth), ("real (distance 1.0 m)", result["real"])):
        if s is None or "posed" not in s:
            continue
        lines.append(
            f"{name:<22} {s['posed']:>3}/{s['scenes']:<3} {s['rotation_deg_median']:8.3f} "
            f"{s['translation_deg_median']:8.3f} {100 * s['scale_error_median']:8.2f} "
            f"{s['seconds_median']:8.1f}"
        )
    if renders:
        d = statistics.median(r["delta_db"] for r in renders)
        worst = min(r["delta_db"] for r in renders)
        lines.append(
            f"render: {len(renders)} scenes, WS-PSNR estimated - true poses: "
            f"median {d:+.2f} dB, worst {worst:+.2f} dB"
        )
    failures = [f"{r['scene']}: {r['failed']}" for r in rows if "failed" in r]
    lines.append(f"failures: {len(failures)}" + "".join(f"\n  {f}" for f in failures))
    print(f"wrote {args.out}")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
