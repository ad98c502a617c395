"""The per-scene depth refinement against an earlier revision's, side by side in one process.

    python benchmarks/refine_speed.py --baseline-rev 4cbd1b4 --views 2,3 --repeats 3 \
        --out lab/results/refine_speed.json

``model/refine.py`` of ``--baseline-rev`` (read with ``git show``) and the working tree's run
the shipped refinement (`PREPARE_REFINE`) on the bundled scene's first V views (the depth: its
true depth at 128 rows, 10 % too far, so that there is something to refine), interleaved,
``--repeats`` times each; the table gives the median seconds, their ratio and the largest
difference of the two results (0: the same to the last bit). The table is printed last.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parent.parent


def module_at(rev: str):
    """``model/refine.py`` as it was at git revision ``rev``, imported as a module of its own."""
    text = subprocess.run(
        ["git", "-C", str(ROOT), "show", f"{rev}:model/refine.py"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    path = Path(tempfile.mkdtemp(prefix="refine_")) / "refine_baseline.py"
    path.write_text(text)
    spec = importlib.util.spec_from_file_location("refine_baseline", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["refine_baseline"] = mod
    spec.loader.exec_module(mod)
    return mod


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--baseline-rev", required=True)
    parser.add_argument("--views", default="2,3", help="scene sizes to time (2 or 3 views)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("lab/results/refine_speed.json"))
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    from panogrf.app.files.atomic import write_json_atomic
    from panogrf.app.scene.folder import load_scene
    from panogrf.assets import path as asset_path
    from panogrf.model import refine as now

    before = module_at(args.baseline_rev)
    scene = load_scene(asset_path("demo"), load_images=True).images
    rows = []
    for v in (int(x) for x in args.views.split(",")):
        pick = [0, 2] if v == 2 else list(range(v))
        images, c2w = scene.images[pick], scene.c2w[pick]
        depth = torch.nn.functional.interpolate(scene.depths[pick], size=(128, 256), mode="nearest")
        depth = depth.clamp(0.3, 10.0) * 1.1
        sources = [[j for j in range(v) if j != i] for i in range(v)]
        times: dict[str, list[float]] = {"before": [], "now": []}
        outs = {}
        for _ in range(args.repeats):
            for name, mod in (("before", before), ("now", now)):
                start = time.perf_counter()
                outs[name] = mod.refine_depth(images, c2w, depth, sources, now.PREPARE_REFINE)
                times[name].append(time.perf_counter() - start)
        med = {k: statistics.median(t) for k, t in times.items()}
        rows.append(
            {
                "views": v,
                "before_s": med["before"],
                "now_s": med["now"],
                "ratio": med["now"] / med["before"],
                "max_abs_diff_m": float((outs["now"] - outs["before"]).abs().max()),
                "runs": times,
            }
        )
    result = {
        "what": "per-scene depth refinement (PREPARE_REFINE), this tree against --baseline-rev",
        "baseline_rev": args.baseline_rev,
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, {args.threads} threads, CPU",
        "rows": rows,
    }
    write_json_atomic(args.out, result)
    print(f"{'views':>5} {'before s':>9} {'now s':>7} {'now/before':>10} {'max diff m':>10}")
    for r in rows:
        print(
            f"{r['views']:>5} {r['before_s']:9.2f} {r['now_s']:7.2f} {r['ratio']:10.2f} "
            f"{r['max_abs_diff_m']:10.2g}"
        )


if __name__ == "__main__":
    main()
