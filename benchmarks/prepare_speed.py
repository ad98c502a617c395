"""A scene's preparation (depth, per-scene refinement, feature maps) against an earlier
revision's, on this machine's CPU, the two run one after the other in the same run.

    python benchmarks/prepare_speed.py --baseline-rev 665c407 --data data/loo_lit \
        --views 3 --repeats 3 --out lab/results/prepare_speed.json

The tree of ``--baseline-rev`` (``git archive``, its own weights) and this one each prepare the
first panoramas (``--views``) of the first scenes of ``--data`` in a process of their own: the
shipped networks loaded first (not timed), then each scene's `SourceViews` with the shipped
refinement until the PanoGRF feature maps exist (timed; the first scene of a process is its
cold start). The processes alternate, ``--repeats`` times; the table gives the median seconds,
and their ratio. The table is printed last.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: Runs inside each tree's process: argv = data folder, views, scenes, threads.
DRIVER = r"""
import json, sys, time
from pathlib import Path
import torch
torch.set_num_threads(int(sys.argv[4]))
from panogrf.app.scene import session
from panogrf.app.scene.folder import load_scene
from panogrf.model.refine import PREPARE_REFINE
from panogrf.renderer.methods import SourceViews
try:
    models = session.default_models("cpu")
except TypeError:  # older trees: no device
    models = session.default_models()
models.estimator("full"), models.renderer("panogrf")
data = Path(sys.argv[1])
index = json.loads((data / "dataset.json").read_text())
times = []
for entry in index["scenes"][: int(sys.argv[3])]:
    scene = load_scene(data / entry["folder"], load_images=True).images
    pick = list(range(int(sys.argv[2])))
    start = time.perf_counter()
    views = SourceViews(scene.images[pick], scene.c2w[pick], refine=PREPARE_REFINE)
    views.cache_for("panogrf", models)
    times.append(time.perf_counter() - start)
print("TIMES", json.dumps(times))
"""


def tree_at(rev: str) -> Path:
    """The repository at ``rev`` unpacked as the package ``panogrf`` in a new folder."""
    top = Path(tempfile.mkdtemp(prefix="prepare_speed_"))
    archive = top / "tree.tar"
    subprocess.run(["git", "-C", str(ROOT), "archive", "-o", str(archive), rev], check=True)
    with tarfile.open(archive) as tar:
        tar.extractall(top / "panogrf", filter="data")
    return top


def run(path: Path, data: Path, views: int, scenes: int, threads: int) -> list[float]:
    env = os.environ | {"PYTHONPATH": str(path)}
    cmd = [sys.executable, "-c", DRIVER, str(data.resolve()), str(views), str(scenes), str(threads)]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=path)
    line = [x for x in out.stdout.splitlines() if x.startswith("TIMES ")]
    if out.returncode or not line:
        raise SystemExit(f"{path}: the preparation failed:\n{out.stderr[-2000:]}")
    return json.loads(line[0][6:])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--baseline-rev", required=True)
    p.add_argument("--data", type=Path, required=True, help="a dataset folder")
    p.add_argument("--views", type=int, default=3)
    p.add_argument("--scenes", type=int, default=2)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("lab/results/prepare_speed.json"))
    args = p.parse_args()
    trees = {"before": tree_at(args.baseline_rev), "now": ROOT.parent}
    if ROOT.name != "panogrf":  # this checkout imported as `panogrf` from a folder beside it
        trees["now"] = Path(tempfile.mkdtemp(prefix="prepare_now_"))
        (trees["now"] / "panogrf").symlink_to(ROOT)
    runs: dict[str, list[list[float]]] = {"before": [], "now": []}
    for i in range(args.repeats):
        for name, path in trees.items():
            runs[name].append(run(path, args.data, args.views, args.scenes, args.threads))
            print(f"repeat {i}: {name} {runs[name][-1]}", flush=True)
    cold = {k: statistics.median(r[0] for r in v) for k, v in runs.items()}
    warm = {k: statistics.median(t for r in v for t in r[1:]) for k, v in runs.items()}
    result = {
        "what": "scene preparation (depth, refinement, feature maps), this tree against a rev",
        "baseline_rev": args.baseline_rev,
        "views": args.views,
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, {args.threads} threads, CPU",
        "runs": runs,
        "cold_median_s": cold,
        "warm_median_s": warm,
    }
    args.out.write_text(json.dumps(result, indent=1))
    print(f"\n{'':22} | {args.baseline_rev:>9} | {'now':>7} | now/before")
    for label, med in (("first scene (cold)", cold), ("later scenes (warm)", warm)):
        ratio = med["now"] / med["before"]
        print(f"{label:22} | {med['before']:9.2f} | {med['now']:7.2f} | {ratio:.2f}")


if __name__ == "__main__":
    main()
