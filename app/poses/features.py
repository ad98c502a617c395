"""SIFT features of a panorama as unit bearings, and matches between two panoramas.

The panorama is resampled to six 90-degree cube faces (`panogrf.model.cubemap` directions,
OpenCV's ``remap`` with the seam wrapped) so that SIFT sees little polar stretching; every
keypoint goes back to a unit bearing in the panorama's camera frame (OpenGL: x right, y up,
looking down -z). Matching is brute force on the descriptors with Lowe's ratio test and a
cross-check (mutual nearest neighbours).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np
import torch
from torch import Tensor

from panogrf.model.cubemap import face_directions, face_rotations
from panogrf.model.erp import direction_to_pixel

#: Columns copied across the seam so that bilinear samples near it wrap.
_PAD = 2


@dataclass(frozen=True)
class Features:
    """Keypoints of one panorama."""

    bearings: np.ndarray
    """[K, 3] float64 unit directions, camera frame."""
    descriptors: np.ndarray
    """[K, 128] float32 SIFT descriptors."""


#: Panoramas narrower than this many columns get faces of this width's size (652 px), up to
#: twice their own: upsampled.
MIN_FACE_COLUMNS = 2048


def face_size_for(width: int) -> int:
    """Face size (px) that samples the equator at the panorama's resolution, and at least a
    2048-column panorama's (652 px) where that is at most twice as fine. SIFT on the faces of
    a panorama exported at 1024 columns, 326 px, finds too few keypoints that match: on the 13
    real scenes of the posing benchmark at 1024 columns, 3 scenes and 8 of 34 panoramas posed;
    with the faces upsampled to 652 px, 5 and 18 (at 2048 columns: 7 and 22). Smaller
    panoramas are upsampled twice only: each doubling of the faces quadruples the keypoints'
    search and matching."""
    return int(round(max(width, min(MIN_FACE_COLUMNS, 2 * width)) / math.pi))


@lru_cache(maxsize=4)
def _face_maps(height: int, width: int, size: int) -> tuple[np.ndarray, np.ndarray]:
    """remap coordinates of the six faces into a seam-padded panorama: two [6 * F, F] maps."""
    dirs = face_directions(size, dtype=torch.float64)
    uv = direction_to_pixel(dirs, height, width).numpy().reshape(6 * size, size, 2)
    u = np.mod(uv[..., 0] + 0.5, width) - 0.5 + _PAD
    return u.astype(np.float32), uv[..., 1].astype(np.float32)


def cube_faces(gray: np.ndarray, size: int) -> np.ndarray:
    """A gray panorama [H, W] uint8 -> six faces stacked vertically [6 * F, F] uint8."""
    h, w = gray.shape
    padded = np.concatenate([gray[:, -_PAD:], gray, gray[:, :_PAD]], axis=1)
    map_u, map_v = _face_maps(h, w, size)
    return cv2.remap(padded, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def face_pixel_to_bearing(face: np.ndarray, x: np.ndarray, y: np.ndarray, size: int) -> np.ndarray:
    """Keypoint positions (OpenCV pixel coordinates, centres at integers) on faces [K] ->
    unit bearings [K, 3] in the panorama's camera frame."""
    tx = (x + 0.5) / size * 2.0 - 1.0
    ty = 1.0 - (y + 0.5) / size * 2.0
    local = np.stack((tx, ty, -np.ones_like(tx)), -1)
    local /= np.linalg.norm(local, axis=1, keepdims=True)
    rots = face_rotations(torch.float64).numpy()
    return np.einsum("kij,kj->ki", rots[face], local)


def detect(
    rgb: np.ndarray,
    *,
    size: int | None = None,
    max_per_face: int = 4000,
    contrast: float = 0.01,
    clahe: float = 2.0,
) -> Features:
    """SIFT keypoints of a panorama [H, W, 3] uint8 (RGB) as bearings and descriptors.

    contrast: SIFT's contrast threshold (low: indoor walls are faintly textured). clahe: the
    clip limit of a local contrast equalisation of each face before detection (0: none).
    """
    h, w = rgb.shape[:2]
    size = size or face_size_for(w)
    gray = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)
    faces = cube_faces(gray, size)
    if clahe > 0:
        faces = cv2.createCLAHE(clipLimit=clahe, tileGridSize=(8, 8 * 6)).apply(faces)
    sift = cv2.SIFT_create(
        nfeatures=max_per_face, contrastThreshold=contrast, enable_precise_upscale=True
    )
    bearings, descs = [], []
    for k in range(6):
        kps, desc = sift.detectAndCompute(faces[k * size : (k + 1) * size], None)
        if not kps:
            continue
        xy = np.array([kp.pt for kp in kps], np.float64)
        bearings.append(face_pixel_to_bearing(np.full(len(kps), k), xy[:, 0], xy[:, 1], size))
        descs.append(desc)
    if not bearings:
        return Features(np.zeros((0, 3)), np.zeros((0, 128), np.float32))
    return Features(np.concatenate(bearings), np.concatenate(descs).astype(np.float32))


