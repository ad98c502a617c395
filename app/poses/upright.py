"""The relative pose of two level panoramas by exhaustive search, for pairs RANSAC cannot pose.

Two rooms that see each other through a doorway share a few percent of their matches: too
few for a five-point RANSAC (COLMAP's verification keeps nothing), yet enough when the
cameras are level, as 360-degree cameras make them (a tripod, or the camera's own horizon
correction). Then the relative pose has three unknowns: the second camera's heading (yaw) and
the direction of its centre, nearly horizontal (the two cameras at about one height). Every
yaw and heading on a one-degree grid, and elevations of the centre within
``max_elevation_deg``, is scored by the matches whose rays meet in front of both cameras within
``tol_deg`` of the epipolar plane (a Hough transform, not sampling, so a 5 % inlier share is
found as surely as a 50 % one). A peak is taken only if it is clearly the best: ``min_support``
matches and ``min_ratio`` times the best hypothesis ``apart_deg`` away from it; it is then
refined in all five degrees of freedom (the cameras need not be exactly level).

The result only seeds the guided matching of `panogrf.app.poses.colmap`; COLMAP verifies the
grown matches and maps as for any other pair. Bearings and poses follow
`panogrf.app.poses.geometry`: ``x2 = R x1 + t``, OpenGL camera frames (y up),
``b2^T E b1 = 0`` with ``E = [t]x R``.
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
    max_elevation_deg: float = 15.0
    """The direction from one camera to the other is searched up to this far above or below
    the horizon (hand-held cameras 0.3 m apart in height at 1.2 m: 14 degrees)."""
    elevation_step_deg: float = 1.5
    max_matches: int = 500
    """More matches than this: the grid counts a random subset of this many (its cost grows
    with the matches; a pair with thousands of matches that RANSAC could not verify, such as a
    photo and a turned copy of it, needs no more to show a peak or its absence)."""
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


def _centres(cfg: UprightConfig) -> np.ndarray:
    """Unit centres [E, H, 3] of camera 2 on the grid of elevations and headings."""
    heads = np.radians(np.arange(0.0, 360.0, cfg.step_deg))
    top = cfg.max_elevation_deg
    elevs = np.radians(np.arange(-top, top + 1e-9, cfg.elevation_step_deg))
    ce, se = np.cos(elevs)[:, None], np.sin(elevs)[:, None]
    return np.stack(np.broadcast_arrays(ce * np.sin(heads), se, -ce * np.cos(heads)), -1)


def _grid(b1: np.ndarray, b2: np.ndarray, cfg: UprightConfig) -> tuple[np.ndarray, np.ndarray]:
    """Support [Y, H] of every yaw (camera 2's axes in camera 1's) and heading on the grid:
    the most matches any elevation of the centre gathers, and that elevation's index [Y, H].

    A match supports a centre c when d2 = R_yaw b2 is within the tolerance of the epipolar
    plane through c and b1 (c . (b1 x d2) = 0 exactly on it) and both rays' depths are
    positive: for each yaw,
    one [C, 3] x [3, M] product over all centres C at once (single precision: the test is
    on sines of a degree or so), the depths' signs only where a match is on the plane. Matches
    with less parallax than the tolerance fit every heading and are not counted."""
    import torch

    centres = torch.from_numpy(_centres(cfg).reshape(-1, 3)).float()
    limit = math.sin(math.radians(cfg.tol_deg))
    yaws = np.radians(np.arange(0.0, 360.0, cfg.step_deg))
    tb1 = torch.from_numpy(b1).float()
    along1 = (centres @ tb1.T).square_()  # cos^2 of centre to b1, [C, M]
    side1 = (1.0 - along1).clamp_(min=0.0).mul_(limit * limit)  # (limit |c x b1|)^2
    out = np.empty((len(yaws), len(centres)), np.int64)
    for k, r in enumerate(_rot_y(yaws)):
        d2 = torch.from_numpy(b2 @ r.T).float()
        n = torch.linalg.cross(tb1, d2)  # [M, 3]; |n| = sine of the parallax
        off = (centres @ n.T).square_() < side1
        off &= n.norm(dim=1) > limit
        # A few percent of (centre, match) lie on the epipolar plane: only those are tested
        # for the depths' signs.
        at, of = torch.nonzero(off, as_tuple=True)
        c = centres[at]
        front = ((c * torch.linalg.cross(d2, n)[of]).sum(1) > 0) & (
            (c * torch.linalg.cross(tb1, n)[of]).sum(1) > 0
        )
        out[k] = torch.bincount(at[front], minlength=len(centres)).numpy()
    score = out.reshape(len(yaws), -1, len(yaws))  # [Y, E, H]
    return score.max(1), score.argmax(1)


def _refine(b1: np.ndarray, b2: np.ndarray, rot: np.ndarray, t: np.ndarray, tol: float):
    """(R, t) refined in five degrees of freedom on the matches within ``tol`` (radians)."""

    def unpack(p):
        r = Rotation.from_rotvec(p[:3]).as_matrix()
        th, ph = p[3], p[4]
        return r, np.array(
            [math.cos(ph) * math.sin(th), math.sin(ph), -math.cos(ph) * math.cos(th)]
        )

    def residual(p):
        dot, length = _epipolar(b1, b2, *unpack(p))
        return dot / np.maximum(length, 1e-12)

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
    sub = slice(None)
    if len(b1) > cfg.max_matches:
        sub = np.sort(np.random.default_rng(0).choice(len(b1), cfg.max_matches, replace=False))
    score, elevation = _grid(b1[sub], b2[sub], cfg)
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
    yaw = math.radians(yi * cfg.step_deg)
    r_21 = _rot_y(np.array([yaw]))[0]  # camera 2's axes in camera 1's
    centre = _centres(cfg)[elevation[yi, hi], hi]
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


def _epipolar(b1: np.ndarray, b2: np.ndarray, rot: np.ndarray, t: np.ndarray):
    """(b2 . n, |n|) [M] with n = E b1 the normal of each match's epipolar plane in camera 2:
    their ratio is the sine of b2's angle out of the plane."""
    normal = b1 @ (skew(t) @ rot).T
    return (normal * b2).sum(-1), np.linalg.norm(normal, axis=-1)


def _within(b1: np.ndarray, b2: np.ndarray, rot: np.ndarray, t: np.ndarray, limit: float):
    """Which matches [M] lie within ``limit`` (a sine) of their epipolar planes."""
    dot, length = _epipolar(b1, b2, rot, t)
    return np.abs(dot) < limit * length
