"""Camera-path interpolation: through every keyframe, smooth (C1 positions and rotations), rigid."""

from __future__ import annotations

import numpy as np
import pytest

from panogrf.app.paths.trajectory import (
    interpolate_keyframes,
    path_duration,
    quaternion_to_rotation,
    rotation_to_quaternion,
    sample_keyframes,
    sample_values,
    slerp,
)


def _rot(axis: int, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    r = np.eye(3)
    r[i, i] = r[j, j] = c
    r[i, j], r[j, i] = -s, s
    return r


def _pose(r: np.ndarray, t) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, t
    return m


KEYS = np.stack(
    [
        _pose(_rot(1, 0.0), [0, 1.5, 0]),
        _pose(_rot(1, 0.8) @ _rot(0, 0.2), [1, 1.6, -0.5]),
        _pose(_rot(1, 2.5), [2, 1.4, 0.3]),
        _pose(_rot(1, -2.9) @ _rot(2, 0.1), [2.5, 1.5, 1.5]),
    ]
)


@pytest.mark.parametrize("seed", range(5))
def test_quaternion_round_trip(seed):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    r = quaternion_to_rotation(q)
    assert np.allclose(r @ r.T, np.eye(3), atol=1e-12) and np.linalg.det(r) > 0
    q2 = rotation_to_quaternion(r)
    assert np.allclose(q2, q) or np.allclose(q2, -q)


def test_slerp_ends_midpoint_and_shorter_arc():
    q0 = rotation_to_quaternion(_rot(1, 0.0))
    q1 = rotation_to_quaternion(_rot(1, 1.0))
    assert np.allclose(slerp(q0, q1, 0.0), q0) and np.allclose(slerp(q0, q1, 1.0), q1)
    assert np.allclose(quaternion_to_rotation(slerp(q0, q1, 0.5)), _rot(1, 0.5))
    # -q1 is the same rotation: the result must not take the long way round.
    assert np.allclose(quaternion_to_rotation(slerp(q0, -q1, 0.5)), _rot(1, 0.5))


def test_path_passes_through_every_keyframe_and_stays_rigid():
    frames = 31  # keyframes at frames 0, 10, 20, 30
    path = interpolate_keyframes(KEYS, frames)
    assert path.shape == (frames, 4, 4)
    for k, f in enumerate((0, 10, 20, 30)):
        assert np.allclose(path[f], KEYS[k], atol=1e-9)
    for m in path:
        assert np.allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-9)
        assert np.allclose(m[3], [0, 0, 0, 1])


def test_path_is_smooth():
    path = interpolate_keyframes(KEYS, 301)
    pos = path[:, :3, 3]
    step = np.linalg.norm(np.diff(pos, axis=0), axis=-1)
    # No jumps: consecutive frames move by comparable amounts (C1 position spline).
    assert step.max() < 3 * np.median(step)
    accel = np.linalg.norm(np.diff(pos, 2, axis=0), axis=-1)
    assert accel.max() < 10 * np.median(accel) + 1e-6
    # Rotations change gradually too (no frame turns more than a few degrees).
    rel = np.einsum("nij,nkj->nik", path[1:, :3, :3], path[:-1, :3, :3])
    angle = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert angle.max() < 3.0


def test_cycle_returns_towards_the_start_and_one_keyframe_holds_still():
    path = interpolate_keyframes(KEYS, 40, cycle=True)
    assert np.allclose(path[0], KEYS[0])
    assert np.linalg.norm(path[-1, :3, 3] - KEYS[0, :3, 3]) < 0.3
    still = interpolate_keyframes(KEYS[:1], 5)
    assert np.allclose(still, KEYS[0])
    with pytest.raises(ValueError):
        interpolate_keyframes(np.zeros((0, 4, 4)), 5)
    with pytest.raises(ValueError):
        interpolate_keyframes(KEYS, 0)


def _angular_speed(path: np.ndarray, dt: float) -> np.ndarray:
    """Rotation angle per second between consecutive poses [N, 4, 4] -> [N - 1]."""
    rel = np.einsum("nij,nkj->nik", path[1:, :3, :3], path[:-1, :3, :3])
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)
    return np.arccos(cos) / dt


@pytest.mark.parametrize("durations", [None, [1.0, 3.0, 0.5]])
def test_rotation_does_not_stop_or_jump_at_keyframes(durations):
    # Keyframes turning the same way about y: slerp per segment stopped and restarted at each
    # (its angular velocity jumps at the keyframes); the rotation spline keeps it continuous.
    keys = np.stack([_pose(_rot(1, a), [0.5 * i, 0, 0]) for i, a in enumerate((0, 0.6, 1.5, 1.9))])
    d = np.ones(3) if durations is None else np.asarray(durations)
    starts = np.concatenate(([0.0], np.cumsum(d)))
    eps = 1e-4
    for t in starts[1:-1]:  # the inner keyframes
        before = sample_keyframes(keys, [t - 2 * eps, t - eps], durations)
        after = sample_keyframes(keys, [t + eps, t + 2 * eps], durations)
        w_before, w_after = _angular_speed(before, eps)[0], _angular_speed(after, eps)[0]
        assert w_before > 0.1
        assert abs(w_before - w_after) < 1e-2 * w_before, (t, w_before, w_after)
    # Still through every keyframe, at its time.
    at_keys = sample_keyframes(keys, starts, durations)
    assert np.allclose(at_keys, keys, atol=1e-9)


def test_angular_velocity_is_continuous_for_general_rotations():
    path = interpolate_keyframes(KEYS, 3001)
    rel = np.einsum("nij,nkj->nik", path[1:, :3, :3], path[:-1, :3, :3])
    # Angular velocity vectors (small-angle axis * angle) per step; no jump anywhere.
    w = (
        np.stack(
            [rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0], rel[:, 1, 0] - rel[:, 0, 1]],
            -1,
        )
        / 2
    )
    jump = np.linalg.norm(np.diff(w, axis=0), axis=-1)
    assert jump.max() < 20 * np.median(jump) + 1e-9, jump.max()


def test_durations_retime_segments_and_values_follow():
    slow_first = interpolate_keyframes(KEYS, 61, durations=[4.0, 1.0, 1.0])  # 6 s, 0.1 s/frame
    assert np.allclose(slow_first[40], KEYS[1], atol=1e-9)  # keyframe 1 at 4 s
    assert np.allclose(slow_first[50], KEYS[2], atol=1e-9)
    assert path_duration(KEYS, [4.0, 1.0, 1.0]) == pytest.approx(6.0)
    with pytest.raises(ValueError, match="durations"):
        interpolate_keyframes(KEYS, 10, durations=[1.0, -1.0, 1.0])
    fov = sample_values([60.0, 90.0, 40.0, 40.0], [0.0, 2.0, 4.5, 6.0], [4.0, 1.0, 1.0])
    assert np.allclose(fov, [60.0, 75.0, 65.0, 40.0])
    cyc = interpolate_keyframes(KEYS, 40, cycle=True, durations=[1.0, 1.0, 1.0, 1.0])
    assert np.allclose(cyc[0], KEYS[0]) and np.allclose(cyc[10], KEYS[1], atol=1e-9)