class _Distances:
    """Squared L2 distances of two sets of descriptors, a block of rows at a time.

    SIFT's descriptors (OpenCV) are whole numbers 0-255, and every such distance is a whole
    number under 2^24: single precision computes them exactly, and so does an 8-bit integer
    product (each descriptor shifted by 128 into a signed byte; the shift's terms added back
    per row and column): a pair of panoramas of 17,000-21,000 keypoints matched in 0.45 times
    the time on 2 cores of a CPU with 8-bit dot products (AVX-512 VNNI). The integer
    product serves whole-number descriptors of 0-255, single precision any others: the two
    give the same distances to the last bit.
    """

    def __init__(self, a: np.ndarray, b: np.ndarray) -> None:
        self.whole = _bytes(a) and _bytes(b)
        da, db = torch.from_numpy(a).float(), torch.from_numpy(b).float()
        sq_a, sq_b = (da * da).sum(1), (db * db).sum(1)
        if self.whole:  # a.b = a'.b' + 128 (sum a' + sum b') + 128^2 D, with x' = x - 128
            a8, b8 = (da - 128).to(torch.int8), (db - 128).to(torch.int8)
            shift = 2 * 128 * 128 * a.shape[1]
            self.a, self.b_t = a8, b8.T.contiguous()
            self.row = (sq_a - 256 * a8.sum(1)).long().sub_(shift).int()
            self.col = (sq_b - 256 * b8.sum(1)).long().int()
        else:
            self.a, self.b_t, self.row, self.col = da, db.T, sq_a, sq_b

    def block(self, lo: int, hi: int) -> Tensor:
        """Squared distances [hi - lo, Nb] of rows lo..hi (int32 or float32)."""
        if self.whole:
            dot = torch._int_mm(self.a[lo:hi], self.b_t)
            return dot.mul_(-2).add_(self.col[None]).add_(self.row[lo:hi, None])
        dist = torch.addmm(self.col.expand(hi - lo, -1), self.a[lo:hi], self.b_t, alpha=-2.0)
        return dist.add_(self.row[lo:hi, None]).clamp_(min=0)

    def at(self, lo: int, hi: int, rows: Tensor, cols: Tensor) -> Tensor:
        """Squared distances [K] (float32) of the pairs (rows, cols), rows within lo..hi: the
        integer product's block, its shift added back at those pairs only."""
        if not self.whole:
            return self.block(lo, hi)[rows - lo, cols]
        dot = torch._int_mm(self.a[lo:hi], self.b_t)[rows - lo, cols]
        return (dot.mul_(-2) + self.col[cols] + self.row[rows]).float()


def _bytes(d: np.ndarray) -> bool:
    """Whether descriptors [N, D] are whole numbers 0-255 (and there is a D to multiply)."""
    return bool(d.size) and d.min() >= 0 and d.max() <= 255 and bool(np.all(d == np.rint(d)))


def _mutual(keep: Tensor, best: Tensor, d1: Tensor, col_min: Tensor) -> np.ndarray:
    """Matches [M, 2] (row, its nearest column) of the rows ``keep`` passes whose nearest
    column ``best`` has no nearer row (``col_min``: each column's least distance), the first
    such row where distances tie. Each column's nearest row is found from the column minima
    alone: a reduction over the rows without its indices is some eight times faster on a CPU
    than one with them (it reads the rows in order)."""
    keep = keep & (d1 <= col_min[best])
    rows = torch.nonzero(keep).squeeze(1).numpy()
    cols = best[keep].numpy()
    _, first = np.unique(cols, return_index=True)
    first.sort()
    return np.stack((rows[first], cols[first]), 1).astype(int)


