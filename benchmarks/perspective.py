"""Perspective frames of a camera path: the camera's own rays against a cut panorama.

    python benchmarks/perspective.py [--width 1280 --height 720 --fov 60] [--repeats 3]

On the bundled scene, one 1280x720 frame at the middle view's pose with ``--quality fast``,
both ways in the same process: ``own rays`` (`render_perspective_view`: the network at every
pixel of the frame) and ``panorama + cut`` (a panorama at the frame's angular resolution,
`erp_height_for`, its network at 256 rows and the sources' detail, then `erp_to_perspective`).
`render --camera-path` takes whichever runs the network on fewer rays (`app/paths/frames.py`).
Median seconds of the repeats (scene preparation excluded), their ratio, and the agreement
of the two frames (PSNR).
Writes lab/results/perspective.json.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from panogrf.app.paths.frames import erp_height_for
from panogrf.app.scene.folder import load_scene
from panogrf.app.scene.session import default_models
from panogrf.assets import path as asset_path
from panogrf.model.perspective import erp_to_perspective
from panogrf.renderer.methods import SourceViews, prepare, render_perspective_view, render_view


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--width", type=int, default=1280)
    parser.add_argument("--height", type=int, default=720)
    parser.add_argument("--fov", type=float, default=60.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("lab/results/perspective.json"))
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    data = load_scene(asset_path("demo"), load_images=True).images
    models = default_models()
    views = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]])
    prepare("panogrf", views, models)
    pose = data.c2w[1]
    w, h, fov = args.width, args.height, args.fov
    rows = erp_height_for("perspective", w, h, fov)
    times: dict[str, list[float]] = {"own rays": [], "panorama + cut": []}
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        own = render_perspective_view("panogrf", views, pose, w, h, fov, models, "fast")
        times["own rays"].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        cut = erp_to_perspective(
            render_view("panogrf", views, pose, rows, models, "fast"), w, h, fov
        )
        times["panorama + cut"].append(time.perf_counter() - t0)
    agree = 10 * np.log10(1 / float(((own - cut) ** 2).mean()))
    med = {k: statistics.median(v) for k, v in times.items()}
    result = {
        "frame": [w, h], "fov_deg": fov, "panorama_rows": rows, "median_seconds": med,
        "speedup": med["panorama + cut"] / med["own rays"], "agreement_psnr_db": agree,
        "repeats": args.repeats, "threads": torch.get_num_threads(),
        "machine": platform.processor() or platform.machine(),
    }  # fmt: skip
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"{w}x{h} perspective frame, fov {fov:g}, PanoGRF fast, {args.repeats} repeats")
    print("| way | rays | median s |")
    print("|---|---|---|")
    print(f"| own rays | {w * h} | {med['own rays']:.2f} |")
    net_rays = 2 * min(rows, 256) ** 2
    print(
        f"| panorama ({rows} rows, network at 256) + cut | {net_rays} "
        f"| {med['panorama + cut']:.2f} |"
    )
    print(f"speed-up {result['speedup']:.2f}x; the two frames agree to {agree:.1f} dB PSNR")


if __name__ == "__main__":
    main()
