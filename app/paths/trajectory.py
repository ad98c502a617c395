"""Smooth camera paths through keyframes: positions on a Catmull-Rom spline, rotations on a
quaternion Bezier spline.

A keyframe is a camera-to-world pose [4, 4] (OpenGL frame, metres). `sample_keyframes` returns
the pose at any time (seconds): segment k (keyframe k to k + 1) lasts ``durations[k]`` (one
second each by default); inside it the position follows the centripetal Catmull-Rom spline (it
passes through every keyframe, never overshoots into loops) and the rotation a cubic Bezier
curve on the unit quaternions (De Casteljau with slerp, Shoemake 1985) whose inner control
points give every keyframe one angular velocity, the time-weighted mean of its two
neighbouring arcs: the rotation passes through the keyframes without stopping or turning
abruptly (C1 in time; slerp per segment stopped at every keyframe). `interpolate_keyframes`
samples it at evenly spaced frames. ``cycle`` closes the path back to the first keyframe.
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


def quaternion_log(q: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) -> its logarithm, a 3-vector (half the rotation vector),
    of the rotation's shorter way round (q and -q are the same rotation)."""
    q = np.asarray(q, np.float64) * (-1.0 if q[0] < 0 else 1.0)
    w, v = float(np.clip(q[0], -1.0, 1.0)), q[1:]
    n = float(np.linalg.norm(v))
    if n < 1e-12:
        return v.copy()
    return v * (np.arctan2(n, w) / n)


def quaternion_exp(v: np.ndarray) -> np.ndarray:
    """3-vector -> unit quaternion exp((0, v)) (the inverse of `quaternion_log`)."""
    v = np.asarray(v, np.float64)
    n = float(np.linalg.norm(v))
    if n < 1e-12:
        return np.array([1.0, *v]) / np.sqrt(1.0 + n * n)
    return np.array([np.cos(n), *(np.sin(n) / n * v)])