def match(a: Features, b: Features, ratio: float = 0.8) -> np.ndarray:
    """Indices [M, 2] of mutual nearest neighbours that pass the ratio test (a -> b).

    Exact L2 distances in blocks of rows (`_Distances`): the same matches as a brute
    force k-nearest-neighbour search, some 20 times faster on two panoramas of 20,000 keypoints
    than OpenCV's brute-force matcher on two cores."""
    if len(a.descriptors) < 2 or len(b.descriptors) < 2:
        return np.zeros((0, 2), int)
    distances = _Distances(a.descriptors, b.descriptors)
    rows = len(a.descriptors)
    best = torch.empty(rows, dtype=torch.long)
    keep = torch.empty(rows, dtype=torch.bool)
    d1 = torch.empty(rows)
    col_min = torch.full((len(b.descriptors),), math.inf)
    block = 2048
    for lo in range(0, rows, block):
        hi = min(rows, lo + block)
        dist = distances.block(lo, hi)
        two = dist.topk(2, dim=1, largest=False)
        values = two.values.float()
        best[lo:hi] = two.indices[:, 0]
        keep[lo:hi] = values[:, 0] < ratio * ratio * values[:, 1]
        torch.minimum(col_min, dist.amin(0).float(), out=col_min)
        d1[lo:hi] = values[:, 0]
    return _mutual(keep, best, d1, col_min)


def match_guided(
    a: Features, b: Features, e: np.ndarray, threshold: float, ratio: float = 0.9
) -> np.ndarray:
    """Matches [M, 2] given an essential matrix (b_b^T E b_a = 0): each keypoint's candidates
    are those within ``threshold`` radians of its epipolar plane in both views; among them the
    nearest descriptor wins if it passes the ratio test and the choice is mutual.

    The candidates are a few percent of all pairs: `_epipolar_band` lists a superset of them
    from the keypoints sorted around the epipole, and each is then tested as the definition
    says (single precision); distances are computed for all pairs by the integer product and
    read at the candidates (`_Distances.at`). The same matches as testing every pair, in 0.28
    times the time on two cores for real panoramas of 18,000 keypoints (testing every pair in
    double precision took up to 4.6 GB per array for two panoramas of 24,000).
    """
    if len(b.descriptors) < 2 or len(a.descriptors) == 0:
        return np.zeros((0, 2), int)
    e = np.asarray(e, np.float64)
    ba = torch.from_numpy(a.bearings).float()
    bb = torch.from_numpy(b.bearings).float()
    et = torch.from_numpy(e).float()
    na = ba @ et.T  # epipolar plane normals in view b, [Na, 3]
    nb = bb @ et  # and in view a, [Nb, 3]
    inv_na = 1.0 / na.norm(dim=1).clamp(min=1e-12)
    inv_nb = 1.0 / nb.norm(dim=1).clamp(min=1e-12)
    distances = _Distances(a.descriptors, b.descriptors)
    limit = math.sin(threshold)
    band = _epipolar_band(a.bearings, b.bearings, e, limit)
    rows = len(a.descriptors)
    best = torch.zeros(rows, dtype=torch.long)
    d1 = torch.full((rows,), math.inf)
    d2 = torch.full((rows,), math.inf)
    col_min = torch.full((len(b.descriptors),), math.inf)
    block = 1024
    for lo in range(0, rows, block):
        hi = min(rows, lo + block)
        r, c = band(lo, hi)
        num = (na[r] * bb[c]).sum(1).abs_()
        near = torch.maximum(num * inv_na[r], num * inv_nb[c]) <= limit
        r, c = r[near], c[near]
        if len(r) == 0:
            continue
        dist = distances.at(lo, hi, r, c)
        col_min.scatter_reduce_(0, c, dist, "amin")
        # Each row's two nearest: the pairs sorted by row, then distance (whole numbers under
        # 2^24 for SIFT; the order of a float's bits otherwise, as both are non-negative).
        key = r * (1 << 32) + dist.view(torch.int32).long()
        order = torch.sort(key).indices
        r, c, dist = r[order], c[order], dist[order]
        first = torch.ones(len(r), dtype=torch.bool)
        first[1:] = r[1:] != r[:-1]
        start = torch.nonzero(first).squeeze(1)
        best[r[start]], d1[r[start]] = c[start], dist[start]
        pair = torch.nonzero(start + 1 < len(r)).squeeze(1)  # rows with a second candidate
        pair = pair[r[start[pair] + 1] == r[start[pair]]]
        d2[r[start[pair]]] = dist[start[pair] + 1]
    keep = torch.isfinite(d1) & (d1 < ratio * ratio * d2)
    return _mutual(keep, best, d1, col_min)


