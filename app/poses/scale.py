"""Upright, metric scale and the canonical world frame of a set of poses.

All poses are camera-to-world [V, 4, 4] in the OpenGL camera frame (x right, y up, looking
down -z). The canonical world frame written to scene folders: y up, the first view's centre at
x = z = 0 looking (horizontally) down -z, and the floor at y = 0 where a floor was found
(otherwise the first view's centre is the origin). Lengths are metres once scaled.

Metric scale cannot come from images. It comes from the camera height above a floor plane
fitted to triangulated points well below the horizon (`fit_floor`), from a known distance
between two capture centres, or from a stated assumed camera height.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np

from panogrf.app.errors import UserError

#: The floor's normal within this of the cameras' mean up axis, or every camera's up axis within
#: this of their mean (degrees): the cameras are level and their up axis (more precise than a
#: fitted plane) is kept.
LEVEL_TOLERANCE_DEG = 2.0

#: Camera height assumed when neither a height nor a distance is given (metres).
ASSUMED_HEIGHT_M = 1.5


def rotation_to_up(up: np.ndarray) -> np.ndarray:
    """The smallest rotation [3, 3] that takes the unit vector ``up`` to +y."""
    up = np.asarray(up, float) / np.linalg.norm(up)
    y = np.array([0.0, 1.0, 0.0])
    axis = np.cross(up, y)
    s, c = np.linalg.norm(axis), float(up @ y)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = axis / s
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * kx + (1 - c) * kx @ kx


def camera_up(c2w: np.ndarray) -> np.ndarray:
    """The mean of the cameras' up axes (their y axes in the world), unit length: [3]."""
    up = c2w[:, :3, 1].sum(0)
    return up / np.linalg.norm(up)


def transform_world(c2w: np.ndarray, rot: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """Poses [V, 4, 4] in a new world frame: x_new = rot @ x_old + shift."""
    out = c2w.copy()
    out[:, :3, :3] = rot @ c2w[:, :3, :3]
    out[:, :3, 3] = c2w[:, :3, 3] @ rot.T + shift
    return out


def canonical_frame(
    c2w: np.ndarray, up: np.ndarray, floor_offset: float | None = None
) -> np.ndarray:
    """Rotate ``up`` (world) to +y, turn the first view to face -z, move it to x = z = 0.

    floor_offset: the floor plane is ``up . x = floor_offset`` in the old world; it becomes
    y = 0. Without it the first view's centre becomes the origin.
    """
    rot = rotation_to_up(up)
    forward = rot @ -c2w[0, :3, 2]
    yaw = np.arctan2(forward[0], -forward[2])  # angle of the view from -z towards +x
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]) @ rot  # the view's heading -> -z
    centre = rot @ c2w[0, :3, 3]
    floor_y = centre[1] if floor_offset is None else floor_offset
    return transform_world(c2w, rot, -np.array([centre[0], floor_y, centre[2]]))


def scale_centres(c2w: np.ndarray, s: float) -> np.ndarray:
    """Poses with every camera centre multiplied by ``s`` (about the world origin)."""
    out = c2w.copy()
    out[:, :3, 3] *= s
    return out


@dataclass(frozen=True)
class Floor:
    """A floor plane ``normal . x = offset`` (world frame, normal pointing up into the room)."""

    normal: np.ndarray
    """[3] unit normal."""
    offset: float
    inliers: int
    """Triangulated points within the tolerance of the plane."""
    candidates: int
    """Points that were low enough to be floor candidates."""
    points: np.ndarray
    """[inliers, 3] the points on the plane."""


