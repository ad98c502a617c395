"""Checks of poses shared by the scene validator (`panogrf.app.scene.check`), camera paths
(`panogrf.app.paths.camera_path`) and every writer of a scene: one rigid pose within reach
(`pose_problems`), views at distinct positions (`same_position_problems`), both together
(`poses_problems`), and JSON numbers read as an array (`number_array`); photos too far apart to
share anything are warned about (`far_apart_warning`).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

#: Largest allowed max |R^T R - I| (and last-row deviation) of a pose.
POSE_TOLERANCE = 1e-4
#: At most this many pairs of frames (at one position, or reading one panorama) are listed.
MAX_LISTED_PAIRS = 20
#: Two views closer than this (metres) are "at the same position": no baseline to triangulate.
MIN_VIEW_SEPARATION_M = 1e-3
#: Largest camera position (metres from the world's origin) a scene may hold: a geo-referenced
#: capture is within 1e7 m of its grid's origin; far larger numbers are a broken export.
MAX_POSITION_M = 1e9
#: A photo farther than this (metres) from every other one shares nothing with them to render
#: from: most likely poses in millimetres (or another unit) read as metres.
FAR_APART_M = 1000.0


def number_array(value: Any) -> np.ndarray:
    """A JSON value (nested lists of numbers) -> float64 array; ValueError saying what is wrong."""
    stack = [value]
    while stack:
        item = stack.pop()
        if isinstance(item, list):
            stack.extend(item)
        elif isinstance(item, bool) or not isinstance(item, (int, float)):
            raise ValueError(f"contains a non-number ({_short(item)})")
    try:
        return np.array(value, dtype=np.float64)
    except ValueError:
        raise ValueError("is not a rectangular list of numbers") from None


def pose_problems(m: np.ndarray, tol: float = POSE_TOLERANCE) -> list[str]:
    """Problems of a [4, 4] camera-to-world matrix: finite, rigid (R^T R = I, det +1), last row,
    a position within `MAX_POSITION_M`."""
    if not np.isfinite(m).all():
        return ["contains NaN or infinite values"]
    problems = []
    if np.abs(m[:3, 3]).max() > MAX_POSITION_M:
        problems.append(
            f"position {_fmt_row(m[:3, 3])} is farther than {MAX_POSITION_M:g} m from the origin"
        )
    if np.abs(m[3] - (0.0, 0.0, 0.0, 1.0)).max() > tol:
        problems.append(f"last row is {_fmt_row(m[3])}, expected [0, 0, 0, 1]")
    r = m[:3, :3]
    err = float(np.abs(r.T @ r - np.eye(3)).max())
    if err > tol:
        problems.append(f"rotation is not orthonormal (max |R^T R - I| = {err:.3g})")
    elif np.linalg.det(r) < 0:
        problems.append("rotation is a reflection (det = -1); expected det = +1")
    return problems


def same_position_problems(frames: Sequence[int], centres: Sequence[np.ndarray]) -> list[str]:
    """One problem per pair of views under `MIN_VIEW_SEPARATION_M` apart (``frames[k]`` is the
    frame index of ``centres[k]``), the first `MAX_LISTED_PAIRS` of them after a count."""
    if len(centres) < 2:
        return []
    points = np.stack(centres)
    pairs = cKDTree(points).query_pairs(MIN_VIEW_SEPARATION_M, output_type="ndarray")
    pairs = pairs.reshape(-1, 2)
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    problems = []
    if len(pairs) > MAX_LISTED_PAIRS:  # one view copied many times: n^2 / 2 pairs
        problems.append(
            f"{len(pairs)} pairs of frames are at the same position (under "
            f"{1000 * MIN_VIEW_SEPARATION_M:g} mm apart); the first {MAX_LISTED_PAIRS} follow"
        )
    for a, b in pairs[:MAX_LISTED_PAIRS].tolist():
        dist_mm = 1000.0 * float(np.linalg.norm(points[a] - points[b]))
        problems.append(
            f"frames[{frames[a]}] and frames[{frames[b]}]: views at the same position "
            f"({dist_mm:.2f} mm apart); views must be at least "
            f"{MIN_VIEW_SEPARATION_M * 1000:g} mm apart"
        )
    return problems


def poses_problems(c2w: np.ndarray) -> list[str]:
    """What `panogrf scene check` would say of these poses [V, 4, 4] (each a rigid pose within
    reach, no two views at one position): a writer checks them before it writes a scene."""
    problems: list[str] = []
    frames, centres = [], []
    for i, m in enumerate(np.asarray(c2w, np.float64)):
        bad = pose_problems(m)
        problems.extend(f"frames[{i}].transform_matrix: {p}" for p in bad)
        if not bad:
            frames.append(i)
            centres.append(m[:3, 3])
    problems.extend(same_position_problems(frames, centres))
    return problems


def far_apart_warning(c2w: np.ndarray) -> str | None:
    """A warning when a photo of poses [V, 4, 4] is more than `FAR_APART_M` from the nearest
    other (the one farthest from its nearest named), else None. Distances between neighbours,
    not from the origin: a geo-referenced capture sits far from its grid's origin, and a long
    walk spans kilometres with its photos metres apart."""
    centres = np.asarray(c2w, np.float64)[:, :3, 3]
    if len(centres) < 2:
        return None
    dist, nearest = cKDTree(centres).query(centres, k=2)
    far = int(np.argmax(dist[:, 1]))
    if not dist[far, 1] > FAR_APART_M:
        return None
    return (
        f"photos {dist[far, 1]:.0f} m apart (frames[{far}] and its nearest, "
        f"frames[{nearest[far, 1]}]): check the units of the poses (metres expected)"
    )


def _short(value: Any) -> str:
    text = json.dumps(value) if isinstance(value, (str, bool, dict, type(None))) else repr(value)
    return text if len(text) <= 30 else text[:27] + "..."


def _fmt_row(row: np.ndarray) -> str:
    return "[" + ", ".join(f"{x:g}" for x in row) + "]"
