"""The instant preview's depth meshes, on the CPU (`panogrf.renderer.gl_preview` draws them).

Each source panorama becomes a mesh over its (estimated) depth map: rows at pixel latitudes and
as many vertices per row as the row's circumference needs (`sphere_mesh`), lifted to the world
once (`_uv_world_points`), maybe simplified (`decimate`). Per frame, `split_seam` sorts a
source's triangles into those drawn as they are and those crossing the target's seam; those
around the target's poles are dropped.
"""

from __future__ import annotations

import numpy as np

#: A triangle is kept unless its depths differ more than a plane this oblique to the source's
#: rays (tan of the angle between ray and normal, here 80.5 deg) would make them differ at the
#: mesh's row spacing: beyond it the triangle spans a depth discontinuity (a "stretched"
#: triangle). The ratio of depths allowed is 1 + (pi / rows) * MAX_OBLIQUE_TAN: 1.15 at 128
#: rows, 1.29 at 64. A fixed ratio of 1.15 dropped floors and walls seen obliquely at 64 rows.
MAX_OBLIQUE_TAN = 6.0
#: Triangles whose longitudes (in half turns) spread wider than this surround a pole.
MAX_LON_SPAN = 0.5


def sphere_mesh(rows: int) -> tuple[np.ndarray, np.ndarray]:
    """A mesh of the sphere in ERP texture coordinates with as many vertices per row as its
    circumference needs: ``rows`` rows at pixel-centre latitudes, ``2 rows cos(lat)`` vertices
    on each (at least 3), so near the poles, where an ERP grid crowds its pixels, it does not
    crowd its triangles (about 36 % fewer than a full grid for the same rows).

    Returns uv [N, 2] float32 (each row ends with its first vertex again at u + 1, closing the
    seam with a repeating texture) and triangles [T, 3] int32, zipping neighbouring rows
    together in order of u."""
    v = (np.arange(rows) + 0.5) / rows
    cols = np.maximum(3, np.round(2 * rows * np.cos(np.pi * (0.5 - v)))).astype(np.int64)
    starts = np.concatenate(([0], np.cumsum(cols + 1)))
    uv = np.concatenate(
        [
            np.stack(((np.arange(n + 1) + 0.5) / n, np.full(n + 1, vr)), -1)
            for n, vr in zip(cols, v, strict=True)
        ]
    ).astype(np.float32)
    tris = []
    for r in range(rows - 1):
        n1, n2 = cols[r], cols[r + 1]
        top, bot = starts[r], starts[r + 1]
        # Every step advances along one row to its next vertex, the one with the smaller u.
        nxt = np.concatenate((uv[top + 1 : top + n1 + 1, 0], uv[bot + 1 : bot + n2 + 1, 0]))
        order = np.argsort(nxt, kind="stable")
        is_top = order < n1
        i = np.cumsum(is_top) - is_top  # top vertices passed before each step
        j = np.cumsum(~is_top) - ~is_top
        third = np.where(is_top, top + i + 1, bot + j + 1)
        tris.append(np.stack((top + i, bot + j, third), -1))
    return uv, np.concatenate(tris).astype(np.int32)


