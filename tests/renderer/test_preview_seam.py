"""The per-frame seam split of the GL preview's meshes (`preview_mesh.split_seam`) against a
triangle-by-triangle reference: which triangles are drawn as they are, which cross the target's
seam, which surround a pole and are dropped (only a triangle with corners on both sides of the
target's x = 0 plane can do either). No GL."""

from __future__ import annotations

import numpy as np
import pytest

from panogrf.renderer.preview_mesh import MAX_LON_SPAN, sphere_mesh, split_seam


def _reference(points: np.ndarray, tris: np.ndarray, w2c: np.ndarray):
    ordinary, crossing = [], []
    for tri in tris:
        cam = points[tri].astype(np.float64) @ w2c[:3, :3].T + w2c[:3, 3]
        lon = np.arctan2(cam[:, 0], -cam[:, 2]) / np.pi  # [-1, 1]
        if len(set(cam[:, 0] >= 0)) == 1 or np.ptp(lon) <= MAX_LON_SPAN:
            ordinary.append(tri)
        elif np.ptp(np.where(lon < 0, lon + 2, lon)) <= MAX_LON_SPAN:
            crossing.append(tri)
    empty = np.zeros((0, 3), tris.dtype)
    return np.array(ordinary or empty, tris.dtype), np.array(crossing or empty, tris.dtype)


@pytest.mark.parametrize("seed", range(6))
def test_the_seam_split_matches_a_triangle_by_triangle_reference(seed):
    rng = np.random.default_rng(seed)
    uv, tris = sphere_mesh(24)
    lon = 2 * np.pi * (uv[:, 0].astype(np.float64) - 0.5)
    lat = np.pi * (0.5 - uv[:, 1].astype(np.float64))
    dirs = np.stack((np.cos(lat) * np.sin(lon), np.sin(lat), -np.cos(lat) * np.cos(lon)), -1)
    points = (dirs * rng.uniform(1.0, 3.0, (len(uv), 1))).astype(np.float32)
    tris = np.ascontiguousarray(tris[rng.permutation(len(tris))])  # any order is kept
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    c2w = np.eye(4)
    c2w[:3, :3] = q * np.sign(np.linalg.det(q))
    c2w[:3, 3] = rng.normal(0.0, 0.3, 3)
    w2c = np.linalg.inv(c2w)

    ordinary, crossing = split_seam(points, np.ascontiguousarray(tris.T), tris, w2c)
    want_ordinary, want_crossing = _reference(points, tris, w2c)
    assert len(crossing) > 0 and len(ordinary) + len(crossing) < len(tris)  # all three kinds
    np.testing.assert_array_equal(ordinary, want_ordinary)
    np.testing.assert_array_equal(crossing, want_crossing)
    assert ordinary.dtype == tris.dtype and ordinary.flags.c_contiguous
