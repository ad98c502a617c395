"""Geometry on unit bearing vectors (any central camera, here panoramas): the triangulation
of a pair and the bundle adjustment on angular residuals that pose two panoramas
(`panogrf.app.poses.colmap`; COLMAP does the rest).

Frames: a bearing is a unit direction in its camera's frame (OpenGL: x right, y up, looking
down -z). A relative pose (R, t) maps camera-1 coordinates to camera-2 coordinates,
``x2 = R x1 + t``; the epipolar constraint is ``b2^T E b1 = 0`` with ``E = [t]x R``. World
poses in this module are world-to-camera (``x_cam = R_v x_world + t_v``); angles are radians,
lengths are in the reconstruction's (arbitrary) unit until `panogrf.app.poses.scale` sets it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation


def skew(t: np.ndarray) -> np.ndarray:
    """[3] -> the cross-product matrix [3, 3]."""
    return np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])


def triangulate_pair(
    rot: np.ndarray, t: np.ndarray, b1: np.ndarray, b2: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint triangulation of bearings [N, 3] under x2 = R x1 + t.

    Returns the distances along b1 and along b2 [N, 2] (negative: behind that camera) and the
    points in camera 1's frame [N, 3].
    """
    r1 = b1 @ rot.T  # b1 in camera 2's axes
    # s1 r1 + t = s2 b2 in least squares: [r1, -b2] [s1, s2]^T = -t
    a11 = (r1 * r1).sum(1)
    a12 = -(r1 * b2).sum(1)
    a22 = (b2 * b2).sum(1)
    y1, y2 = -(r1 @ t), b2 @ t
    det = a11 * a22 - a12 * a12
    det = np.where(np.abs(det) < 1e-12, 1e-12, det)
    s1 = (a22 * y1 - a12 * y2) / det
    s2 = (a11 * y2 - a12 * y1) / det
    points = 0.5 * (s1[:, None] * b1 + (s2[:, None] * b2 - t) @ rot)
    return np.stack((s1, s2), 1), points


@dataclass(frozen=True)
class Adjusted:
    """Result of `bundle_adjust`: world-to-camera rotations [V, 3, 3], translations [V, 3],
    points [P, 3] and the angular residual of every observation [M] (radians)."""

    rots: np.ndarray
    trans: np.ndarray
    points: np.ndarray
    residuals: np.ndarray


def _residuals(params, n_views, view, point, bearing, anchor, anchor_dist, weight):
    poses = params[: 6 * (n_views - 1)].reshape(-1, 6)
    pts = params[6 * (n_views - 1) :].reshape(-1, 3)
    rots = np.concatenate([np.eye(3)[None], Rotation.from_rotvec(poses[:, :3]).as_matrix()])
    trans = np.concatenate([np.zeros((1, 3)), poses[:, 3:]])
    p = np.einsum("mij,mj->mi", rots[view], pts[point]) + trans[view]
    p = p / np.maximum(np.linalg.norm(p, axis=1, keepdims=True), 1e-12)
    centre = -rots[anchor].T @ trans[anchor]
    gauge = weight * (np.linalg.norm(centre) - anchor_dist)
    return np.concatenate([(p - bearing).ravel(), [gauge]])


def bundle_adjust(
    rots: np.ndarray,
    trans: np.ndarray,
    points: np.ndarray,
    view: np.ndarray,
    point: np.ndarray,
    bearing: np.ndarray,
    *,
    loss_scale: float,
    max_nfev: int = 50,
) -> Adjusted:
    """Refine poses and points on angular residuals (chordal: |normalise(R X + t) - b|).

    rots [V, 3, 3], trans [V, 3] world-to-camera, with view 0 the world frame (held fixed);
    points [P, 3]; observations: view [M], point [M] indices and bearing [M, 3]. The scale
    gauge holds the distance of the farthest view from view 0. loss_scale: the Huber scale
    (radians). Uses scipy's trust-region least squares with a sparse Jacobian.
    """
    n_views = len(rots)
    centres = -np.einsum("vji,vj->vi", rots, trans)
    anchor = int(np.argmax(np.linalg.norm(centres, axis=1)))
    anchor_dist = float(np.linalg.norm(centres[anchor]))
    rv = Rotation.from_matrix(rots[1:]).as_rotvec()
    x0 = np.concatenate([np.hstack([rv, trans[1:]]).ravel(), points.ravel()])
    m = len(view)
    sparsity = scipy.sparse.lil_matrix((3 * m + 1, len(x0)), dtype=np.int8)
    obs = np.arange(m)
    for k in range(3):
        r = 3 * obs + k
        for c in range(3):
            sparsity[r, 6 * (n_views - 1) + 3 * point + c] = 1
        moving = view > 0
        for c in range(6):
            sparsity[r[moving], 6 * (view[moving] - 1) + c] = 1
    if anchor > 0:
        sparsity[3 * m, 6 * (anchor - 1) : 6 * anchor] = 1
    args = (n_views, view, point, bearing, anchor, anchor_dist, 10.0)
    # A wide loss first: from a rough start a narrow Huber scale converges very slowly.
    for f_scale in (10 * loss_scale, loss_scale):
        res = least_squares(
            _residuals,
            x0,
            jac_sparsity=sparsity.tocsr(),
            loss="huber",
            f_scale=f_scale,
            x_scale="jac",
            method="trf",
            tr_solver="lsmr",
            max_nfev=max_nfev,
            args=args,
        )
        x0 = res.x
    poses = res.x[: 6 * (n_views - 1)].reshape(-1, 6)
    out_rots = np.concatenate([np.eye(3)[None], Rotation.from_rotvec(poses[:, :3]).as_matrix()])
    out_trans = np.concatenate([np.zeros((1, 3)), poses[:, 3:]])
    pts = res.x[6 * (n_views - 1) :].reshape(-1, 3)
    chord = np.linalg.norm(res.fun[:-1].reshape(-1, 3), axis=1)
    return Adjusted(out_rots, out_trans, pts, 2 * np.arcsin(np.clip(chord / 2, 0, 1)))