def _uv_world_points(
    uv: np.ndarray, depth: np.ndarray, c2w: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Depth [h, w] sampled (nearest) at ERP coordinates uv [N, 2] -> (world points [N, 3],
    the depths [N]) of a camera c2w [4, 4]."""
    h, w = depth.shape
    row = np.minimum((uv[:, 1] * h).astype(np.int64), h - 1)
    col = np.minimum(((uv[:, 0] % 1.0) * w).astype(np.int64), w - 1)
    d = depth[row, col].astype(np.float64)
    lon = 2 * np.pi * (uv[:, 0].astype(np.float64) - 0.5)
    lat = np.pi * (0.5 - uv[:, 1].astype(np.float64))
    dirs = np.stack((np.cos(lat) * np.sin(lon), np.sin(lat), -np.cos(lat) * np.cos(lon)), -1)
    cam = dirs * d[:, None]
    return cam @ c2w[:3, :3].T + c2w[:3, 3], d


def _uv_masked(uv: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``mask`` [h, w] (bool) read (nearest) at ERP coordinates uv [N, 2] -> [N] bool."""
    h, w = mask.shape
    row = np.minimum((uv[:, 1] * h).astype(np.int64), h - 1)
    col = np.minimum(((uv[:, 0] % 1.0) * w).astype(np.int64), w - 1)
    masked: np.ndarray = mask[row, col]
    return masked


def decimate(
    points: np.ndarray, tris: np.ndarray, target: int, c2w: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A source's depth mesh (world points [N, 3], triangles [T, 3]) simplified to at most
    ``target`` triangles by quadric edge collapse (fast_simplification), its open borders (the
    edges at depth discontinuities, the seam, the rows nearest the poles) kept where they are:
    flat walls and floors need few triangles, edges and furniture keep theirs. Returns (points,
    ERP texture coordinates in the source ``c2w`` [4, 4], triangles); a triangle that crosses
    the source's seam gets copies of its vertices at u + 1 (the texture repeats in u), as the
    undecimated mesh's last column has."""
    import fast_simplification
    import torch

    from panogrf.model.erp import world_to_erp

    used = np.unique(tris)
    index = np.full(len(points), -1, np.int64)
    index[used] = np.arange(len(used))
    pts, faces = fast_simplification.simplify(
        np.asarray(points[used], np.float64),
        index[tris].astype(np.int32),
        target_count=target,
        preserve_border=True,
    )
    # ERP coordinates in [0, 1]: the pixel coordinates in a 1 x 1 image, from its corner.
    pix, _ = world_to_erp(
        torch.from_numpy(pts), torch.from_numpy(np.asarray(c2w, np.float64)), 1, 1
    )
    uv = pix.numpy() + 0.5
    faces = np.asarray(faces, np.int64)
    u = uv[faces, 0]
    low = ((u.max(1) - u.min(1)) > 0.5)[:, None] & (u < 0.5)
    if low.any():
        dup, where = np.unique(faces[low], return_inverse=True)
        faces[low] = len(pts) + where
        pts = np.concatenate((pts, pts[dup]))
        uv = np.concatenate((uv, uv[dup] + [1.0, 0.0]))
    return pts.astype(np.float32), uv.astype(np.float32), faces.astype(np.int32)


def split_seam(
    points: np.ndarray, corners: np.ndarray, triangles: np.ndarray, w2c: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """A source's kept triangles (``triangles`` [T, 3] over world ``points`` [N, 3];
    ``corners``: the triangles transposed, [3, T]) for a target w2c: (ordinary, seam-crossing)
    index arrays; triangles around the target's poles are in neither.

    Only a triangle with vertices on both sides of the target's x = 0 plane can cross the
    seam (behind the target) or surround a pole (its vertices' longitudes then spread all
    round); longitude spans are computed for those alone. Any other triangle spans less
    than half a turn and is drawn as it is."""
    east = (points @ w2c[0, :3].astype(np.float32) >= -np.float32(w2c[0, 3])).view(np.uint8)
    e = np.take(east, corners)  # [3, T]: each corner's side
    suspect = ((e[0] ^ e[1]) | (e[0] ^ e[2])).view(bool)
    tris = triangles
    if not suspect.any():
        return tris, tris[:0]
    cand = tris[suspect]
    # The candidates' corners in the target's frame, x and z only: [3 S, 2].
    xz = points[cand.ravel()] @ w2c[(0, 2), :3].T.astype(np.float32)
    xz += w2c[(0, 2), 3].astype(np.float32)
    t = np.arctan2(xz[:, 0], -xz[:, 1]).reshape(-1, 3)
    t *= np.float32(1 / np.pi)  # longitude, [-1, 1]
    span = t.max(1) - t.min(1)
    u = np.where(t < 0, t + 2.0, t)
    wrapped = (span > 1.0) & ((u.max(1) - u.min(1)) <= MAX_LON_SPAN)
    ordinary = ~suspect
    ordinary[suspect] = span <= MAX_LON_SPAN
    # Whole triangles as one 12-byte item each: a boolean selection of rows, ten times faster.
    rows = np.ascontiguousarray(tris).view(np.dtype((np.void, tris.itemsize * 3))).ravel()
    kept = rows[ordinary].view(tris.dtype).reshape(-1, 3)
    return kept, cand[wrapped]
