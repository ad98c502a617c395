"""Relative poses of V panoramas from their pixels: features, pairs, registration, adjustment.

Output poses are camera-to-world [V, 4, 4] (OpenGL camera frame) in the frame of the first
registered view, with an arbitrary unit (the farthest registered view from the reference sits
at the distance of the initial pair's unit baseline); `panogrf.app.poses.scale` makes them
upright and metric. Every pair and every view gets a line in the report: matches, inliers,
residuals in degrees, or why it failed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from panogrf.app.poses import features as ft
from panogrf.app.poses import geometry as geo


@dataclass(frozen=True)
class EstimateConfig:
    """Settings of `estimate_poses`."""

    threshold_px: float = 1.5
    """Inlier threshold, in pixels of the panorama's equator (angle = px * pi / H)."""
    min_matches: int = 20
    """Fewer putative matches than this: the pair fails (no overlap or too little texture)."""
    min_inliers: int = 20
    """Fewer geometric inliers than this: the pair fails."""
    min_parallax_deg: float = 0.3
    """Median parallax below this: the pair fails (same position, or a rotation only)."""
    min_points: int = 8
    """Triangulated points a view must see to be registered."""


@dataclass
class PairResult:
    """One pair of views: the matches and what became of them."""

    i: int
    j: int
    matches: int = 0
    inliers: int = 0
    ok: bool = False
    reason: str = ""
    residual_deg: float = float("nan")
    """Median angular residual after adjustment of the points seen by both views."""
    rel: geo.RelativePose | None = None
    pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), int))
    """[K, 2] keypoint indices of the inlier matches."""


@dataclass
class Estimate:
    """Poses of the registered views and the evidence behind them."""

    c2w: np.ndarray
    """[V, 4, 4] camera-to-world (OpenGL), reference view's frame; NaN for unregistered views."""
    registered: np.ndarray
    """[V] bool."""
    points: np.ndarray
    """[P, 3] triangulated points, same frame."""
    point_views: list[np.ndarray]
    """For each point the views that observe it."""
    point_bearings: list[np.ndarray]
    """For each point its bearings in those views [k, 3] (camera frames)."""
    pairs: list[PairResult]
    view_notes: list[str]
    """One line per view: registered (points, residual) or why not."""
    residual_deg: float
    """Median angular residual over all observations after adjustment."""


def _relative(fa, fb, threshold: float, cfg: EstimateConfig, i: int, j: int) -> PairResult:
    result = PairResult(i, j)
    m = ft.match(fa, fb)
    result.matches = len(m)
    if len(m) < cfg.min_matches:
        result.reason = f"too few matches ({len(m)} < {cfg.min_matches}): no overlap or no texture"
        return result
    rel = geo.ransac_essential(fa.bearings[m[:, 0]], fb.bearings[m[:, 1]], threshold)
    if rel is None or rel.inliers.sum() < 8:
        result.reason = f"no consistent geometry in {len(m)} matches"
        return result
    e = geo.skew(rel.t) @ rel.rot
    guided = ft.match_guided(fa, fb, e, 2 * threshold)
    if len(guided) > rel.inliers.sum():
        better = geo.ransac_essential(
            fa.bearings[guided[:, 0]], fb.bearings[guided[:, 1]], threshold, seed=1
        )
        if better is not None and better.inliers.sum() > rel.inliers.sum():
            m, rel = guided, better
    result.inliers = int(rel.inliers.sum())
    if result.inliers < cfg.min_inliers:
        result.reason = (
            f"too few inliers ({result.inliers} of {len(m)} matches < {cfg.min_inliers})"
        )
        return result
    b1, b2 = fa.bearings[m[rel.inliers, 0]], fb.bearings[m[rel.inliers, 1]]
    parallax = np.degrees(np.median(np.arccos(np.clip(((b1 @ rel.rot.T) * b2).sum(1), -1, 1))))
    if parallax < cfg.min_parallax_deg:
        result.reason = f"no parallax (median {parallax:.2f} deg): same place or a rotation only"
        return result
    result.ok, result.rel, result.pairs = True, rel, m[rel.inliers]
    return result