def fit_floor(
    points: np.ndarray,
    centres: np.ndarray,
    up: np.ndarray,
    *,
    min_below: float = 0.35,
    tol: float = 0.015,
    max_tilt_deg: float = 15.0,
    iterations: int = 400,
    seed: int = 0,
) -> Floor | None:
    """RANSAC plane through the low points, the floor; None when there is none to be found.

    points: [N, 3] triangulated points, world. centres: [V, 3] camera centres. up: [3] rough
    world up (the cameras' mean up axis). min_below: a candidate lies at least this fraction of
    its horizontal distance below the lowest camera (about 20 degrees under the horizon).
    tol: inlier distance as a fraction of the mean camera-to-point distance. Among planes within
    ``max_tilt_deg`` of ``up`` the one with most inliers wins; its normal is refined by least
    squares on the inliers.
    """
    up = up / np.linalg.norm(up)
    lowest = float((centres @ up).min())
    rel = points - centres.mean(0)
    drop = lowest - points @ up
    horizontal = np.linalg.norm(rel - np.outer(rel @ up, up), axis=1)
    cand = points[drop > min_below * np.maximum(horizontal, 1e-9)]
    if len(cand) < 12:
        return None
    thresh = tol * float(np.linalg.norm(cand - centres.mean(0), axis=1).mean())
    rng = np.random.default_rng(seed)
    best, best_count = None, 0
    cos_tilt = np.cos(np.radians(max_tilt_deg))
    for _ in range(iterations):
        a, b, c = cand[rng.choice(len(cand), 3, replace=False)]
        n = np.cross(b - a, c - a)
        if np.linalg.norm(n) < 1e-12:
            continue
        n = n / np.linalg.norm(n)
        n = n if n @ up > 0 else -n
        if n @ up < cos_tilt:
            continue
        inl = np.abs(cand @ n - n @ a) < thresh
        if inl.sum() > best_count:
            best, best_count = inl, int(inl.sum())
    if best is None or best_count < 10:
        return None
    pts = cand[best]
    mean = pts.mean(0)
    n = np.linalg.svd(pts - mean)[2][2]
    n = n if n @ up > 0 else -n
    return Floor(n, float(n @ mean), best_count, len(cand), pts)


def parse_distance(text: str, views: int) -> tuple[int, int, float]:
    """``"0,1=2.5"`` -> (0, 1, 2.5): views i and j are 2.5 m apart. Raises UserError."""
    try:
        pair, metres = text.split("=")
        i, j = (int(x) for x in pair.split(","))
        m = float(metres)
    except ValueError:
        raise UserError(f"--distance: expected I,J=METRES such as 0,1=2.5, got {text!r}") from None
    if not (0 <= i < views and 0 <= j < views) or i == j:
        raise UserError(f"--distance {text}: need two different views of the {views} (0-based)")
    if not np.isfinite(m) or m <= 0:
        raise UserError(f"--distance {text}: the distance must be positive metres")
    return i, j, m


#: Camera heights above this many metres are warned about (a unit mistake, most likely).
HIGH_CAMERA_M = 5.0


def parse_heights(text: str, views: int) -> np.ndarray:
    """``"1.6"`` (every view) or ``"1.6,1.62,1.7"`` (one per view) -> heights [V] in metres."""
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        raise UserError(f"--camera-height: expected metres, got {text!r}") from None
    if len(values) == 1:
        values = values * views
    if len(values) != views:
        raise UserError(f"--camera-height: give one height or {views} (one per view), got {text}")
    heights = np.array(values)
    if not np.all(np.isfinite(heights) & (heights > 0)):
        raise UserError(f"--camera-height {text}: heights must be positive metres")
    if heights.max() > HIGH_CAMERA_M:  # 160 for a camera 160 cm up: a scene 100 times too big
        print(
            f"warning: --camera-height {text}: {heights.max():g} m above the floor; heights "
            f"are in metres ({heights.max() / 100:g} for {heights.max():g} cm)",
            file=sys.stderr,
            flush=True,
        )
    return heights


def scale_from_heights(estimated: np.ndarray, given: np.ndarray) -> float:
    """Least-squares factor s minimising sum (s * estimated - given)^2 (both [V])."""
    return float(estimated @ given / (estimated @ estimated))


def scale_from_distance(c2w: np.ndarray, i: int, j: int, metres: float) -> float:
    """Factor that makes views i and j ``metres`` apart."""
    d = float(np.linalg.norm(c2w[i, :3, 3] - c2w[j, :3, 3]))
    if d < 1e-9:
        raise UserError(f"--distance: views {i} and {j} have the same estimated centre")
    return metres / d


@dataclass(frozen=True)
class Metric:
    """Upright, metric poses and how they were made so."""

    c2w: np.ndarray
    """[V, 4, 4] camera-to-world, canonical world frame, metres."""
    points: np.ndarray
    """[P, 3] the triangulated points in the same frame."""
    lines: list[str]
    """The report: upright and scale, one line each."""


