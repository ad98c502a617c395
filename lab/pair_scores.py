"""Can a cheap match of a subsample of each panorama's keypoints tell which pairs to match?

    python lab/pair_scores.py PANOS_DIR OUT.json

For every pair of the panoramas in PANOS_DIR (``*.jpg``): the number of mutual ratio-test
matches among 1000, 2000 and 4000 of each panorama's SIFT keypoints (every n-th, as
`panogrf.app.poses.colmap` detects them), and the time; compared with the pairs a full
`panogrf scene from-panoramas` run verified (its poses_report.json) in `lab/analysis.md`.
"""

import glob
import json
import math
import sys
import time

import numpy as np
import torch

from panogrf.app.files.images import read_rgb
from panogrf.app.poses import features as ft


def detect_all(folder: str) -> tuple[list[str], list[ft.Features]]:
    """The ``*.jpg`` panoramas of ``folder`` and their SIFT features as the posing detects
    them (keypoints more than 70 degrees below the horizon dropped)."""
    paths = sorted(glob.glob(f"{folder}/*.jpg"))
    floor = -math.sin(math.radians(70.0))
    t0 = time.time()
    feats = []
    for p in paths:
        f = ft.detect(read_rgb(p))
        keep = f.bearings[:, 1] > floor
        feats.append(ft.Features(f.bearings[keep], f.descriptors[keep]))
    print("features", time.time() - t0, [len(f.descriptors) for f in feats][:5], flush=True)
    return paths, feats


def sub(f, n):
    idx = np.linspace(0, len(f.descriptors) - 1, min(n, len(f.descriptors))).astype(int)
    return ft.Features(f.bearings[idx], f.descriptors[idx])


def main() -> None:
    torch.set_num_threads(2)
    paths, feats = detect_all(sys.argv[1])
    out = {}
    for n in (1000, 2000, 4000):
        s = [sub(f, n) for f in feats]
        t0 = time.time()
        v = len(s)
        score = np.zeros((v, v), int)
        for i in range(v):
            for j in range(i + 1, v):
                score[i, j] = score[j, i] = len(ft.match(s[i], s[j], 0.8))
        print(n, "scores in", time.time() - t0)
        out[n] = score.tolist()
    t0 = time.time()
    m = ft.match(feats[0], feats[1], 0.8)
    print("one full pair", time.time() - t0, len(m))
    with open(sys.argv[2], "w") as f:
        json.dump({"paths": paths, "scores": out}, f)


if __name__ == "__main__":
    main()
