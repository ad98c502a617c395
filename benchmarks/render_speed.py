"""Rendering speed and quality against the number of samples, on this machine, in one process.

    python benchmarks/render_speed.py --data data/test --out lab/results/render_speed.json

Part 1 (speed): one test scene at 1.0 m (its middle view rendered from the outer two), the
scene prepared once (depth + caches, timed separately), then every (size, sampling) pair
rendered ``--repeats`` times; the median milliseconds per panorama are reported, with the
ratio of ``paper`` (the seed's 64 + 64 samples) to ``fast`` (depth-guided) measured side by
side. Part 2 (quality against cost): on the first ``--scenes`` scenes at 1.0 m, WS-PSNR of the
middle view for depth-guided sampling (4 or 8 guided samples alone, or with a sparse
uniform backbone: 3 + 1 = draft, 4 + 2, 8 + 4 = fast, 16 + 8) and for coarse-to-fine sampling
with 16 + 16, 32 + 32 and 64 + 64 samples, with their render times. A table is printed last.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import subprocess
import time
from pathlib import Path

import torch

from panogrf.app.files.images import write_json_atomic
from panogrf.app.scene.folder import load_scene
from panogrf.app.scene.session import default_models
from panogrf.app.scoring import image_scores
from panogrf.renderer.methods import SourceViews, prepare
from panogrf.renderer.render import QUALITY, Sampling, render_panorama

SWEEP = {
    "guided 4": Sampling(n_coarse=0, n_fine=0, n_guided=4),
    "guided 8": Sampling(n_coarse=0, n_fine=0, n_guided=8),
    "guided 3 + 1 (draft)": QUALITY["draft"],
    "guided 4 + 2 uniform": Sampling(n_coarse=2, n_fine=0, n_guided=4),
    "guided 8 + 4 (fast)": QUALITY["fast"],
    "guided 16 + 8": Sampling(n_coarse=8, n_fine=0, n_guided=16),
    "16 + 16": Sampling(n_coarse=16, n_fine=16),
    "32 + 32": Sampling(n_coarse=32, n_fine=32),
    "64 + 64 (paper)": QUALITY["paper"],
}


def _scenes_at(root: Path, baseline: float) -> list[Path]:
    entries = json.loads((root / "dataset.json").read_text())["scenes"]
    out = []
    for e in entries:
        scene = load_scene(root / e["folder"])
        c = scene.c2w[:, :3, 3]
        if abs(float(((c[2] - c[0]) ** 2).sum() ** 0.5) - baseline) < 0.05:
            out.append(root / e["folder"])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=Path("data/test"))
    parser.add_argument("--out", type=Path, default=Path("lab/results/render_speed.json"))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--heights", default="256,512")
    parser.add_argument("--scenes", type=int, default=10, help="scenes of the quality sweep")
    parser.add_argument("--sweep-height", type=int, default=256)
    parser.add_argument("--threads", type=int, default=0)
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    models = default_models()
    scenes = _scenes_at(args.data, 1.0)
    if not scenes:
        raise SystemExit(f"{args.data}: no scene at 1.0 m")

    # Part 1: speed.
    data = load_scene(scenes[0], load_images=True).images
    views = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]])
    t0 = time.perf_counter()
    prepare("panogrf", views, models)
    prep = time.perf_counter() - t0
    net = models.renderer("panogrf")
    cache = views.cache_for("panogrf", models)
    speed = {}
    for height in (int(h) for h in args.heights.split(",")):
        for quality in ("fast", "paper"):
            times = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                render_panorama(net, cache, data.c2w[1], height, quality)
                times.append(1000 * (time.perf_counter() - t0))
            speed[f"{height}x{2 * height} {quality}"] = {
                "median_ms": statistics.median(times),
                "runs_ms": times,
            }
            print(f"{height}x{2 * height} {quality}: {statistics.median(times):.0f} ms", flush=True)

    # Part 2: quality against the number of samples.
    sweep: dict[str, dict[str, list[float]]] = {k: {"ws_psnr": [], "ms": []} for k in SWEEP}
    for folder in scenes[: args.scenes]:
        d = load_scene(folder, load_images=True).images
        v = SourceViews(d.images[[0, 2]], d.c2w[[0, 2]])
        c = v.cache_for("panogrf", models)
        for name, sampling in SWEEP.items():
            t0 = time.perf_counter()
            out = render_panorama(net, c, d.c2w[1], args.sweep_height, sampling)
            sweep[name]["ms"].append(1000 * (time.perf_counter() - t0))
            sweep[name]["ws_psnr"].append(image_scores(out.rgb, d.images[1:2])["ws_psnr"])
        print(f"sweep: {folder.name} done", flush=True)
    sweep_summary = {
        k: {
            "samples_per_ray": SWEEP[k].n_guided + SWEEP[k].n_coarse + SWEEP[k].n_fine,
            "ws_psnr": statistics.fmean(v["ws_psnr"]),
            "median_ms": statistics.median(v["ms"]),
        }
        for k, v in sweep.items()
    }
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    report = {
        "what": "PanoGRF render time per panorama and quality against samples per ray",
        "scene_for_speed": scenes[0].name,
        "prepare_s": prep,
        "speed": speed,
        "sweep_height": args.sweep_height,
        "sweep_scenes": [p.name for p in scenes[: args.scenes]],
        "sweep": sweep_summary,
        "machine": f"{platform.machine()}, {torch.get_num_threads()} torch threads, CPU",
        "commit": commit.stdout.strip(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out, report)
    print(f"\nscene preparation (depth + caches): {prep:.2f} s")
    print(f"{'size / sampling':<24} {'median ms':>10}")
    for k, v in speed.items():
        print(f"{k:<24} {v['median_ms']:10.0f}")
    for height in (int(h) for h in args.heights.split(",")):
        key = f"{height}x{2 * height}"
        ratio = speed[f"{key} paper"]["median_ms"] / speed[f"{key} fast"]["median_ms"]
        print(f"{key}: paper / fast = {ratio:.1f}x")
    n = len(scenes[: args.scenes])
    print(f"\nquality vs samples ({n} scenes at 1.0 m, {args.sweep_height} rows):")
    print(f"{'sampling':<22} {'samples':>7} {'WS-PSNR':>8} {'median ms':>10}")
    for k, v in sweep_summary.items():
        print(f"{k:<22} {v['samples_per_ray']:7d} {v['ws_psnr']:8.2f} {v['median_ms']:10.0f}")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
