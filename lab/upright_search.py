"""Upright relative poses by exhaustive search: does it pose the pairs COLMAP cannot?

For each pair of panoramas of a real scene (folders with ``transforms.json``, OpenGL
camera-to-world, y up), SIFT matches as the product makes them; then every relative yaw and
heading of the second camera (1-degree grid, level baseline) is scored by the matches whose rays
meet in front of both cameras within ``--tol`` degrees of the epipolar plane (the product's
`panogrf.app.poses.upright` grid). The best
hypotheses are grown by guided matching and scored again. Printed per pair: the matches that
agree with the true geometry, the best hypothesis and its error against the truth, the runner-up.

    python lab/upright_search.py /work/realdata/zind_scenes/* data/real/m3d_00000007
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import cv2
import numpy as np

from panogrf.app.poses import features as ft
from panogrf.app.poses import upright
from panogrf.app.poses.geometry import skew


def rot_y(a: np.ndarray) -> np.ndarray:
    return upright._rot_y(a)


def residuals(xa: np.ndarray, db: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rays xa [M, 3] from the origin and db [M, 3] from centre c [1, 3] -> (sine of db's angle
    out of the epipolar plane [M], both depths positive [M])."""
    n = np.cross(c, xa)
    n /= np.linalg.norm(n, axis=-1, keepdims=True) + 1e-12
    res = np.abs((n * db).sum(-1))
    cr = np.cross(xa, db)
    den = (cr * cr).sum(-1) + 1e-12
    la = (np.cross(c, db) * cr).sum(-1) / den
    lb = (np.cross(c, xa) * cr).sum(-1) / den
    return res, (la > 0) & (lb > 0)


def peaks(score: np.ndarray, count: int, sep: int = 6) -> list[tuple[int, int, float]]:
    """The ``count`` best cells, each at least ``sep`` cells (circular) from a better one."""
    s = score.copy()
    out = []
    n_y, n_h = s.shape
    for _ in range(count):
        k = int(np.argmax(s))
        i, j = divmod(k, n_h)
        if s[i, j] <= 0:
            break
        out.append((i, j, float(s[i, j])))
        ii = np.arange(i - sep, i + sep + 1) % n_y
        jj = np.arange(j - sep, j + sep + 1) % n_h
        s[np.ix_(ii, jj)] = -1
    return out


def truth(c2w_a: np.ndarray, c2w_b: np.ndarray) -> tuple[float, np.ndarray]:
    """(yaw of b in a's frame (rad), unit direction of b's centre in a's frame)."""
    r = c2w_a[:3, :3].T @ c2w_b[:3, :3]
    yaw = math.atan2(r[0, 2], r[0, 0])
    c = c2w_a[:3, :3].T @ (c2w_b[:3, 3] - c2w_a[:3, 3])
    return yaw, c / np.linalg.norm(c)


def essential_gl(yaw: float, c: np.ndarray) -> np.ndarray:
    """E with b_b^T E b_a = 0 for b's rotation yaw and centre c in a's frame."""
    r_ab = rot_y(np.array([yaw]))[0]  # b -> a
    r_ba = r_ab.T
    t = -r_ba @ c  # a -> b translation
    t /= np.linalg.norm(t)
    return skew(t) @ r_ba


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    cos = float(a @ b) / np.linalg.norm(a) / np.linalg.norm(b)
    return math.degrees(math.acos(np.clip(cos, -1, 1)))


def count_consistent(fa, fb, m, yaw, c, tol):
    r = rot_y(np.array([yaw]))[0]
    res, front = residuals(fa.bearings[m[:, 0]], fb.bearings[m[:, 1]] @ r.T, c[None])
    return int(((res < math.sin(tol)) & front).sum())


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("scenes", nargs="+", type=Path)
    p.add_argument("--tol", type=float, default=1.0, help="degrees")
    p.add_argument("--peaks", type=int, default=5)
    p.add_argument("--width", type=int, default=2048)
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--ratio", type=float, default=0.8, help="Lowe's ratio of the matching")
    p.add_argument("--guided", action="store_true", help="grow each hypothesis by guided matching")
    a = p.parse_args()
    tol = math.radians(a.tol)
    band = math.radians(3 * 180 / 1024)  # the product's guided band, 3 px at 1024 columns
    rows = []
    for scene in a.scenes:
        meta = json.loads((scene / "transforms.json").read_text())
        frames = meta["frames"]
        imgs, poses = [], []
        for f in frames:
            img = cv2.cvtColor(cv2.imread(str(scene / f["file_path"])), cv2.COLOR_BGR2RGB)
            if img.shape[1] > a.width:
                img = cv2.resize(img, (a.width, a.width // 2), interpolation=cv2.INTER_AREA)
            imgs.append(img)
            poses.append(np.asarray(f["transform_matrix"], np.float64))
        feats = []
        for img in imgs:
            f = ft.detect(img)
            keep = f.bearings[:, 1] > -math.sin(math.radians(70))
            feats.append(ft.Features(f.bearings[keep], f.descriptors[keep]))
        for i in range(len(imgs)):
            for j in range(i + 1, len(imgs)):
                fa, fb = feats[i], feats[j]
                m = ft.match(fa, fb, a.ratio)
                yaw_t, c_t = truth(poses[i], poses[j])
                good = count_consistent(fa, fb, m, yaw_t, c_t, tol)
                score, _ = upright._grid(
                    fa.bearings[m[:, 0]], fb.bearings[m[:, 1]], upright.UprightConfig(tol_deg=a.tol)
                )
                yaws = heads = np.radians(np.arange(0.0, 360.0, 1.0))
                top = peaks(score, a.peaks, sep=20)
                cand = []
                for yi, hj, s in top:
                    yaw, hd = yaws[yi], heads[hj]
                    c = np.array([math.sin(hd), 0.0, -math.cos(hd)])
                    e = essential_gl(yaw, c)
                    g = ft.match_guided(fa, fb, e, band) if a.guided else m[:0]
                    gs = count_consistent(fa, fb, g, yaw, c, tol) if len(g) else 0
                    yerr = abs((math.degrees(yaw - yaw_t) + 180) % 360 - 180)
                    derr = angle_deg(c, c_t)
                    cand.append(
                        dict(score=s, guided=len(g), guided_ok=gs, yaw_err=yerr, dir_err=derr)
                    )
                e_t = essential_gl(yaw_t, c_t)
                g_t = ft.match_guided(fa, fb, e_t, band) if a.guided else m[:0]
                gt_ok = count_consistent(fa, fb, g_t, yaw_t, c_t, tol) if len(g_t) else 0
                elev = math.degrees(math.asin(c_t[1]))
                row = dict(scene=scene.name, pair=f"{i}-{j}", matches=len(m), true_consistent=good)
                row.update(guided_at_truth=gt_ok, elev_deg=elev, peaks=cand)
                rows.append(row)
                print(
                    f"{scene.name[-16:]:>16} {i}-{j} m={len(m):5d} true={good:4d} "
                    f"guided@truth={gt_ok:5d} | "
                    + " ".join(
                        f"[{c['score']:.0f}/{c['guided_ok']} "
                        f"y{c['yaw_err']:.1f} d{c['dir_err']:.1f}]"
                        for c in cand
                    ),
                    flush=True,
                )
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    sys.exit(main())
