"""Cold preparation against a warm load of the scene cache, on the bundled scene, on this CPU.

    python benchmarks/prepare_cache.py [--cold 3] [--warm 5] [--cli 3]
        [--out lab/results/prepare_cache.json]

What `panogrf render` (and `view`, `eval`, `bench`, `demo`) spends before its first pixel, in
one process with the shipped networks loaded once: read the scene folder, balance the
exposure, then `session.prepare_views` (the sources' depth estimated and refined for the
scene, the renderer's feature maps). Cold: into an empty cache folder (everything computed,
then written). Warm: the same again, the cache now there (read and checked). Two source sets:
every view (what `view`, `render --c2w` and `--camera-path` prepare) and views 0 and 2 (what
`render --target-frame 1` prepares). The median of ``--cold`` and ``--warm`` runs (cold runs
get a fresh folder each). Last, ``--cli`` runs of `panogrf render --c2w ... --json` in fresh
processes on the warm cache: their own ``prepare_s`` and the whole process's wall time
(Python, torch and the networks' import included). Prints a table last; writes JSON.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

C2W = "1 0 0 0.3 0 1 0 1.5 0 0 1 0 0 0 0 1"


def _prepare(scene_dir: Path, sources, cache_dir: Path, models) -> tuple[float, str]:
    """Seconds before the first pixel and the cache's status."""
    from panogrf.app.scene import session
    from panogrf.app.scene.folder import load_scene
    from panogrf.model.refine import PREPARE_REFINE
    from panogrf.renderer.methods import SourceViews

    start = time.perf_counter()
    data = load_scene(scene_dir, load_images=True).images
    idx = list(range(data.images.shape[0])) if sources is None else sources
    views = SourceViews(data.images[idx], data.c2w[idx], refine=PREPARE_REFINE)
    result = session.prepare_views(views, models, "panogrf", "fast", cache_dir)
    return time.perf_counter() - start, result.status


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cold", type=int, default=3, help="cold runs per case (median)")
    parser.add_argument("--warm", type=int, default=5, help="warm runs per case (median)")
    parser.add_argument("--cli", type=int, default=3, help="CLI renders on the warm cache")
    parser.add_argument("--out", type=Path, default=Path("lab/results/prepare_cache.json"))
    args = parser.parse_args()

    import torch

    from panogrf.app.scene import session
    from panogrf.assets import path as asset_path

    scene = asset_path("demo")
    models = session.default_models()
    models.estimator("full")
    models.renderer("panogrf")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, sources in (("every view (view, render --c2w)", None), ("views 0,2", [0, 2])):
            cold, warm = [], []
            for i in range(args.cold):
                cache = Path(tmp) / f"{label[:5]}_{i}"
                seconds, status = _prepare(scene, sources, cache, models)
                assert status == "built", status
                cold.append(seconds)
                print(f"{label}: cold {seconds:.2f} s", flush=True)
            for _ in range(args.warm):
                seconds, status = _prepare(scene, sources, cache, models)
                assert status == "loaded", status
                warm.append(seconds)
                print(f"{label}: warm {seconds:.3f} s", flush=True)
            rows.append(
                {
                    "sources": label,
                    "cold_s": cold,
                    "warm_s": warm,
                    "cold_median_s": statistics.median(cold),
                    "warm_median_s": statistics.median(warm),
                }
            )
        cli = []
        cache = Path(tmp) / "every_0"
        panogrf = Path(sys.executable).with_name("panogrf")
        for i in range(args.cli):
            out = Path(tmp) / f"r{i}.png"
            start = time.perf_counter()
            done = subprocess.run(
                [str(panogrf), "render", str(scene), "--out", str(out), "--c2w", C2W]
                + ["--json", "--quiet", "--cache-dir", str(cache)],
                capture_output=True,
                text=True,
                check=True,
            )
            wall = time.perf_counter() - start
            summary = json.loads(done.stdout)
            assert summary["cache"]["status"] == "loaded", summary
            cli.append({"prepare_s": summary["prepare_s"], "wall_s": wall})
            print(
                f"CLI render on the warm cache: prepared in {summary['prepare_s']:.3f} s, "
                f"process {wall:.2f} s",
                flush=True,
            )
    report = {
        "what": "seconds before the first pixel on the bundled scene (256 x 512, 3 views): "
        "cold preparation (depth, per-scene refinement, feature maps, cache written) against a "
        "warm load of the scene cache; CLI renders on the warm cache in fresh processes",
        "repeats": {"cold": args.cold, "warm": args.warm, "cli": args.cli},
        "rows": rows,
        "cli_warm": cli,
        "cli_warm_prepare_median_s": statistics.median(c["prepare_s"] for c in cli)
        if cli
        else None,
        "cli_warm_wall_median_s": statistics.median(c["wall_s"] for c in cli) if cli else None,
        "machine": f"{platform.machine()}, {torch.get_num_threads()} torch threads, CPU",
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {args.out}")
    head = f"{'sources':<34} {'cold median s':>14} {'warm median s':>14} {'speed-up':>9}"
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(
            f"{r['sources']:<34} {r['cold_median_s']:>14.2f} {r['warm_median_s']:>14.3f} "
            f"{r['cold_median_s'] / r['warm_median_s']:>8.0f}x"
        )
    if cli:
        lines.append(
            f"{'CLI render --c2w, warm: prepare_s':<34} {'':>14} "
            f"{report['cli_warm_prepare_median_s']:>14.3f}"
        )
        lines.append(
            f"{'CLI render --c2w, warm: process':<34} {'':>14} "
            f"{report['cli_warm_wall_median_s']:>14.2f}"
        )
    print("\n".join(lines))


if __name__ == "__main__":
    main()
