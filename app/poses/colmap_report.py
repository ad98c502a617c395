"""The poses and the report of COLMAP's reconstruction (`panogrf.app.poses.colmap`).

`_collect` takes the reconstruction that registers most panoramas and keeps a panorama only
where enough points place it and one of its pairs agrees with that pair's own verified
two-view geometry (`_check_pairs`); `_two_view` poses the only pair, or the best one when
COLMAP's mappers build nothing, from its verified relative pose alone. Both report every pair
and every panorama (`PairReport`, `ViewReport`) in a `ColmapEstimate`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from panogrf.app.poses import CV_TO_GL
from panogrf.app.poses import geometry as geo

if TYPE_CHECKING:
    from panogrf.app.poses.colmap import ColmapConfig


#: Median angle (degrees) by which a verified pair's matches miss a turn alone, below which the
#: two were taken from one spot: a step of 0.1 m in a small room already gives about 2 degrees.
#: Or half a pixel at the equator, if that is more: a copy of a 512-column photo saved again
#: with fewer colours moves its keypoints by 0.2 degrees.
NO_PARALLAX_DEG = 0.2
NO_PARALLAX_PX = 0.5


@dataclass
class PairReport:
    """One pair of panoramas."""

    i: int
    j: int
    matches: int = 0
    """Putative matches (pooled, then grown along the verified epipolar planes)."""
    inliers: int = 0
    """Matches that passed COLMAP's geometric verification."""
    shared_points: int = 0
    """Points of the reconstruction seen by both panoramas."""
    residual_deg: float | None = None
    """Median reprojection residual of those points (degrees; None: no shared points)."""
    ok: bool = False
    reason: str = ""
    level_search: tuple[int, int] | None = None
    """Where COLMAP could not verify the pooled matches and the search for level cameras
    seeded the guided matching: (supporting matches at its peak, the best support elsewhere)."""


@dataclass
class ViewReport:
    index: int
    registered: bool = False
    points: int = 0
    residual_deg: float | None = None
    note: str = ""


@dataclass
class ColmapEstimate:
    """Poses of the registered panoramas and the evidence behind them."""

    c2w: np.ndarray
    """[V, 4, 4] camera-to-world (OpenGL), COLMAP's world frame; NaN for unregistered views."""
    registered: np.ndarray
    """[V] bool."""
    points: np.ndarray
    """[P, 3] the reconstruction's points, same frame."""
    pairs: list[PairReport] = field(default_factory=list)
    views: list[ViewReport] = field(default_factory=list)
    residual_deg: float | None = None
    """Median reprojection residual over all observations (degrees)."""
    mapper: str = ""
    """Which of COLMAP's mappers gave the poses."""
    seconds: float = 0.0

    @property
    def view_notes(self) -> list[str]:
        return [v.note for v in self.views]