def quaternion_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of quaternions (w, x, y, z)."""
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def _conj(q: np.ndarray) -> np.ndarray:
    return np.array([q[0], -q[1], -q[2], -q[3]])


def _rotation_controls(quats: np.ndarray, durations: np.ndarray, cycle: bool) -> list[tuple]:
    """Per segment k: the Bezier control quaternions (q_k, a_k, b_k, q_k+1).

    Each keyframe gets one body-frame rate v_k (dq/dt = q v), the time-weighted mean of the
    rates of its two arcs (at the ends of an open path, the one arc's); a_k = q_k exp(v_k T/3)
    and b_k = q_k+1 exp(-v_k+1 T/3) make the curve leave and reach its keyframes at exactly
    those rates (a Bezier's end derivative is 3 x its end leg), so the rate is continuous."""
    k = len(quats)
    segments = len(durations)

    def arc(i: int) -> np.ndarray:  # body-frame rate along segment i (rad/2 per second)
        q0, q1 = quats[i % k], quats[(i + 1) % k]
        return quaternion_log(quaternion_multiply(_conj(q0), q1)) / durations[i]

    rates = []
    for i in range(k):
        before = i - 1 if (cycle or i > 0) else None
        after = i if (cycle or i < k - 1) else None
        if before is None:
            rates.append(arc(after))
        elif after is None:
            rates.append(arc(before % segments))
        else:
            t0, t1 = durations[before % segments], durations[after]
            # Weights of a non-uniform central difference: the shorter arc counts more.
            rates.append((t1 * arc(before % segments) + t0 * arc(after)) / (t0 + t1))
    controls = []
    for i in range(segments):
        q0, q1, t = quats[i % k], quats[(i + 1) % k], durations[i]
        a = quaternion_multiply(q0, quaternion_exp(rates[i % k] * t / 3))
        b = quaternion_multiply(q1, quaternion_exp(-rates[(i + 1) % k] * t / 3))
        controls.append((q0, a, b, q1))
    return controls


def _bezier_rotation(controls: tuple, t: float) -> np.ndarray:
    """De Casteljau on the unit quaternions: a cubic Bezier at t in [0, 1]."""
    q0, a, b, q1 = controls
    p01, p12, p23 = slerp(q0, a, t), slerp(a, b, t), slerp(b, q1, t)
    return slerp(slerp(p01, p12, t), slerp(p12, p23, t), t)


def _check_keys(keyframes: np.ndarray, durations, cycle: bool) -> tuple[np.ndarray, np.ndarray]:
    keys = np.asarray(keyframes, np.float64)
    if keys.ndim != 3 or keys.shape[1:] != (4, 4) or len(keys) == 0:
        raise ValueError(f"keyframes must be [K, 4, 4] with K >= 1, got {keys.shape}")
    segments = len(keys) if cycle else len(keys) - 1
    d = np.ones(segments) if durations is None else np.asarray(durations, np.float64)
    if d.shape != (segments,) or not np.all(np.isfinite(d)) or not np.all(d > 0):
        raise ValueError(
            f"durations must be {segments} positive seconds (one per segment), got {d.tolist()}"
        )
    return keys, d


def path_duration(keyframes: np.ndarray, durations=None, cycle: bool = False) -> float:
    """Seconds from the first keyframe to the end of the path."""
    return float(_check_keys(keyframes, durations, cycle)[1].sum())


def sample_keyframes(
    keyframes: np.ndarray, times: np.ndarray, durations=None, cycle: bool = False
) -> np.ndarray:
    """Poses [N, 4, 4] at ``times`` [N] (seconds from the first keyframe, clipped to the path)
    on the smooth path through keyframes [K, 4, 4]; ``durations`` [K - 1] (cycle: [K]) are
    the seconds of each segment (default: 1 each)."""
    keys, durations = _check_keys(keyframes, durations, cycle)
    times = np.atleast_1d(np.asarray(times, np.float64))
    k = len(keys)
    if k == 1:
        return np.repeat(keys, len(times), axis=0)
    pos = keys[:, :3, 3]
    quats = [rotation_to_quaternion(m[:3, :3]) for m in keys]
    for i in range(1, k):  # one hemisphere along the path: every arc the shorter one
        if np.dot(quats[i], quats[i - 1]) < 0:
            quats[i] = -quats[i]
    controls = _rotation_controls(np.array(quats), durations, cycle)
    starts = np.concatenate(([0.0], np.cumsum(durations)))
    segments = len(durations)
    out = np.tile(np.eye(4), (len(times), 1, 1))
    for f, time in enumerate(np.clip(times, 0.0, starts[-1])):
        i = int(np.clip(np.searchsorted(starts, time, side="right") - 1, 0, segments - 1))
        t = float(np.clip((time - starts[i]) / durations[i], 0.0, 1.0))

        def at(j: int) -> np.ndarray:
            return pos[j % k] if cycle else pos[min(max(j, 0), k - 1)]

        p0, p1, p2, p3 = at(i - 1), at(i), at(i + 1), at(i + 2)
        if not cycle:  # reflect the missing outer control points: the ends stay straight
            if i == 0:
                p0 = 2 * p1 - p2
            if i + 2 > k - 1:
                p3 = 2 * p2 - p1
        out[f, :3, 3] = _catmull_rom(p0, p1, p2, p3, t)
        out[f, :3, :3] = quaternion_to_rotation(_bezier_rotation(controls[i], t))
    return out


def frame_times(frames: int, duration: float, cycle: bool = False) -> np.ndarray:
    """Times [frames] of evenly spaced frames over ``duration`` seconds: the first at 0; the
    last at the end (an open path) or one step short of it (a cycle, whose end is its start)."""
    if frames < 1:
        raise ValueError(f"frames must be at least 1, got {frames}")
    if cycle:
        return np.arange(frames) * (duration / frames)
    return np.linspace(0.0, duration, frames) if frames > 1 else np.zeros(1)


def interpolate_keyframes(
    keyframes: np.ndarray, frames: int, cycle: bool = False, durations=None
) -> np.ndarray:
    """Poses [frames, 4, 4] at evenly spaced times along the smooth path through keyframes
    [K, 4, 4] (K >= 1), segments lasting ``durations`` (default: equal).

    The first output frame is the first keyframe; without ``cycle`` the last output frame is
    the last keyframe, with it the path returns towards the first.
    """
    if frames < 1:
        raise ValueError(f"frames must be at least 1, got {frames}")
    total = path_duration(keyframes, durations, cycle) if len(keyframes) else 0.0
    return sample_keyframes(keyframes, frame_times(frames, total, cycle), durations, cycle)


def sample_values(values: np.ndarray, times: np.ndarray, durations=None, cycle=False):
    """A per-keyframe number (e.g. the field of view) at ``times``: linear between keyframes."""
    values = np.asarray(values, np.float64)
    segments = len(values) if cycle else len(values) - 1
    d = np.ones(max(segments, 0)) if durations is None else np.asarray(durations, np.float64)
    starts = np.concatenate(([0.0], np.cumsum(d)))
    ends = np.append(values, values[0]) if cycle else values
    return np.interp(np.asarray(times, np.float64), starts, ends)
