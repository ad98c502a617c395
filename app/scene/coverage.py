"""Is a camera inside the region its source panoramas cover, and not inside an object?

A view rendered far from every source shows holes and stretched geometry; the viewer and
``render --camera-path`` warn about it. The covered region: within `FACTOR` times the largest
spacing between source centres of the nearest source (at least `MIN_RADIUS_M`), which keeps
the middle of a triplet (half the spacing away) well inside. A camera behind the surface that
its nearest source sees in its direction is inside an object or behind a wall
(`behind_surface`; the viewer warns). Poses are camera-to-world [.., 4, 4], metres.
"""

from __future__ import annotations

import numpy as np

#: Covered radius around each source, as a multiple of the largest source spacing.
FACTOR = 0.75
#: Covered radius never below this (one source, or sources very close together), metres.
MIN_RADIUS_M = 0.5


def covered_radius(sources: np.ndarray) -> float:
    """Radius (m) around each source centre inside which a camera counts as covered."""
    c = np.asarray(sources)[:, :3, 3]
    spacing = float(np.linalg.norm(c[:, None] - c[None], axis=-1).max()) if len(c) > 1 else 0.0
    return max(FACTOR * spacing, MIN_RADIUS_M)


def nearest_source_distance(targets: np.ndarray, sources: np.ndarray) -> np.ndarray:
    """Distance (m) of every target camera [N, 4, 4] to its nearest source [V, 4, 4]: [N]."""
    t = np.asarray(targets)[:, None, :3, 3]
    s = np.asarray(sources)[None, :, :3, 3]
    return np.linalg.norm(t - s, axis=-1).min(axis=1)


def uncovered(targets: np.ndarray, sources: np.ndarray) -> np.ndarray:
    """[N] bool: the targets outside the covered region."""
    return nearest_source_distance(targets, sources) > covered_radius(sources)


def frame_ranges(indices: np.ndarray) -> str:
    """[3, 4, 5, 9] -> "3-5, 9"."""
    out, idx = [], [int(i) for i in indices]
    start = prev = None
    for i in [*idx, None]:
        if start is not None and (i is None or i != prev + 1):
            out.append(f"{start}-{prev}" if prev != start else f"{start}")
            start = None
        if i is not None and start is None:
            start = i
        prev = i
    return ", ".join(out)


def path_warning(targets: np.ndarray, sources: np.ndarray) -> str | None:
    """A one-line warning naming the frames of a camera path outside the covered region."""
    far = np.flatnonzero(uncovered(targets, sources))
    if not len(far):
        return None
    worst = float(nearest_source_distance(targets[far], sources).max())
    return (
        f"warning: {len(far)} of {len(targets)} frames leave the region the sources cover "
        f"(farther than {covered_radius(sources):.2f} m from every source, up to {worst:.2f} m): "
        f"frames {frame_ranges(far)}; expect holes and stretched geometry there"
    )


#: A camera farther than this factor times the surface its nearest source sees in its
#: direction is behind that surface (the margin absorbs the estimated depth's error).
BEHIND_FACTOR = 1.15


def behind_surface(
    position: np.ndarray, sources: np.ndarray, depth: np.ndarray
) -> tuple[int, float, float] | None:
    """Is a camera at ``position`` [3] (world, metres) behind the surface its nearest source
    [V, 4, 4] sees in its direction? depth [V, h, w]: each source's distance per ERP pixel
    (metres, 0 unknown). Returns (source, camera distance, surface distance) or None."""
    centres = np.asarray(sources)[:, :3, 3]
    k = int(np.argmin(np.linalg.norm(centres - position, axis=-1)))
    v = np.asarray(sources[k])[:3, :3].T @ (np.asarray(position, np.float64) - centres[k])
    dist = float(np.linalg.norm(v))
    if dist < 1e-6:
        return None
    h, w = depth.shape[1:]
    lon = np.arctan2(v[0], -v[2])
    lat = np.arcsin(np.clip(v[1] / dist, -1.0, 1.0))
    row = min(int((0.5 - lat / np.pi) * h), h - 1)
    col = min(int((lon / (2 * np.pi) + 0.5) * w), w - 1)
    surface = float(depth[k, row, col])
    if surface <= 0 or dist <= BEHIND_FACTOR * surface:
        return None
    return k, dist, surface


def inside_warning(targets: np.ndarray, sources: np.ndarray, depth: np.ndarray) -> str | None:
    """A one-line warning naming the frames of a camera path whose camera is behind the surface
    its nearest source sees (inside an object or beyond a wall); depth [V, h, w] metres."""
    hits = [
        (i, hit)
        for i, pose in enumerate(np.asarray(targets))
        if (hit := behind_surface(pose[:3, 3], sources, depth)) is not None
    ]
    if not hits:
        return None
    k, dist, surface = hits[0][1]
    return (
        f"warning: {len(hits)} of {len(targets)} frames put the camera behind a surface (inside "
        f"an object or beyond a wall): frames {frame_ranges(np.array([i for i, _ in hits]))}; "
        f"frame {hits[0][0]} is {dist:.2f} m from source {k}, whose surface there is "
        f"{surface:.2f} m away"
    )