def _two_view(db_path, image_ids, feats, counts, cfg: ColmapConfig, width: int, pair_ij=(0, 1)):
    """One pair of the panoramas (the only pair, or the best one when COLMAP's mappers, which
    want a graph of pairs, build nothing): COLMAP's verified relative pose, its inliers
    triangulated, and both poses refined together on angular residuals. The other panoramas
    are reported as not registered."""
    from panogrf.app.poses.colmap import load_pycolmap

    pycolmap = load_pycolmap()

    v_count = len(image_ids)
    i, j = pair_ij
    a, b = image_ids[i], image_ids[j]
    matches, inliers = counts[(i, j)]
    pairs = [
        PairReport(x, y, *counts.get((x, y), (0, 0)))
        for x in range(v_count)
        for y in range(x + 1, v_count)
    ]
    pair = next(p for p in pairs if (p.i, p.j) == (i, j))
    for p in pairs:
        if p is not pair:
            p.reason = (
                f"{p.inliers} of {p.matches} matches agree on a geometry: too little overlap "
                "or texture, or not consistent with the rest"
            )
    every = [ViewReport(k) for k in range(v_count)]
    for v in every:
        if v.index not in (i, j):
            v.note = "not registered: no pair links it to the posed pair"
    views = [every[i], every[j]]
    c2w = np.full((v_count, 4, 4), np.nan)
    registered = np.zeros(v_count, bool)
    est = ColmapEstimate(c2w, registered, np.zeros((0, 3)), pairs, every, None, "two-view")
    tvg = None
    with pycolmap.Database.open(db_path) as db:
        if db.exists_two_view_geometry(a, b):
            tvg = db.read_two_view_geometry(a, b)
    if tvg is None or inliers < cfg.min_pair_inliers:
        pair.reason = (
            f"{inliers} of {matches} matches agree on a geometry (< {cfg.min_pair_inliers}): "
            "too little overlap or texture between these two"
        )
        for v in views:
            v.note = f"not registered: {inliers} verified matches with the other panorama"
        return est
    m = np.asarray(tvg.inlier_matches)
    pose = tvg.cam2_from_cam1
    if pose is None:  # e.g. one photo upside down or mirrored: no camera motion fits
        pair.reason = (
            f"{inliers} matches agree on a geometry, but no camera motion fits it: is one "
            "photo upside down or mirrored?"
        )
        for v in views:
            v.note = "not registered: no camera motion fits its matches with the other panorama"
        return est
    rot_cv = np.asarray(pose.rotation.matrix())
    t_cv = np.asarray(pose.translation).reshape(3)
    # OpenGL camera frames: x_gl = F x_cv on both sides.
    rot, t = CV_TO_GL @ rot_cv @ CV_TO_GL, CV_TO_GL @ t_cv
    t = t / max(np.linalg.norm(t), 1e-12)
    b1, b2 = feats[i].bearings[m[:, 0]], feats[j].bearings[m[:, 1]]
    # The same spot twice (a turned or re-saved copy): a turn alone explains the matches. The
    # turn that fits them best, not COLMAP's, whose rotation is ill-posed without a baseline.
    u, _, vt = np.linalg.svd(b2.T @ b1)
    turn = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt  # b2 ~ turn b1
    off = float(np.median(np.degrees(np.arccos(np.clip(((b1 @ turn.T) * b2).sum(1), -1, 1)))))
    if off < max(NO_PARALLAX_DEG, NO_PARALLAX_PX * 360.0 / width):
        pair.reason = (
            f"no parallax: {len(m)} verified matches agree with a turn alone (median "
            f"{off:.3f} deg off it): taken from one spot"
        )
        for v in views:
            v.note = "not registered: no parallax with the other panorama"
        return est
    dist, pts = geo.triangulate_pair(rot, t, b1, b2)
    front = (dist > 0).all(1)
    if front.sum() < cfg.min_pair_inliers:
        pair.reason = f"only {int(front.sum())} verified matches triangulate in front of both"
        for v in views:
            v.note = "not registered: the pair's geometry puts the points behind a camera"
        return est
    pts, b1, b2 = pts[front], b1[front], b2[front]
    # The two poses refined on a spread subset of the points (the adjustment's cost grows
    # with the points; 500 pin two poses down), then every point triangulated again.
    sub = np.random.default_rng(cfg.seed).permutation(len(pts))[:500]
    n = len(sub)
    adj = geo.bundle_adjust(
        np.stack([np.eye(3), rot]),
        np.stack([np.zeros(3), t]),
        pts[sub],
        np.repeat([0, 1], n),
        np.tile(np.arange(n), 2),
        np.concatenate([b1[sub], b2[sub]]),
        loss_scale=cfg.max_error_px * math.pi / 512.0 / 2,
    )
    rot = adj.rots[1] @ adj.rots[0].T
    t = adj.trans[1] - rot @ adj.trans[0]
    dist, pts = geo.triangulate_pair(rot, t, b1, b2)
    p2 = pts @ rot.T + t
    res = np.stack(
        [
            np.arccos(np.clip((pts * b1).sum(1) / np.linalg.norm(pts, axis=1), -1, 1)),
            np.arccos(np.clip((p2 * b2).sum(1) / np.linalg.norm(p2, axis=1), -1, 1)),
        ]
    )
    good = (dist > 0).all(1) & (res < cfg.max_error_px * math.pi / 512.0).all(0)
    for k, (r, tk) in zip((i, j), ((np.eye(3), np.zeros(3)), (rot, t)), strict=True):
        c2w[k] = np.eye(4)
        c2w[k, :3, :3] = r.T
        c2w[k, :3, 3] = -r.T @ tk
        registered[k] = True
    deg = np.degrees(res[:, good])
    est.points = pts[good]
    est.residual_deg = float(np.median(deg)) if deg.size else None
    pair.shared_points = int(good.sum())
    pair.residual_deg = est.residual_deg
    pair.ok = True
    for k, v in enumerate(views):
        v.registered, v.points = True, int(good.sum())
        v.residual_deg = float(np.median(deg[k])) if deg.size else None
        v.note = f"registered: {v.points} points, median residual {v.residual_deg:.3f} deg"
    return est


def _check_pairs(pairs, c2w, registered, relatives) -> dict:
    """{(i, j): why} for registered pairs whose relative pose in the reconstruction disagrees
    with their own verified two-view geometry."""
    out = {}
    for p in pairs:
        rel = relatives.get((p.i, p.j))
        if rel is None or not (registered[p.i] and registered[p.j]):
            continue
        rot_v, t_v = rel  # x_j = rot_v x_i + t_v (camera frames, OpenGL)
        w2c = [np.linalg.inv(c2w[k]) for k in (p.i, p.j)]
        rot = w2c[1][:3, :3] @ w2c[0][:3, :3].T
        t = w2c[1][:3, 3] - rot @ w2c[0][:3, 3]
        d_rot = _angle_deg((np.trace(rot.T @ rot_v) - 1) / 2)
        norm = np.linalg.norm(t) * np.linalg.norm(t_v)
        d_dir = _angle_deg(float(t @ t_v / norm)) if norm > 0 else 180.0
        if d_rot > MAX_PAIR_ROTATION_DEG or d_dir > MAX_PAIR_DIRECTION_DEG:
            out[(p.i, p.j)] = (
                f"its place in the reconstruction disagrees with its own geometry (rotation "
                f"by {d_rot:.1f} deg, direction by {d_dir:.1f} deg)"
            )
    return out


