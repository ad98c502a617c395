"""Can a bag of visual words (tf-idf) tell which pairs of a home's photos to match?

    python lab/pair_words.py PANOS_DIR REPORT.json

The SIFT keypoints of every panorama in PANOS_DIR (``*.jpg``, as `panogrf.app.poses.colmap`
detects them) quantised to 256, 1024 and 4096 words (k-means on 50,000 of them, 10 rounds),
each photo a tf-idf vector, pairs ranked by cosine similarity; printed: for every pair that
a full `panogrf scene from-panoramas` run verified (REPORT.json, its poses_report.json), its
rank among its photo's partners (the better of its two photos).
"""

import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from pair_scores import detect_all  # noqa: E402

torch.set_num_threads(2)
paths, feats = detect_all(sys.argv[1])
r = json.load(open(sys.argv[2]))
names = [p.split("/")[-1] for p in paths]
idx = {n: i for i, n in enumerate(names)}
ok = [(idx[p["a"]], idx[p["b"]], p["inliers"]) for p in r["pairs"] if p["ok"]]
V = len(feats)


def kmeans(x, k, iters, gen):
    c = x[torch.randperm(len(x), generator=gen)[:k]].clone()
    for _ in range(iters):
        d = (x * x).sum(1, keepdim=True) - 2 * x @ c.T + (c * c).sum(1)
        a = d.argmin(1)
        s = torch.zeros_like(c).index_add_(0, a, x)
        n = torch.bincount(a, minlength=k).float()
        c = torch.where(n[:, None] > 0, s / n.clamp(min=1)[:, None], c)
    return c


for words in (256, 1024, 4096):
    t0 = time.time()
    gen = torch.Generator().manual_seed(0)
    allx = torch.from_numpy(np.concatenate([f.descriptors for f in feats])).float()
    sample = allx[torch.randperm(len(allx), generator=gen)[:50000]]
    c = kmeans(sample, words, 10, gen)
    hist = np.zeros((V, words))
    for i, f in enumerate(feats):
        x = torch.from_numpy(f.descriptors).float()
        a = torch.cat(
            [
                ((xb * xb).sum(1, keepdim=True) - 2 * xb @ c.T + (c * c).sum(1)).argmin(1)
                for xb in x.split(4096)
            ]
        )
        hist[i] = np.bincount(a.numpy(), minlength=words)
    df = (hist > 0).sum(0)
    idf = np.log(V / np.maximum(df, 1))
    tf = hist / hist.sum(1, keepdims=True)
    vec = tf * idf
    vec /= np.linalg.norm(vec, axis=1, keepdims=True)
    sim = vec @ vec.T
    np.fill_diagonal(sim, -1)
    rank = np.argsort(np.argsort(-sim, axis=1, kind="stable"), axis=1) + 1
    best = sorted((min(rank[i, j], rank[j, i]), inl) for i, j, inl in ok)
    print(
        words,
        "words",
        f"{time.time() - t0:.1f} s",
        "best-side ranks of verified pairs:",
        [b[0] for b in best],
        flush=True,
    )
