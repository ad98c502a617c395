"""`panogrf.app.poses` geometry and scale: synthetic round trips on bearings (no rendering)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from panogrf.app.errors import UserError
from panogrf.app.poses import errors as er
from panogrf.app.poses import geometry as geo
from panogrf.app.poses import scale as sc


def _unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _scene(rng, n=400, tilt=0.0):
    """World points in a room and three camera poses (c2w, OpenGL) 1 m apart on a line."""
    points = rng.uniform([-3, 0, -3], [3, 2.6, 3], (n, 3))
    points[: n // 3, 1] = 0.0  # a floor at y = 0
    c2w = np.stack([np.eye(4)] * 3)
    for k in range(3):
        rot = Rotation.from_euler("y", rng.uniform(0, 360), degrees=True)
        rot = Rotation.from_rotvec([tilt, 0, 0]) * rot if tilt else rot
        c2w[k, :3, :3] = rot.as_matrix()
        c2w[k, :3, 3] = [0.5 * k - 0.5, 1.5 + 0.02 * k, 0.2 * k]
    return points, c2w


def _bearings(points, c2w, rng, noise=0.0):
    local = (points - c2w[:3, 3]) @ c2w[:3, :3]
    return _unit(
        local + noise * rng.normal(size=local.shape) * np.linalg.norm(local, axis=1)[:, None]
    )


def test_bundle_adjustment_recovers_poses_from_perturbed_start():
    rng = np.random.default_rng(3)
    points, c2w = _scene(rng, n=200)
    # The world is camera 0's frame (BA holds view 0 fixed).
    points = (points - c2w[0, :3, 3]) @ c2w[0, :3, :3]
    c2w = np.linalg.inv(c2w[0]) @ c2w
    w2c = np.linalg.inv(c2w)
    pts0 = np.stack([_bearings(points, m, rng, 5e-4) for m in c2w])
    view = np.repeat(np.arange(3), len(points))
    point = np.tile(np.arange(len(points)), 3)
    rots = w2c[:, :3, :3].copy()
    rots[1:] = Rotation.from_rotvec(rng.normal(0, 0.01, (2, 3))).as_matrix() @ rots[1:]
    trans = w2c[:, :3, 3] + np.r_[np.zeros((1, 3)), rng.normal(0, 0.02, (2, 3))]
    adj = geo.bundle_adjust(
        rots,
        trans,
        points + rng.normal(0, 0.05, points.shape),
        view,
        point,
        pts0.reshape(-1, 3),
        loss_scale=0.005,
    )
    est = np.stack(
        [
            np.linalg.inv(np.r_[np.c_[r, t], [[0, 0, 0, 1]]])
            for r, t in zip(adj.rots, adj.trans, strict=True)
        ]
    )
    errors = er.pair_errors(est, c2w)
    assert max(e["rotation_deg"] for e in errors) < 0.1
    assert max(e["translation_deg"] for e in errors) < 0.3
    assert np.degrees(np.median(adj.residuals)) < 0.1


def test_floor_upright_and_scale_from_heights():
    rng = np.random.default_rng(4)
    points, c2w = _scene(rng, n=600)
    # Move everything into a tilted, shifted, shrunk frame: make_metric must undo it.
    tilt = Rotation.from_rotvec([0.3, 1.0, -0.2]).as_matrix()
    s = 0.37
    moved = sc.transform_world(c2w, tilt, np.array([1.0, -2.0, 0.5]))
    moved[:, :3, 3] *= s
    pts = (points @ tilt.T + [1.0, -2.0, 0.5]) * s
    metric = sc.make_metric(moved, pts, heights=c2w[:, 1, 3])
    np.testing.assert_allclose(metric.c2w[:, 1, 3], c2w[:, 1, 3], atol=1e-6)
    assert max(e["rotation_deg"] for e in er.pair_errors(metric.c2w, c2w)) < 1e-4
    assert er.scale_error(metric.c2w, c2w) < 1e-6
    np.testing.assert_allclose(metric.c2w[:, :3, 1] @ [0, 1, 0], 1.0, atol=1e-9)  # level
    np.testing.assert_allclose(metric.c2w[0, [0, 2], 3], 0.0, atol=1e-9)
    assert abs(np.median(metric.points[:200, 1])) < 1e-6  # the floor at y = 0
    dist = sc.make_metric(moved, pts, distance=(0, 2, 2.0))
    assert abs(np.linalg.norm(dist.c2w[0, :3, 3] - dist.c2w[2, :3, 3]) - 2.0) < 1e-9
    assumed = sc.make_metric(moved, pts)
    assert abs(assumed.c2w[:, 1, 3].mean() - sc.ASSUMED_HEIGHT_M) < 1e-9
    assert any("ASSUMED" in line for line in assumed.lines)


def test_option_parsing_errors():
    assert sc.parse_distance("0,2=2.5", 3) == (0, 2, 2.5)
    np.testing.assert_allclose(sc.parse_heights("1.6", 3), [1.6] * 3)
    for bad in ("0,0=1", "0,5=1", "0-1=2", "0,1=-1"):
        with pytest.raises(UserError):
            sc.parse_distance(bad, 3)
    for bad in ("x", "1,2", "-1"):
        with pytest.raises(UserError):
            sc.parse_heights(bad, 3)
