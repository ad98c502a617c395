"""Sparse depth anchors: SIFT matches between posed panoramas, triangulated with the known poses.

The networks' depth is learned on synthetic rooms, and the photometric refinement only moves it
locally from where the networks left it. A keypoint matched between two views whose poses are
known needs neither: its distance from each camera follows from the two rays alone. On a real
capture such points are accurate (distinct texture), wherever the networks' depth is wrong; on
repeated patterns (tiled floors, wallpaper) a match can pick the wrong repetition along its
epipolar line, so the refinement weighs them with a bounded loss (`RefineConfig.anchors`).

Per pair of views: SIFT on cube faces (`panogrf.model.features.detect`), matches guided by the
essential matrix of the known poses (`match_guided`: within ``threshold_px`` of the epipolar
plane in both views, Lowe's ratio test, mutual), midpoint triangulation in the world, kept when
both distances are positive, inside the depth range and the rays meet at an angle of at least
``min_parallax_deg`` (a narrow angle leaves the distance unsure).

Shapes: V views, N anchors of a view.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from panogrf.model import features as ft
from panogrf.model.erp import sample_erp_directions


@dataclass(frozen=True)
class AnchorConfig:
    """How anchors are found."""

    max_per_face: int = 1000
    """SIFT keypoints per cube face."""
    threshold_px: float = 1.0
    """Largest angle from the epipolar plane, in pixels of the panorama's equator."""
    ratio: float = 0.7
    """Lowe's ratio test among the candidates near the epipolar plane."""
    min_parallax_deg: float = 3.0
    """Smallest angle between the two rays at the point."""


@dataclass(frozen=True)
class Anchors:
    """One view's anchors."""

    bearings: Tensor
    """[N, 3] unit directions in the view's camera frame."""
    log_depth: Tensor
    """[N] log of the spherical distance (metres) along them."""

    def __len__(self) -> int:
        return int(self.log_depth.shape[0])


def _uint8(image: Tensor) -> np.ndarray:
    """[3, H, W] in [0, 1] -> [H, W, 3] uint8."""
    return (image.detach().float().clamp(0, 1) * 255).round().byte().permute(1, 2, 0).numpy()


def _skew(t: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])


def triangulate_known(
    c2w_a: np.ndarray, c2w_b: np.ndarray, bearings_a: np.ndarray, bearings_b: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint triangulation of matched bearings [N, 3] (camera frames) of two posed views.

    Returns the distances along each view's ray [N, 2] (negative: behind that camera) and the
    angle between the two rays at the point [N] (degrees)."""
    da = bearings_a @ c2w_a[:3, :3].T  # world directions
    db = bearings_b @ c2w_b[:3, :3].T
    gap = c2w_b[:3, 3] - c2w_a[:3, 3]
    # s_a da - s_b db = gap in least squares.
    dot = (da * db).sum(1)
    ga, gb = da @ gap, db @ gap
    det = 1.0 - dot * dot
    det = np.where(np.abs(det) < 1e-12, 1e-12, det)
    s_a = (ga - dot * gb) / det
    s_b = (dot * ga - gb) / det
    angle = np.degrees(np.arccos(np.clip(dot, -1.0, 1.0)))
    return np.stack((s_a, s_b), 1), angle


def triangulated_anchors(
    images: Tensor,  # [V, 3, H, W] in [0, 1]
    c2w: Tensor,  # [V, 4, 4]
    sources: list[list[int]],
    config: AnchorConfig = AnchorConfig(),
    d_range: tuple[float, float] = (0.1, 10.0),
) -> list[Anchors]:
    """Each view's anchors from every pair (r, s) with s among r's ``sources`` (each pair
    matched once; its points anchor both views)."""
    v, _, h, _ = images.shape
    pairs = sorted({(min(r, s), max(r, s)) for r in range(v) for s in sources[r]})
    feats = {
        i: ft.detect(_uint8(images[i]), max_per_face=config.max_per_face) for p in pairs for i in p
    }
    poses = c2w.detach().double().cpu().numpy()
    found: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in range(v)]
    for i, j in pairs:
        # x_j = R x_i + t between the camera frames; E = [t]x R.
        rot = poses[j, :3, :3].T @ poses[i, :3, :3]
        shift = poses[j, :3, :3].T @ (poses[i, :3, 3] - poses[j, :3, 3])
        threshold = config.threshold_px * math.pi / h
        m = ft.match_guided(feats[i], feats[j], _skew(shift) @ rot, threshold, config.ratio)
        if len(m) == 0:
            continue
        b_i, b_j = feats[i].bearings[m[:, 0]], feats[j].bearings[m[:, 1]]
        dist, angle = triangulate_known(poses[i], poses[j], b_i, b_j)
        ok = (angle >= config.min_parallax_deg) & np.all(
            (dist >= d_range[0]) & (dist <= d_range[1]), axis=1
        )
        found[i].append((b_i[ok], dist[ok, 0]))
        found[j].append((b_j[ok], dist[ok, 1]))
    out = []
    for parts in found:
        bearings = np.concatenate([p[0] for p in parts]) if parts else np.zeros((0, 3))
        dist = np.concatenate([p[1] for p in parts]) if parts else np.zeros(0)
        out.append(
            Anchors(
                torch.from_numpy(bearings).to(images.dtype),
                torch.from_numpy(np.log(dist)).to(images.dtype),
            )
        )
    return out


def anchor_loss(
    log_depth: Tensor, anchors: list[Anchors], views: list[int], scale: float
) -> Tensor:
    """Mean over ``views`` of the mean bounded loss r^2 / (r^2 + scale^2) of the anchors'
    log-depth residuals r, the view's log depth [V, 1, h, w] read bilinearly along each anchor's
    bearing. Bounded: an anchor far off (a wrong repetition) pulls little, one near the depth
    pulls it onto itself."""
    total, count = log_depth.new_zeros(()), 0
    for r in views:
        a = anchors[r]
        if len(a) == 0:
            continue
        seen = sample_erp_directions(log_depth[r : r + 1], a.bearings[None])[0, 0]
        res2 = (seen - a.log_depth) ** 2
        total = total + (res2 / (res2 + scale * scale)).mean()
        count += 1
    return total / max(count, 1)
