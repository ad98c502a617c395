"""Speed and peak memory of depth estimation for a two-view 512 x 1024 scene, on this CPU.

    python benchmarks/depth_speed.py [--out lab/results/depth_speed.json]

A two-view scene is rendered by the synthetic generator (test split, a seed of its own) into a
temporary folder. Each mode then runs in a fresh subprocess, so its peak resident memory is its
own: load the networks, then five times end to end (read the scene from disk, estimate depth
for both views at 512 x 1024, write the 16-bit depth PNGs); the median and the spread are
reported. Targets (issue): at most 3 s end to end, at most 3 GB peak.
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPEATS = 5


def _child(scene: Path, mode: str) -> dict:
    import torch

    from panogrf.app.files.images import write_depth
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.weights.networks import NETWORKS, load_depth_estimator

    t0 = time.perf_counter()
    estimator = load_depth_estimator(NETWORKS[mode])
    load_s = time.perf_counter() - t0
    times, net_times = [], []
    with tempfile.TemporaryDirectory() as out:
        for _ in range(REPEATS):
            t0 = time.perf_counter()
            s = load_scene(scene, load_images=True)
            t1 = time.perf_counter()
            est = estimator(s.images.images, s.images.c2w, mode)
            t2 = time.perf_counter()
            for i, frame in enumerate(s.frames):
                write_depth(Path(out) / f"{frame.name}.png", est.depth[i, 0].numpy())
            times.append(time.perf_counter() - t0)
            net_times.append(t2 - t1)
    return {
        "mode": mode,
        "end_to_end_s": statistics.median(times),
        "end_to_end_all_s": [round(t, 3) for t in times],
        "network_s": statistics.median(net_times),
        "weights_load_s": load_s,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "threads": torch.get_num_threads(),
        "size": list(s.images.images.shape[-2:]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("lab/results/depth_speed.json"))
    parser.add_argument("--child", nargs=2, metavar=("SCENE", "MODE"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(_child(Path(args.child[0]), args.child[1])))
        return

    from panogrf.app.scene.folder import load_scene, write_scene
    from panogrf.app.synth.make import MakeConfig, make_dataset

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        make_dataset(
            MakeConfig(out=Path(tmp), split="test", count=1, height=512, baselines=(1.0,), seed=31),
            progress=False,
        )
        triplet = load_scene(Path(tmp) / "test_00000", load_images=True)
        scene = Path(tmp) / "pair"
        keep = [0, 2]  # first and last: a 1.0 m pair
        write_scene(
            scene,
            triplet.images.c2w[keep],
            triplet.images.images[keep],
            triplet.images.depths[keep],
            names=[triplet.frames[i].name for i in keep],
        )
        for mode in ("mono", "mvs", "full"):
            res = subprocess.run(
                [sys.executable, __file__, "--child", str(scene), mode],
                capture_output=True,
                text=True,
                check=True,
            )
            rows.append(json.loads(res.stdout.strip().splitlines()[-1]))
    report = {
        "what": "two-view 512x1024 scene: read, estimate depth for both views, write PNGs",
        "repeats": REPEATS,
        "machine": f"{platform.machine()} CPU, {rows[0]['threads']} torch threads",
        "targets": {"end_to_end_s": 3.0, "peak_rss_mb": 3072},
        "rows": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))
    print(f"depth speed, two views at 512x1024, median of {REPEATS} ({report['machine']})")
    print(f"{'mode':>5} {'end to end s':>13} {'network s':>10} {'peak RSS MB':>12}")
    for r in rows:
        e2e, net, rss = r["end_to_end_s"], r["network_s"], r["peak_rss_mb"]
        print(f"{r['mode']:>5} {e2e:13.3f} {net:10.3f} {rss:12.0f}")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
