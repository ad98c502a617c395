"""Does a quick RANSAC on a subsample's matches tell which pairs of panoramas to match?

    python lab/pair_geometry.py PANOS_DIR REPORT.json OUT.json

For every pair of the panoramas in PANOS_DIR (``*.jpg``): the mutual ratio-test matches among
N of each panorama's SIFT keypoints (those of the largest scale... see ``pick``), then COLMAP's
essential-matrix RANSAC on them (the posing's camera and threshold); the score is the number of
inliers. Ranked against the pairs a full `panogrf scene from-panoramas` run verified (its
poses_report.json): the rank of each verified pair among its photo's partners.
"""

import json
import sys
import time

import numpy as np
import torch
from pair_scores import detect_all, sub

from panogrf.app.poses import colmap
from panogrf.app.poses import features as ft


def ranks(score: np.ndarray, verified: list[tuple[int, int]]) -> list[int]:
    """Worst rank (1 = best) of each verified pair among either photo's partners."""
    out = []
    for i, j in verified:
        ri = int((score[i] > score[i, j]).sum()) + 1
        rj = int((score[j] > score[i, j]).sum()) + 1
        out.append(max(ri, rj))
    return out


def top_k_pairs(score: np.ndarray, k: int) -> set[tuple[int, int]]:
    """Each photo's k best-scoring partners, as pairs (i < j)."""
    out = set()
    for i in range(len(score)):
        s = score[i].copy()
        s[i] = -1
        for j in np.argsort(-s, kind="stable")[:k]:
            out.add((min(i, int(j)), max(i, int(j))))
    return out


def linked(pairs: list[tuple[int, int]], v: int) -> int:
    """Photos in the largest group the pairs link."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rows, cols = zip(*pairs, strict=True) if pairs else ((), ())
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(v, v))
    _, labels = connected_components(graph, directed=False)
    return int(np.bincount(labels).max())


def main() -> None:
    torch.set_num_threads(2)
    paths, feats = detect_all(sys.argv[1])
    names = [p.rsplit("/", 1)[-1] for p in paths]
    report = json.load(open(sys.argv[2]))
    verified = [(names.index(p["a"]), names.index(p["b"])) for p in report["pairs"] if p["ok"]]
    pycolmap = colmap.load_pycolmap()
    camera = colmap._camera(2048, 1024)
    opts = pycolmap.RANSACOptions()
    opts.max_error = 8.0
    opts.random_seed = 0
    opts.max_num_trials = 3000
    opts.min_num_trials = 200
    out = {"paths": names, "verified": verified}
    v = len(feats)
    for n in (2000, 4000):
        s = [sub(f, n) for f in feats]
        px = [colmap._pixels(camera, f.bearings) for f in s]
        t_match = t_geo = 0.0
        count = np.zeros((v, v), int)
        inl = np.zeros((v, v), int)
        for i in range(v):
            for j in range(i + 1, v):
                t0 = time.perf_counter()
                m = ft.match(s[i], s[j], 0.8)
                t1 = time.perf_counter()
                count[i, j] = count[j, i] = len(m)
                if len(m) >= 8:
                    r = pycolmap.estimate_essential_matrix(
                        px[i][m[:, 0]], px[j][m[:, 1]], camera, camera, opts
                    )
                    inl[i, j] = inl[j, i] = 0 if r is None else int(r["num_inliers"])
                t_geo += time.perf_counter() - t1
                t_match += t1 - t0
        rk = ranks(inl, verified)
        rc = ranks(count, verified)
        false = inl[np.triu_indices(v, 1)]
        vset = set(verified)
        false = [inl[i, j] for i in range(v) for j in range(i + 1, v) if (i, j) not in vset]
        weakest = min(inl[i, j] for i, j in verified)
        print(
            f"N={n}: match {t_match:.1f} s, RANSAC {t_geo:.1f} s; verified pairs' worst rank by "
            f"inliers {max(rk)} (median {np.median(rk):.0f}), by matches {max(rc)}; "
            f"inliers of verified min {weakest}, of others max {max(false)}, "
            f"others >= weakest: {sum(f >= weakest for f in false)}",
            flush=True,
        )
        print("   ranks by inliers", sorted(rk))
        for k in (3, 4, 5, 6, 8):
            chosen = top_k_pairs(inl, k)
            kept = [ij for ij in verified if ij in chosen]
            print(
                f"   top {k}: {len(chosen)} pairs, {len(kept)} of {len(verified)} verified, "
                f"photos linked {linked(kept, v)} (all verified: {linked(verified, v)})"
            )
        out[n] = {
            "matches": count.tolist(),
            "inliers": inl.tolist(),
            "ranks": rk,
            "seconds_match": t_match,
            "seconds_ransac": t_geo,
        }
    with open(sys.argv[3], "w") as f:
        json.dump(out, f)


if __name__ == "__main__":
    main()
