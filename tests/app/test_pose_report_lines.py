"""The printed report of a posing stays readable for a home of many photos: every posed pair,
the pairs that share nothing counted, each view's nearest photo instead of every distance."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from panogrf.app.commands.scene_poses_report import _baselines, pose_report, shown_names
from panogrf.app.poses.colmap_report import ColmapEstimate, PairReport, ViewReport


def _estimate(views: int, ok: set[tuple[int, int]]) -> ColmapEstimate:
    pairs = [
        PairReport(
            i,
            j,
            matches=100,
            inliers=500 if (i, j) in ok else 0,
            ok=(i, j) in ok,
            reason="" if (i, j) in ok else "no consistent geometry",
        )  # fmt: skip
        for i in range(views)
        for j in range(i + 1, views)
    ]
    return ColmapEstimate(
        c2w=np.tile(np.eye(4), (views, 1, 1)),
        registered=np.ones(views, bool),
        points=np.zeros((0, 3)),
        pairs=pairs,
        views=[ViewReport(k, True, note="registered") for k in range(views)],
    )


def test_a_home_of_many_photos_prints_its_posed_pairs_and_counts_the_rest():
    files = [Path(f"p{k:02d}.jpg") for k in range(12)]
    est = _estimate(12, {(0, 1), (1, 2), (5, 9)})
    odd = next(p for p in est.pairs if (p.i, p.j) == (0, 4))  # many inliers, yet failed
    odd.inliers, odd.reason = 95, "its place in the reconstruction disagrees with its geometry"
    lines = pose_report(files, est)
    assert [line for line in lines if "FAILED" in line] == [
        "  p00.jpg - p04.jpg: 100 matches; FAILED: its place in the reconstruction disagrees "
        "with its geometry"
    ]
    assert sum(": 100 matches; ok" in line for line in lines) == 3
    assert "  62 other pairs: fewer than 30 matches agree" in "\n".join(lines)  # 66, 3 posed


def test_a_triplet_prints_every_failed_pair():
    files = [Path(f"p{k}.jpg") for k in range(3)]
    lines = pose_report(files, _estimate(3, {(0, 1)}))
    assert sum("FAILED: no consistent geometry" in line for line in lines) == 2
    assert not any("other pairs" in line for line in lines)


def test_baselines_of_a_few_views_each_pair_and_of_many_each_views_nearest():
    c2w = np.tile(np.eye(4), (3, 1, 1))
    c2w[:, 0, 3] = [0.0, 1.0, 3.0]
    assert _baselines(c2w) == "0-1 1.000, 0-2 3.000, 1-2 2.000"
    many = np.tile(np.eye(4), (8, 1, 1))
    many[:, 0, 3] = [0.0, 1.0, 3.0, 3.5, 7.5, 8.0, 9.0, 11.0]
    # nearest: 1, 1, 0.5, 0.5, 0.5, 0.5, 1, 2
    assert _baselines(many) == (
        "to each view's nearest min 0.500, median 0.750, max 2.000; largest pairwise 11.000"
    )


def test_photos_of_one_name_from_two_folders_are_told_apart():
    files = [Path("/home/u/day1/pano.jpg"), Path("/home/u/day2/pano.jpg"), Path("/x/other.jpg")]
    assert shown_names(files) == ["day1/pano.jpg", "day2/pano.jpg", "x/other.jpg"]
    assert shown_names([Path("a/p.jpg"), Path("a/q.jpg")]) == ["p.jpg", "q.jpg"]
    lines = pose_report(files, _estimate(3, {(0, 1), (1, 2)}))
    assert "  day1/pano.jpg - day2/pano.jpg: 100 matches; ok" in "\n".join(lines)
