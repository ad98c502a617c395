"""Two- and multi-view geometry on unit bearing vectors (any central camera, here panoramas).

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


def essential_linear(b1: np.ndarray, b2: np.ndarray) -> np.ndarray:
    """Normalised 8-point on bearings: b1, b2 [..., N, 3] (N >= 8) -> E [..., 3, 3].

    Bearings are unit vectors already, so the system is well conditioned without Hartley's
    normalisation. The result is projected onto the essential matrices (singular values 1, 1, 0).
    """
    a = (b2[..., :, :, None] * b1[..., :, None, :]).reshape(*b1.shape[:-1], 9)
    e = np.linalg.svd(a)[2][..., -1, :].reshape(*b1.shape[:-2], 3, 3)
    u, _, vt = np.linalg.svd(e)
    return u @ (np.array([1.0, 1.0, 0.0])[:, None] * vt)


def essential_upright(b1: np.ndarray, b2: np.ndarray) -> np.ndarray:
    """Linear 5-point solver for level cameras (rotation about y only): [..., N, 3] -> E.

    With R a rotation about y, E = [t]x R has E11 = 0, E00 = E22 and E02 = -E20: six unknowns,
    so five bearings fix it up to scale. The result is projected onto the essential matrices.
    """
    x1, y1, z1 = np.moveaxis(b1, -1, 0)
    x2, y2, z2 = np.moveaxis(b2, -1, 0)
    # unknowns (a = E00 = E22, b = E02 = -E20, E01, E10, E12, E21)
    a = np.stack((x2 * x1 + z2 * z1, x2 * z1 - z2 * x1, x2 * y1, y2 * x1, y2 * z1, z2 * y1), -1)
    v = np.linalg.svd(a)[2][..., -1, :]
    e = np.zeros((*v.shape[:-1], 3, 3))
    e[..., 0, 0] = e[..., 2, 2] = v[..., 0]
    e[..., 0, 2], e[..., 2, 0] = v[..., 1], -v[..., 1]
    e[..., 0, 1], e[..., 1, 0], e[..., 1, 2], e[..., 2, 1] = (v[..., k] for k in range(2, 6))
    u, _, vt = np.linalg.svd(e)
    return u @ (np.array([1.0, 1.0, 0.0])[:, None] * vt)


def epipolar_angle(e: np.ndarray, b1: np.ndarray, b2: np.ndarray) -> np.ndarray:
    """Angular epipolar error (radians), the larger of the two views': E [..., 3, 3] -> [..., N].

    In view 2 it is the angle between b2 and the epipolar plane of b1 (normal E b1), and
    likewise in view 1 with the normal E^T b2.
    """
    n2 = b1 @ np.swapaxes(e, -1, -2)  # [..., N, 3] rows E b1
    n1 = b2 @ e  # rows E^T b2
    num = np.abs((n2 * b2).sum(-1))
    s2 = num / np.maximum(np.linalg.norm(n2, axis=-1), 1e-12)
    s1 = num / np.maximum(np.linalg.norm(n1, axis=-1), 1e-12)
    return np.arcsin(np.clip(np.maximum(s1, s2), 0.0, 1.0))


def decompose_essential(e: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The four (R, t) with E ~ [t]x R, |t| = 1."""
    u, _, vt = np.linalg.svd(e)
    if np.linalg.det(u) < 0:
        u = -u
    if np.linalg.det(vt) < 0:
        vt = -vt
    w = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    t = u[:, 2]
    return [(u @ w @ vt, t), (u @ w @ vt, -t), (u @ w.T @ vt, t), (u @ w.T @ vt, -t)]


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
class RelativePose:
    """The relative pose of a panorama pair: x2 = rot x1 + t, |t| = 1."""

    rot: np.ndarray
    t: np.ndarray
    inliers: np.ndarray
    """[N] bool: the matches within the threshold that triangulate in front of both views."""
    median_error: float
    """Median angular epipolar error of the inliers (radians)."""