#: A registered pair's relative pose may differ from its own verified two-view geometry by this
#: much (rotation, translation direction; degrees) before the pair counts as inconsistent.
MAX_PAIR_ROTATION_DEG = 3.0
MAX_PAIR_DIRECTION_DEG = 10.0


def _angle_deg(cos: float) -> float:
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def _collect(
    recs, v_count, pano_of, counts, cfg: ColmapConfig, width: int, relatives=None
) -> ColmapEstimate:
    """The reconstruction that registers most panoramas (then: the smaller residual) as poses
    and the report. A panorama is kept only if it sees ``min_pair_inliers`` points of the
    reconstruction and one of its pairs agrees with that pair's own verified geometry: the
    mapper can place a panorama on a handful of points, and then it is wrong."""
    c2w = np.full((v_count, 4, 4), np.nan)
    registered = np.zeros(v_count, bool)
    px_to_deg = 360.0 / width  # at the equator; towards the poles a pixel is less
    views = [ViewReport(k) for k in range(v_count)]
    pairs = [
        PairReport(i, j, *counts.get((i, j), (0, 0)))
        for i in range(v_count)
        for j in range(i + 1, v_count)
    ]
    points = np.zeros((0, 3))
    residual, mapper = None, ""
    usable = [(n, r) for n, r in recs if r.num_reg_images() >= 2]
    if usable:
        mapper, rec = max(
            usable,
            key=lambda nr: (nr[1].num_reg_images(), -nr[1].compute_mean_reprojection_error()),
        )
        for image in rec.images.values():
            if not image.has_pose:
                continue
            k = pano_of[image.image_id]
            m = np.eye(4)
            m[:3, :4] = np.asarray(image.cam_from_world().matrix())
            c2w_cv = np.linalg.inv(m)
            registered[k] = True
            c2w[k] = c2w_cv
            c2w[k, :3, :3] = c2w_cv[:3, :3] @ CV_TO_GL
        ids = list(rec.points3D.keys())
        points = np.array([rec.points3D[i].xyz for i in ids]).reshape(-1, 3)
        errors = np.array([rec.points3D[i].error for i in ids])
        seen = [{pano_of[e.image_id] for e in rec.points3D[i].track.elements} for i in ids]
        if len(errors):
            residual = float(np.median(errors) * px_to_deg)
        for v in views:
            if registered[v.index]:
                sel = [n for n, s in enumerate(seen) if v.index in s]
                v.registered, v.points = True, len(sel)
                v.residual_deg = float(np.median(errors[sel]) * px_to_deg) if sel else None
                v.note = f"registered: {v.points} points" + (
                    f", median residual {v.residual_deg:.3f} deg" if sel else ""
                )
        for p in pairs:
            sel = [n for n, s in enumerate(seen) if p.i in s and p.j in s]
            p.shared_points = len(sel)
            if sel:
                p.residual_deg = float(np.median(errors[sel]) * px_to_deg)
    inconsistent = _check_pairs(pairs, c2w, registered, relatives or {})
    for v in views:
        if not registered[v.index]:
            continue
        links = [p for p in pairs if v.index in (p.i, p.j) and registered[p.i] and registered[p.j]]
        agreeing = [p for p in links if (p.i, p.j) not in inconsistent and p.inliers]
        if v.points < cfg.min_pair_inliers or not agreeing:
            registered[v.index] = False
            c2w[v.index] = np.nan
            v.registered = False
            v.note = (
                f"not registered: placed on {v.points} points only"
                if v.points < cfg.min_pair_inliers
                else "not registered: its place disagrees with its own pairs' geometry"
            ) + " (wrong matches, or too little overlap)"
    for p in pairs:
        if (p.i, p.j) in inconsistent:
            p.reason = inconsistent[(p.i, p.j)]
        elif p.inliers < cfg.min_pair_inliers:
            p.reason = (
                f"{p.inliers} of {p.matches} matches agree on a geometry "
                f"(< {cfg.min_pair_inliers}): too little overlap or texture between these two"
            )
        elif not (registered[p.i] and registered[p.j]):
            lost = p.i if not registered[p.i] else p.j
            p.reason = f"{p.inliers} inliers, but view {lost} could not be placed (see views)"
        else:
            p.ok = True
    for v in views:
        if not registered[v.index] and not v.note:
            links = [p for p in pairs if v.index in (p.i, p.j)]
            best = max(links, key=lambda p: p.inliers) if links else None
            v.note = "not registered: " + (
                f"at most {best.inliers} verified matches with another panorama"
                if best is not None
                else "no other panorama"
            )
    return ColmapEstimate(c2w, registered, points, pairs, views, residual, mapper)
