"""The relative pose of two level panoramas by exhaustive search, for pairs RANSAC cannot pose.

Two rooms that see each other through a doorway share a few percent of their matches: too
few for a five-point RANSAC (COLMAP's verification keeps nothing), yet enough when the
cameras are level, as 360-degree cameras make them (a tripod, or the camera's own horizon
correction). Then the relative pose has two unknowns: the second camera's heading (yaw) and the
direction of its centre in the horizontal plane. Every pair of them on a one-degree grid is
scored by the matches whose rays meet in front of both cameras within ``tol_deg`` of the
epipolar plane (a Hough transform, not sampling, so a 5 % inlier share is found as surely as
a 50 % one). A peak is taken only if it is clearly the best: ``min_support`` matches and
``min_ratio`` times the best hypothesis ``apart_deg`` away from it; it is then refined in all
five degrees of freedom (the cameras need not be exactly level, nor at one height).

The result only seeds the guided matching of `panogrf.app.poses.colmap`; COLMAP verifies the
grown matches and maps as for any other pair, so a wrong seed that finds no support is dropped
there. Bearings and poses follow `panogrf.app.poses.geometry`: ``x2 = R x1 + t``, OpenGL camera
frames (y up), ``b2^T E b1 = 0`` with ``E = [t]x R``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from panogrf.app.poses.geometry import skew


@dataclass(frozen=True)
class UprightConfig:
    """Settings of `search`."""

    step_deg: float = 1.0
    """Grid step of the yaw and the heading."""
    tol_deg: float = 1.0
    """A match supports a hypothesis within this angle of its epipolar plane (the grid's
    half step in yaw and heading, and a height difference of 5 cm in 3 m, each move true
    matches by up to half a degree)."""
    min_support: int = 20
    """Fewer supporting matches: no pose. On the real home of the posing benchmark, pairs
    that see little of each other peak at 6-12 among 150-330 matches, pairs through a doorway
    or across a room at 39-254."""
    min_ratio: float = 1.5
    """The peak's support over the best hypothesis ``apart_deg`` away from it (there: 1.8-4.1
    for true peaks, 1.0-1.3 for the others)."""
    apart_deg: float = 20.0
    """Yaw or heading this far from the peak: another hypothesis, not the peak's shoulder."""


@dataclass(frozen=True)
class UprightPose:
    """A relative pose found by `search`: ``x2 = rot @ x1 + t`` (``t`` a unit vector)."""

    rot: np.ndarray
    t: np.ndarray
    support: int
    """Matches within the tolerance at the grid's peak."""
    runner_up: int
    """The best support ``apart_deg`` away from the peak."""

    @property
    def essential(self) -> np.ndarray:
        return skew(self.t) @ self.rot


def _rot_y(angles: np.ndarray) -> np.ndarray:
    """[N] angles (rad) -> [N, 3, 3] rotations about +y."""
    c, s = np.cos(angles), np.sin(angles)
    z, o = np.zeros_like(angles), np.ones_like(angles)
    rows = (np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1))
    return np.stack(rows, -2)


def _support(b1: np.ndarray, d2: np.ndarray, trig: np.ndarray, limit: float) -> np.ndarray:
    """Rays b1 [M, 3] from the origin and d2 [M, 3] (camera 1's axes) from the level centres
    (sin h, 0, -cos h) given as ``trig`` [H, 2] = (sin h, -cos h) -> the matches [H] within
    ``limit`` (a sine) of the epipolar plane, in front of both cameras.

    Each quantity is linear in (sin h, -cos h): with c = sin h e_x - cos h e_z, the plane's
    normal is c x b1 = sin h (e_x x b1) - cos h (e_z x b1), so every test is one [H, 2] x
    [2, M] product."""
    ex, ez = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
    nx, nz = np.cross(ex, b1), np.cross(ez, b1)  # [M, 3]
    cross = np.cross(b1, d2)
    off = trig @ np.stack([(nx * d2).sum(1), (nz * d2).sum(1)])  # normal . d2, [H, M]
    sq = (
        trig[:, :1] ** 2 * (nx * nx).sum(1)
        + trig[:, 1:] ** 2 * (nz * nz).sum(1)
        + 2 * trig[:, :1] * trig[:, 1:] * (nx * nz).sum(1)
    )  # |normal|^2
    # depths along b1 and d2, up to the positive factor |b1 x d2|^2
    depth2 = trig @ np.stack([(nx * cross).sum(1), (nz * cross).sum(1)])
    depth1 = trig @ np.stack([(np.cross(ex, d2) * cross).sum(1), (np.cross(ez, d2) * cross).sum(1)])
    ok = (off * off < limit * limit * sq) & (depth1 > 0) & (depth2 > 0)
    return ok.sum(1)


