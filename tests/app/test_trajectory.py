"""Camera-path interpolation: through every keyframe, smooth, rigid, slerped rotations."""

from __future__ import annotations

import numpy as np
import pytest

from panogrf.app.trajectory import (
    interpolate_keyframes,
    quaternion_to_rotation,
    rotation_to_quaternion,
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
