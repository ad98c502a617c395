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

    Computed in blocks of rows, in single precision: the descriptor distances and the sines of
    the epipolar angles of all pairs at once, in double precision, take up to 4.6 GB per array
    for two panoramas of 24,000 keypoints (4000 per face).
    """
    if len(b.descriptors) < 2 or len(a.descriptors) == 0:
        return np.zeros((0, 2), int)
    ba = torch.from_numpy(a.bearings).float()
    bb = torch.from_numpy(b.bearings).float()
    et = torch.from_numpy(np.asarray(e, np.float64)).float()
    na = ba @ et.T  # epipolar plane normals in view b, [Na, 3]
    nb = bb @ et  # and in view a, [Nb, 3]
    inv_na = 1.0 / na.norm(dim=1).clamp(min=1e-12)
    inv_nb = 1.0 / nb.norm(dim=1).clamp(min=1e-12)
    distances = _Distances(a.descriptors, b.descriptors)
    limit = math.sin(threshold)
    rows = len(a.descriptors)
    best = torch.empty(rows, dtype=torch.long)
    d1 = torch.empty(rows)
    d2 = torch.empty(rows)
    col_min = torch.full((len(b.descriptors),), math.inf)
    block = 1024
    for lo in range(0, rows, block):
        hi = min(rows, lo + block)
        num = (na[lo:hi] @ bb.T).abs_()
        sin_err = torch.maximum(num * inv_na[lo:hi, None], num.mul_(inv_nb[None]))
        dist = distances.block(lo, hi).float()
        dist.masked_fill_(sin_err > limit, math.inf)
        two = dist.topk(2, dim=1, largest=False)
        best[lo:hi], d1[lo:hi], d2[lo:hi] = two.indices[:, 0], two.values[:, 0], two.values[:, 1]
        torch.minimum(col_min, dist.amin(0), out=col_min)
    keep = torch.isfinite(d1) & (d1 < ratio * ratio * d2)
    return _mutual(keep, best, d1, col_min)