def ransac_essential(
    b1: np.ndarray,
    b2: np.ndarray,
    threshold: float,
    *,
    iterations: int = 512,
    upright_iterations: int = 4096,
    seed: int = 0,
) -> RelativePose | None:
    """Relative pose from matched bearings [N, 3] with RANSAC; None when N < 8.

    threshold: inlier angular epipolar error (radians). Hypotheses come from the general
    8-point solver and from the 5-point solver for level cameras (most 360-degree cameras level
    their panoramas; the upright samples need far fewer inliers to be found). The best
    hypothesis' inliers are refitted with the general 8-point solver, so tilted cameras still
    get their own rotation; then the one of the four decompositions that puts most inliers in
    front of both cameras is kept.
    """
    n = len(b1)
    if n < 8:
        return None
    rng = np.random.default_rng(seed)
    idx = np.argsort(rng.random((iterations, n)), axis=1)[:, :8]
    cand = [essential_linear(b1[idx], b2[idx])]  # [K, 3, 3]
    if upright_iterations:
        idx = np.argsort(rng.random((upright_iterations, n)), axis=1)[:, :5]
        cand.append(essential_upright(b1[idx], b2[idx]))
    cand = np.concatenate(cand)
    err = epipolar_angle(cand, b1[None], b2[None])  # [K, N]
    best = int((err < threshold).sum(1).argmax())
    inl = err[best] < threshold
    e = cand[best]
    for _ in range(2):
        if inl.sum() < 8:
            break
        e = essential_linear(b1[inl], b2[inl])
        inl = epipolar_angle(e, b1, b2) < threshold
    best_pose, best_front = None, -1
    for rot, t in decompose_essential(e):
        dist, _ = triangulate_pair(rot, t, b1[inl], b2[inl])
        front = int(((dist[:, 0] > 0) & (dist[:, 1] > 0)).sum())
        if front > best_front:
            best_pose, best_front = (rot, t), front
    rot, t = best_pose
    dist, _ = triangulate_pair(rot, t, b1, b2)
    inliers = inl & (dist[:, 0] > 0) & (dist[:, 1] > 0)
    errors = epipolar_angle(e, b1[inliers], b2[inliers])
    median = float(np.median(errors)) if len(errors) else float("nan")
    return RelativePose(rot, t, inliers, median)


def triangulate_views(rots: np.ndarray, trans: np.ndarray, bearings: np.ndarray) -> np.ndarray:
    """Linear triangulation of one point seen by several views: minimises sum |b_v x x_v|^2.

    rots [K, 3, 3], trans [K, 3] world-to-camera; bearings [K, 3] -> world point [3].
    """
    a = np.einsum("kij,kjl->kil", np.stack([skew(b) for b in bearings]), rots).reshape(-1, 3)
    rhs = -np.einsum("kij,kj->ki", np.stack([skew(b) for b in bearings]), trans).reshape(-1)
    return np.linalg.lstsq(a, rhs, rcond=None)[0]


def translation_from_points(
    rot: np.ndarray, points: np.ndarray, bearings: np.ndarray, threshold: float
) -> tuple[np.ndarray, np.ndarray]:
    """A view's translation given its rotation and 2D-3D correspondences (world points [N, 3],
    bearings [N, 3]): b x (R X + t) = 0 solved linearly, with outliers dropped over 3 rounds.

    Returns t [3] (world-to-camera) and the inlier mask [N] (angular error < threshold).
    """
    rx = points @ rot.T
    keep = np.ones(len(points), bool)
    t = np.zeros(3)
    for k in range(4):
        sk = np.stack([skew(b) for b in bearings[keep]])
        a = sk.reshape(-1, 3)
        rhs = -np.einsum("kij,kj->ki", sk, rx[keep]).reshape(-1)
        t = np.linalg.lstsq(a, rhs, rcond=None)[0]
        p = rx + t
        cosang = (p * bearings).sum(1) / np.maximum(np.linalg.norm(p, axis=1), 1e-12)
        ang = np.arccos(np.clip(cosang, -1, 1))
        limit = threshold * (8.0, 4.0, 2.0, 1.0)[k]
        new = ang < limit
        if new.sum() < 6:
            break
        keep = new
    return t, keep


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