def _tracks(num_views: int, sizes: list[int], pairs: list[PairResult]) -> list[dict[int, int]]:
    """Union of the pairs' inlier matches into tracks {view: keypoint}; inconsistent ones go."""
    offset = np.concatenate([[0], np.cumsum(sizes)])
    parent = np.arange(offset[-1])

    def find(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for p in pairs:
        if p.ok:
            for ka, kb in p.pairs:
                ra, rb = find(offset[p.i] + ka), find(offset[p.j] + kb)
                if ra != rb:
                    parent[ra] = rb
    groups: dict[int, dict[int, int]] = {}
    bad = set()
    for v in range(num_views):
        for k in range(sizes[v]):
            node = offset[v] + k
            root = find(node)
            track = groups.setdefault(root, {})
            if v in track:
                bad.add(root)
            track[v] = k
    return [t for r, t in groups.items() if len(t) >= 2 and r not in bad]


def estimate_poses(images: list[np.ndarray], cfg: EstimateConfig = EstimateConfig()) -> Estimate:
    """Poses of panoramas [H, W, 3] uint8 (RGB), at least two, all the same size."""
    v_count = len(images)
    threshold = cfg.threshold_px * math.pi / images[0].shape[0]
    feats = [ft.detect(img) for img in images]
    pairs = [
        _relative(feats[i], feats[j], threshold, cfg, i, j)
        for i in range(v_count)
        for j in range(i + 1, v_count)
    ]
    for _ in range(3):
        tracks = _tracks(v_count, [len(f.bearings) for f in feats], pairs)
        rots, trans, registered, points, notes = _register(
            v_count, tracks, feats, pairs, cfg, threshold
        )
        if not _drop_inconsistent(pairs, rots, trans, registered):
            break
    for v in range(v_count):
        if not registered[v] and not notes[v]:
            notes[v] = "not registered: no successful pair with a registered view"
    if registered.sum() < 2:
        return Estimate(
            np.full((v_count, 4, 4), np.nan),
            registered,
            np.zeros((0, 3)),
            [],
            [],
            pairs,
            [n or "not registered" for n in notes],
            float("nan"),
        )
    return _adjust(tracks, feats, rots, trans, registered, points, pairs, notes, threshold)


def _register(v_count, tracks, feats, pairs, cfg, threshold):
    """Incremental registration from the pair with most inliers; rotations from the pairs,
    translations from the triangulated points each new view sees."""
    rots = np.full((v_count, 3, 3), np.nan)
    trans = np.full((v_count, 3), np.nan)
    registered = np.zeros(v_count, bool)
    notes = [""] * v_count
    good = [p for p in pairs if p.ok]
    points: dict[int, np.ndarray] = {}
    if good:
        first = max(good, key=lambda p: p.inliers)
        rots[first.i], trans[first.i] = np.eye(3), np.zeros(3)
        rots[first.j], trans[first.j] = first.rel.rot, first.rel.t
        registered[[first.i, first.j]] = True
        _triangulate(tracks, feats, rots, trans, registered, points, threshold)
        while True:
            best = _next_view(tracks, feats, rots, registered, points, good, cfg, notes, threshold)
            if best is None:
                break
            v, rot, t = best
            rots[v], trans[v], registered[v] = rot, t, True
            _triangulate(tracks, feats, rots, trans, registered, points, threshold)
    return rots, trans, registered, points, notes


def _drop_inconsistent(pairs, rots, trans, registered, max_rot_deg=2.0, max_dir_deg=6.0) -> bool:
    """Fail the pairs whose relative pose disagrees with the registered poses; any failed?"""
    dropped = False
    for p in pairs:
        if not (p.ok and registered[p.i] and registered[p.j]):
            continue
        rot = rots[p.j] @ rots[p.i].T
        t = trans[p.j] - rot @ trans[p.i]
        d_rot = np.degrees(np.arccos(np.clip((np.trace(rot.T @ p.rel.rot) - 1) / 2, -1, 1)))
        cos = t @ p.rel.t / max(np.linalg.norm(t), 1e-12)
        d_dir = np.degrees(np.arccos(np.clip(cos, -1, 1)))
        if d_rot > max_rot_deg or d_dir > max_dir_deg:
            p.ok = False
            p.reason = (
                f"inconsistent with the other pairs (rotation off by {d_rot:.1f} deg, "
                f"direction by {d_dir:.1f} deg): wrong matches"
            )
            dropped = True
    return dropped


def _triangulate(tracks, feats, rots, trans, registered, points, threshold) -> None:
    """(Re)triangulate every track seen by two or more registered views; keep good ones."""
    for n, track in enumerate(tracks):
        views = [v for v in track if registered[v]]
        if len(views) < 2:
            continue
        b = np.stack([feats[v].bearings[track[v]] for v in views])
        x = geo.triangulate_views(rots[views], trans[views], b)
        p = np.einsum("kij,j->ki", rots[views], x) + trans[views]
        cos = (p * b).sum(1) / np.maximum(np.linalg.norm(p, axis=1), 1e-12)
        if np.all(cos > math.cos(4 * threshold)):
            points[n] = x
        else:
            points.pop(n, None)


def _next_view(tracks, feats, rots, registered, points, good, cfg, notes, threshold):
    """The unregistered view with most triangulated points, with its pose; None if none."""
    best, best_count = None, -1
    for v in np.flatnonzero(~registered):
        links = [
            p for p in good if (p.i == v and registered[p.j]) or (p.j == v and registered[p.i])
        ]
        if not links:
            continue
        link = max(links, key=lambda p: p.inliers)
        rot = link.rel.rot @ rots[link.i] if link.j == v else link.rel.rot.T @ rots[link.j]
        seen = [n for n in points if v in tracks[n]]
        if len(seen) < cfg.min_points:
            notes[v] = f"not registered: sees {len(seen)} triangulated points (< {cfg.min_points})"
            continue
        x = np.stack([points[n] for n in seen])
        b = np.stack([feats[v].bearings[tracks[n][v]] for n in seen])
        t, keep = geo.translation_from_points(rot, x, b, threshold)
        if keep.sum() >= cfg.min_points and keep.sum() > best_count:
            best, best_count = (int(v), rot, t), int(keep.sum())
        elif keep.sum() < cfg.min_points:
            notes[v] = f"not registered: {int(keep.sum())} of {len(seen)} points agree on a pose"
    return best


def _adjust(tracks, feats, rots, trans, registered, points, pairs, notes, threshold) -> Estimate:
    """Bundle adjustment (twice, dropping outliers between), then the report."""
    views = np.flatnonzero(registered)
    ref = int(
        views[np.argmax([np.allclose(rots[v], np.eye(3)) and not trans[v].any() for v in views])]
    )
    order = [ref] + [int(v) for v in views if v != ref]  # BA index -> view
    slot = {v: k for k, v in enumerate(order)}
    ids = sorted(points)
    for round_ in range(2):
        obs_v, obs_p, obs_b = [], [], []
        for k, n in enumerate(ids):
            for v, kp in tracks[n].items():
                if registered[v]:
                    obs_v.append(slot[v])
                    obs_p.append(k)
                    obs_b.append(feats[v].bearings[kp])
        obs_v, obs_p, obs_b = np.array(obs_v), np.array(obs_p), np.array(obs_b)
        adj = geo.bundle_adjust(
            rots[order],
            trans[order],
            np.stack([points[n] for n in ids]),
            obs_v,
            obs_p,
            obs_b,
            loss_scale=threshold,
        )
        for k, v in enumerate(order):
            rots[v], trans[v] = adj.rots[k], adj.trans[k]
        bad = adj.residuals > 3 * threshold
        bad_points = set(obs_p[bad].tolist())
        if round_ == 0:
            for k, n in enumerate(ids):
                points[n] = adj.points[k]
            ids = [n for k, n in enumerate(ids) if k not in bad_points]
    c2w = np.full((len(registered), 4, 4), np.nan)
    for v in views:
        c2w[v] = np.eye(4)
        c2w[v, :3, :3] = rots[v].T
        c2w[v, :3, 3] = -rots[v].T @ trans[v]
    res_deg = np.degrees(adj.residuals)
    for p in pairs:
        if p.ok and registered[p.i] and registered[p.j]:
            both = [k for k, n in enumerate(ids) if p.i in tracks[n] and p.j in tracks[n]]
            sel = np.isin(obs_p, both) & np.isin(obs_v, [slot[p.i], slot[p.j]])
            p.residual_deg = float(np.median(res_deg[sel])) if sel.any() else float("nan")
    for v in views:
        sel = obs_v == slot[v]
        notes[v] = (
            f"registered: {int(sel.sum())} points, median residual "
            f"{np.median(res_deg[sel]):.3f} deg"
        )
    pv = [np.array([v for v in tracks[n] if registered[v]]) for n in ids]
    pb = [
        np.stack([feats[v].bearings[tracks[n][v]] for v in vs])
        for n, vs in zip(ids, pv, strict=True)
    ]
    return Estimate(c2w, registered, adj.points, pv, pb, pairs, notes, float(np.median(res_deg)))
