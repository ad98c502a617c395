"""Slow, obviously-correct reference for the GL depth: CPU ray casting with trimesh.

Used by the tests (and nothing on a hot path): for every ERP pixel centre, the first triangle
hit along the pixel's ray and its distance from the camera centre.
"""

from __future__ import annotations

import numpy as np
import torch
import trimesh

from panogrf.model.erp import erp_directions


def _cast(mesh: trimesh.Trimesh, c2w: np.ndarray, height: int, width: int):
    """Nearest hit per pixel: (triangle index [H*W], -1 for none; distance [H*W], inf for none)."""
    dirs_cam = erp_directions(height, width, dtype=torch.float64).reshape(-1, 3).numpy()
    c2w = np.asarray(c2w, np.float64)
    dirs = dirs_cam @ c2w[:3, :3].T
    origins = np.broadcast_to(c2w[:3, 3], dirs.shape).copy()
    # Plain numpy triangle tests (no Embree): slow but exact, what a reference should be.
    intersector = trimesh.ray.ray_triangle.RayMeshIntersector(mesh)
    tri, ray, loc = intersector.intersects_id(
        origins, dirs, multiple_hits=True, return_locations=True
    )
    dist = np.linalg.norm(loc - origins[ray], axis=1)
    best = np.full(len(dirs), np.inf)
    np.minimum.at(best, ray, dist)
    first = np.full(len(dirs), -1, np.int64)
    is_first = dist <= best[ray]
    first[ray[is_first]] = tri[is_first]
    return first, best


def raycast_depth(mesh: trimesh.Trimesh, c2w: np.ndarray, height: int, width: int) -> np.ndarray:
    """Spherical depth [H, W] (metres, 0 = no hit) of camera ``c2w`` [4, 4] looking at ``mesh``."""
    _, dist = _cast(mesh, c2w, height, width)
    dist[~np.isfinite(dist)] = 0.0
    return dist.reshape(height, width).astype(np.float32)


def first_hits(mesh: trimesh.Trimesh, c2w: np.ndarray, height: int, width: int) -> np.ndarray:
    """Index of the first triangle hit by every pixel's ray [H*W] (-1 where nothing is hit)."""
    return _cast(mesh, c2w, height, width)[0]