def _grid(b1: np.ndarray, b2: np.ndarray, cfg: UprightConfig) -> np.ndarray:
    """Support [Y, H] of every yaw (camera 2 in camera 1's axes) and heading on the grid."""
    angles = np.radians(np.arange(0.0, 360.0, cfg.step_deg))
    trig = np.stack([np.sin(angles), -np.cos(angles)], -1)
    limit = math.sin(math.radians(cfg.tol_deg))
    return np.stack([_support(b1, b2 @ r.T, trig, limit) for r in _rot_y(angles)])


def _refine(b1: np.ndarray, b2: np.ndarray, rot: np.ndarray, t: np.ndarray, tol: float):
    """(R, t) refined in five degrees of freedom on the matches within ``tol`` (radians)."""

    def unpack(p):
        r = Rotation.from_rotvec(p[:3]).as_matrix()
        th, ph = p[3], p[4]
        return r, np.array(
            [math.cos(ph) * math.sin(th), math.sin(ph), -math.cos(ph) * math.cos(th)]
        )

    def residual(p):
        r, tt = unpack(p)
        n = b1 @ (skew(tt) @ r).T
        return (n * b2).sum(1) / np.maximum(np.linalg.norm(n, axis=1), 1e-12)

    p0 = np.concatenate([Rotation.from_matrix(rot).as_rotvec(), [0.0, 0.0]])
    p0[3] = math.atan2(t[0], -t[2])
    p0[4] = math.asin(float(np.clip(t[1], -1.0, 1.0)))
    fit = least_squares(residual, p0, loss="soft_l1", f_scale=math.sin(tol))
    return unpack(fit.x)


def search(b1: np.ndarray, b2: np.ndarray, cfg: UprightConfig = UprightConfig()):
    """The relative pose of two level panoramas from matched bearings b1, b2 [M, 3], or None
    when no hypothesis stands out (see the module's description)."""
    if len(b1) < cfg.min_support:
        return None
    score = _grid(b1, b2, cfg)
    yi, hi = np.unravel_index(int(np.argmax(score)), score.shape)
    best = int(score[yi, hi])
    n = score.shape[0]
    apart = int(round(cfg.apart_deg / cfg.step_deg))
    ring = np.arange(n)
    dist_y = np.minimum((ring - yi) % n, (yi - ring) % n)
    dist_h = np.minimum((ring - hi) % n, (hi - ring) % n)
    far = (dist_y[:, None] >= apart) | (dist_h[None, :] >= apart)
    runner_up = int(score[far].max()) if far.any() else 0
    if best < cfg.min_support or best < cfg.min_ratio * runner_up:
        return None
    yaw, head = math.radians(yi * cfg.step_deg), math.radians(hi * cfg.step_deg)
    r_21 = _rot_y(np.array([yaw]))[0]  # camera 2's axes in camera 1's
    centre = np.array([math.sin(head), 0.0, -math.cos(head)])
    rot = r_21.T
    t = -rot @ centre
    last = None
    # tighter each pass, then until the inliers stop changing: the inliers found grow
    for share in (1.0, 0.5, 0.25, 0.25, 0.25, 0.25, 0.25):
        tol = math.radians(cfg.tol_deg * share)
        keep = _within(b1, b2, rot, t, math.sin(tol))
        if keep.sum() < 5 or (last is not None and np.array_equal(keep, last)):
            break
        rot, t = _refine(b1[keep], b2[keep], rot, t, tol)
        last = keep if share == 0.25 else None
    return UprightPose(rot=rot, t=t, support=best, runner_up=runner_up)


def _within(b1: np.ndarray, b2: np.ndarray, rot: np.ndarray, t: np.ndarray, limit: float):
    """Which matches [M] lie within ``limit`` (a sine) of their epipolar planes."""
    normal = b1 @ (skew(t) @ rot).T
    return np.abs((normal * b2).sum(-1)) < limit * np.linalg.norm(normal, axis=-1)