def _epipolar_band(bearings_a: np.ndarray, bearings_b: np.ndarray, e: np.ndarray, limit: float):
    """``band(lo, hi)`` -> (rows, cols) [K] int64: a superset of the pairs of keypoints (rows
    lo..hi of a) whose b-bearing lies within ``limit`` (a sine) of the row's epipolar plane.

    Every epipolar plane in b contains the epipole e_b (E^T e_b = 0). A bearing at angle psi
    from it and azimuth w around it is sin(psi) |sin(w - theta)| out of the plane of azimuth
    theta + 90 degrees (theta: where the plane's normal E b_a points). So the b-keypoints are
    banded by sin(psi) (doubling from ``limit``) and sorted by azimuth (modulo 180 degrees,
    a plane's two halves); a row's candidates in a band of sin(psi) >= s are those within
    asin(limit / s) of its theta, found by binary search. A degenerate E (no epipole): every
    pair."""
    n_b = len(bearings_b)
    u_e, sing, _ = np.linalg.svd(e)
    if not sing[1] > 1e-9 * sing[0]:
        return lambda lo, hi: _all_pairs(lo, hi, n_b)
    pole = u_e[:, 2]  # e_b
    x = np.cross(pole, [1.0, 0.0, 0.0] if abs(pole[0]) < 0.9 else [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(pole, x)
    sin_psi = np.linalg.norm(np.cross(bearings_b, pole), axis=1)
    azimuth = np.mod(np.arctan2(bearings_b @ y, bearings_b @ x), math.pi)
    normals = bearings_a @ e.T  # E b_a, [Na, 3]
    theta = np.mod(np.arctan2(normals @ y, normals @ x) - math.pi / 2, math.pi)
    # A keypoint at (or within a milliradian of) a's epipole has no plane of its own: the
    # single-precision test sees a plane of rounding errors there, so every b-keypoint is its
    # candidate.
    length = np.linalg.norm(normals, axis=1)
    wild = (length < 1e-3 * sing[0]) | (np.abs(normals @ pole) > 1e-6 * length)
    slack = 1e-4  # rounding of the single-precision test and of E's own null space
    bands = []
    edge = limit
    lower = 0.0
    while lower < 1.0:
        upper = edge if lower == 0.0 else 2.0 * lower
        members = np.nonzero((sin_psi >= lower) & (sin_psi < upper))[0]
        if len(members):
            width = math.pi / 2 if lower <= limit else math.asin(limit / lower) + slack
            order = members[np.argsort(azimuth[members], kind="stable")]
            bands.append((order, azimuth[order], width))
        lower = upper

    def band(lo: int, hi: int) -> tuple[Tensor, Tensor]:
        ids = np.arange(lo, hi)
        odd, ids = ids[wild[lo:hi]], ids[~wild[lo:hi]]
        rows, cols = [np.repeat(odd, n_b)], [np.tile(np.arange(n_b), len(odd))]
        t = theta[ids]
        for order, az, width in bands:
            if width >= math.pi / 2 - slack:
                rows.append(np.repeat(ids, len(order)))
                cols.append(np.tile(order, len(ids)))
                continue
            ext = np.concatenate([az - math.pi, az, az + math.pi])
            first = np.searchsorted(ext, t - width, "left")
            last = np.searchsorted(ext, t + width, "right")
            counts = last - first
            r = np.repeat(ids, counts)
            offset = np.arange(len(r)) - np.repeat(np.cumsum(counts) - counts, counts)
            rows.append(r)
            cols.append(np.tile(order, 3)[np.repeat(first, counts) + offset])
        return torch.from_numpy(np.concatenate(rows)), torch.from_numpy(np.concatenate(cols))

    return band


def _all_pairs(lo: int, hi: int, n_b: int) -> tuple[Tensor, Tensor]:
    rows = torch.arange(lo, hi).repeat_interleave(n_b)
    return rows, torch.arange(n_b).repeat(hi - lo)
