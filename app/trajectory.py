"""Smooth camera paths through keyframes: positions on a Catmull-Rom spline, rotations by slerp.

A keyframe is a camera-to-world pose [4, 4] (OpenGL frame, metres). `interpolate_keyframes`
returns one pose per output frame: segment k (keyframe k to k + 1) takes an equal share of the
duration; inside it the position follows the centripetal Catmull-Rom spline (it passes through
every keyframe, never overshoots into loops) and the rotation the shortest great-circle arc
between the two keyframes' quaternions. ``cycle`` closes the path back to the first keyframe.
"""

from __future__ import annotations

import numpy as np


def rotation_to_quaternion(r: np.ndarray) -> np.ndarray:
    """3x3 rotation -> unit quaternion (w, x, y, z)."""
    m = np.asarray(r, np.float64)
    t = np.trace(m)
    if t > 0:
        s = 2.0 * np.sqrt(t + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k])
        q = np.empty(4)
        q[0] = (m[k, j] - m[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (m[j, i] + m[i, j]) / s
        q[1 + k] = (m[k, i] + m[i, k]) / s
    q = np.asarray(q, np.float64)
    return q / np.linalg.norm(q)


def quaternion_to_rotation(q: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) -> 3x3 rotation."""
    w, x, y, z = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def slerp(q0: np.ndarray, q1: np.ndarray, t: float) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions along the shorter arc."""
    dot = float(np.dot(q0, q1))
    if dot < 0.0:
        q1, dot = -q1, -dot
    if dot > 0.9995:  # nearly the same rotation: linear is exact enough and stable
        q = q0 + t * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(dot)
    return (np.sin((1 - t) * theta) * q0 + np.sin(t * theta) * q1) / np.sin(theta)


def _catmull_rom(p0, p1, p2, p3, t: float, alpha: float = 0.5) -> np.ndarray:
    """Centripetal Catmull-Rom point between p1 and p2 at t in [0, 1] (Barry-Goldman)."""

    def knot(ti, a, b):
        return ti + max(np.linalg.norm(b - a), 1e-9) ** alpha

    t0 = 0.0
    t1 = knot(t0, p0, p1)
    t2 = knot(t1, p1, p2)
    t3 = knot(t2, p2, p3)
    u = t1 + t * (t2 - t1)
    a1 = (t1 - u) / (t1 - t0) * p0 + (u - t0) / (t1 - t0) * p1
    a2 = (t2 - u) / (t2 - t1) * p1 + (u - t1) / (t2 - t1) * p2
    a3 = (t3 - u) / (t3 - t2) * p2 + (u - t2) / (t3 - t2) * p3
    b1 = (t2 - u) / (t2 - t0) * a1 + (u - t0) / (t2 - t0) * a2
    b2 = (t3 - u) / (t3 - t1) * a2 + (u - t1) / (t3 - t1) * a3
    return (t2 - u) / (t2 - t1) * b1 + (u - t1) / (t2 - t1) * b2


def interpolate_keyframes(keyframes: np.ndarray, frames: int, cycle: bool = False) -> np.ndarray:
    """Poses [frames, 4, 4] along the smooth path through keyframes [K, 4, 4] (K >= 1).

    The first output frame is the first keyframe; without ``cycle`` the last output frame is
    the last keyframe, with it the path returns towards the first.
    """
    keys = np.asarray(keyframes, np.float64)
    if keys.ndim != 3 or keys.shape[1:] != (4, 4) or len(keys) == 0:
        raise ValueError(f"keyframes must be [K, 4, 4] with K >= 1, got {keys.shape}")
    if frames < 1:
        raise ValueError(f"frames must be at least 1, got {frames}")
    k = len(keys)
    if k == 1:
        return np.repeat(keys, frames, axis=0)
    pos = keys[:, :3, 3]
    quats = [rotation_to_quaternion(m[:3, :3]) for m in keys]
    segments = k if cycle else k - 1
    out = np.tile(np.eye(4), (frames, 1, 1))
    for f in range(frames):
        s = f / frames * segments if cycle else (f / (frames - 1) * segments if frames > 1 else 0)
        i = min(int(s), segments - 1)
        t = s - i

        def at(j: int) -> np.ndarray:
            return pos[j % k] if cycle else pos[min(max(j, 0), k - 1)]

        p0, p1, p2, p3 = at(i - 1), at(i), at(i + 1), at(i + 2)
        if not cycle:  # reflect the missing outer control points: the ends stay straight
            if i == 0:
                p0 = 2 * p1 - p2
            if i + 2 > k - 1:
                p3 = 2 * p2 - p1
        out[f, :3, 3] = _catmull_rom(p0, p1, p2, p3, t)
        out[f, :3, :3] = quaternion_to_rotation(slerp(quats[i % k], quats[(i + 1) % k], t))
    return out
