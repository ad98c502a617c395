"""Depth accuracy of the shipped networks on the held-out synthetic test split.

    python benchmarks/depth_accuracy.py --data data/test \
        --out lab/results/depth_accuracy.json

Test scenes are triplets on a line; the first and last views form a pair at the scene's
baseline, each taking the other as its source (two reference/source pairs per scene). Modes:
``mono`` (monocular only), ``mvs`` (the MVS-only network: N_mono = 0, N_uni = 64, no mono
input, trained separately) and ``full`` (mono-guided MVS, N_mono = 5, N_uni = 59). Depth is
estimated at the networks' working resolution and compared, upsampled, with the ground truth at
the dataset's resolution, on pixels with 0 < gt <= d_max (10 m). Per-pair metrics are averaged.

The N_mono sweep re-runs the *full* network with N_mono in (0, 1, 3, 5, 9) and N_uni = 64 - N_mono
(the same D = 64, so the same weights load): an inference-time sweep of one trained model, not
five trained models as in the paper's supplementary table.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import subprocess
import time
from pathlib import Path

import numpy as np
import torch

from panogrf.app.train.data import load_triplets
from panogrf.app.weights.networks import load_depth_estimator
from panogrf.model.depth import DepthEstimator
from panogrf.model.metrics import depth_metrics
from panogrf.model.mvs import MVSNet

KEYS = ("l1", "rmse", "ws_l1", "ws_rmse")


def evaluate(estimator: DepthEstimator, data, mode: str, baselines: list[float]) -> dict:
    """Mean metrics per baseline for one mode: {baseline: {metric: value, "pairs": n}}."""
    per_baseline: dict[float, list] = {b: [] for b in baselines}
    d_max = estimator.d_max
    for i in range(len(data)):
        b = round(float(data.baselines[i]), 2)
        if b not in per_baseline:
            continue
        views = [0, 2]
        images = data.images[i, views].float() / 255.0
        c2w = data.c2w[i, views]
        est = estimator(images, c2w, mode)
        for k, v in enumerate(views):
            gt = data.depths[i, v]
            mask = (gt > 0) & (gt <= d_max)
            m = depth_metrics(est.depth[k, 0], gt, mask)
            per_baseline[b].append([getattr(m, key) for key in KEYS])
    out = {}
    for b, rows in per_baseline.items():
        if rows:
            mean = np.mean(np.array(rows), axis=0)
            out[str(b)] = {key: float(x) for key, x in zip(KEYS, mean, strict=True)} | {
                "pairs": len(rows)
            }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=Path("data/test"))
    parser.add_argument("--out", type=Path, default=Path("lab/results/depth_accuracy.json"))
    parser.add_argument("--baselines", default="0.5,1.0,1.5,2.0")
    parser.add_argument("--sweep", default="0,1,3,5,9", help="N_mono values at 1.0 m")
    parser.add_argument("--threads", type=int, default=0)
    parser.add_argument("--limit", type=int, default=0, help="first N scenes per baseline")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    baselines = [float(b) for b in args.baselines.split(",")]
    data = load_triplets(args.data, height=_native_height(args.data))
    if args.limit:
        keep = [
            i
            for b in baselines
            for i in [j for j in range(len(data)) if round(float(data.baselines[j]), 2) == b][
                : args.limit
            ]
        ]
        data = data.subset(sorted(keep))
    estimator = load_depth_estimator(("full", "mvs"))
    start = time.perf_counter()
    results = {mode: evaluate(estimator, data, mode, baselines) for mode in ("mono", "mvs", "full")}
    # Round 2's full mode: the mono-guided network and the sweep alone.
    results["full_no_fusion"] = evaluate(estimator.configured(fuse=False), data, "full", baselines)

    full_net = estimator.mvs["full"]
    sweep = {}
    for n_mono in (int(x) for x in args.sweep.split(",") if x):
        cfg = dataclasses.replace(full_net.config, n_mono=n_mono, n_uni=64 - n_mono)
        net = MVSNet(cfg)
        net.load_state_dict(full_net.state_dict())
        swept = DepthEstimator(estimator.mono, {"full": net.eval()}, estimator.config)
        sweep[str(n_mono)] = evaluate(swept, data, "full", [1.0]).get("1.0")
    seconds = time.perf_counter() - start

    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    report = {
        "what": "spherical depth error (metres) on the synthetic test split, mean over pairs",
        "data": str(args.data),
        "resolution_gt": list(data.depths.shape[-2:]),
        "working_resolution": [estimator.working_height, 2 * estimator.working_height],
        "valid": f"0 < gt <= {estimator.d_max} m",
        "results": results,
        "n_mono_sweep_1.0m": sweep,
        "n_mono_sweep_note": (
            "one trained full model evaluated with N_mono in the list, N_uni = 64 - N_mono"
        ),
        "machine": f"{platform.machine()}, {torch.get_num_threads()} torch threads, CPU",
        "seconds": round(seconds, 1),
        "commit": commit.stdout.strip(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))

    print(f"depth on {args.data} ({len(data)} scenes), GT {tuple(data.depths.shape[-2:])}, metres")
    header = f"{'baseline':>8} {'mode':>14} {'pairs':>5} " + " ".join(f"{k:>8}" for k in KEYS)
    print(header)
    for b in baselines:
        for mode in ("mono", "mvs", "full", "full_no_fusion"):
            r = results[mode].get(str(b))
            if r:
                vals = " ".join(f"{r[k]:8.4f}" for k in KEYS)
                print(f"{b:8.1f} {mode:>14} {r['pairs']:5d} {vals}")
    print("N_mono sweep at 1.0 m (full network, N_uni = 64 - N_mono):")
    for n, r in sweep.items():
        if r:
            print(f"{'N_mono':>8} {n:>5} {r['pairs']:5d} " + " ".join(f"{r[k]:8.4f}" for k in KEYS))
    print(f"wrote {args.out} ({seconds:.0f} s)")


def _native_height(root: Path) -> int:
    index = json.loads((root / "dataset.json").read_text())
    return int(index["height"])


if __name__ == "__main__":
    main()