def make_metric(
    c2w: np.ndarray,
    points: np.ndarray,
    heights: np.ndarray | None = None,
    distance: tuple[int, int, float] | None = None,
) -> Metric:
    """Level, place and scale reconstructed poses [V, 4, 4] (and points [P, 3]).

    Up is the floor plane's normal where a floor is found (within 15 degrees of the cameras'
    mean up axis) and the cameras' own up axes disagree (`LEVEL_TOLERANCE_DEG`), else that
    axis. Scale: ``heights`` [V] (metres above the floor, needs the
    floor), else ``distance`` (i, j, metres), else the assumed height `ASSUMED_HEIGHT_M` (or,
    without a floor, a first-to-last distance of 1 m), each stated in the report.
    """
    cam_up = camera_up(c2w)
    floor = fit_floor(points, c2w[:, :3, 3], cam_up)
    lines = []
    # Captures that agree with each other on up were levelled (a 360 camera levels its
    # panoramas; separate set-ups that share one tilt are rare), and a floor fitted to a few
    # low points of a bare floor can be tilted: then the cameras' up is kept.
    spread = float(np.degrees(np.arccos(np.clip(c2w[:, :3, 1] @ cam_up, -1, 1))).max())
    if floor is not None:
        tilt = np.degrees(np.arccos(np.clip(floor.normal @ cam_up, -1, 1)))
        found = f"floor plane from {floor.inliers} of {floor.candidates} low points"
        if tilt <= LEVEL_TOLERANCE_DEG or spread <= LEVEL_TOLERANCE_DEG:
            up, offset = cam_up, float(np.median(floor.points @ cam_up))
            agree = (
                "so the cameras are level"
                if tilt <= LEVEL_TOLERANCE_DEG
                else f"but the cameras agree on up within {spread:.2f} deg, so they are level"
            )
            lines.append(
                f"upright: {found}; its normal is {tilt:.2f} deg from the cameras' mean up "
                f"axis, {agree}: kept their up axis"
            )
        else:
            up, offset = floor.normal, floor.offset
            lines.append(
                f"upright: {found}; its normal is {tilt:.2f} deg from the cameras' mean up "
                "axis: corrected to the floor's normal"
            )
    else:
        up, offset = cam_up, None
        lines.append("upright: no floor plane found; assumed level cameras (their mean up axis)")
    canon = canonical_frame(c2w, up, offset)
    est_heights = canon[:, 1, 3] if floor is not None else None
    if heights is not None:
        if est_heights is None or np.any(est_heights <= 0):
            raise UserError(
                "--camera-height: no floor plane was found below the cameras; "
                "give --distance I,J=METRES instead"
            )
        s = scale_from_heights(est_heights, heights)
        lines.append(
            "scale: camera heights "
            + ", ".join(f"{h:.3f}" for h in heights)
            + f" m given (fit residual {np.abs(s * est_heights - heights).max():.3f} m)"
        )
    elif distance is not None:
        i, j, m = distance
        s = scale_from_distance(canon, i, j, m)
        lines.append(f"scale: views {i} and {j} are {m} m apart (given)")
    elif est_heights is not None and np.all(est_heights > 0):
        s = ASSUMED_HEIGHT_M / float(est_heights.mean())
        lines.append(
            f"scale: ASSUMED mean camera height {ASSUMED_HEIGHT_M} m (no --camera-height or "
            "--distance given): distances are only as right as that guess"
        )
    else:
        s = 1.0 / float(np.linalg.norm(canon[0, :3, 3] - canon[-1, :3, 3]))
        lines.append(
            "scale: ASSUMED 1 m between the first and last view (no floor found, no "
            "--camera-height or --distance given)"
        )
    final = scale_centres(canon, s)
    if floor is not None:
        lines.append(
            "camera heights above the floor (m): " + ", ".join(f"{h:.3f}" for h in final[:, 1, 3])
        )
    world = _world_change(c2w[0], canon[0])
    pts = (points @ world[:3, :3].T + world[:3, 3]) * s
    return Metric(final, pts, lines)


def _world_change(before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """The world transform [4, 4] that took one camera pose ``before`` to ``after``."""
    return after @ np.linalg.inv(before)
