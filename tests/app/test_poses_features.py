"""Guided matching, computed in blocks of rows, gives the matches of the whole distance matrix
at once (the plain definition, written out here in numpy)."""

from __future__ import annotations

import math

import numpy as np

from panogrf.app.poses.features import Features, match, match_guided


def _dense(a: Features, b: Features, e: np.ndarray, threshold: float, ratio: float) -> set:
    na, nb = a.bearings @ e.T, b.bearings @ e
    num = np.abs(na @ b.bearings.T)
    sin_err = np.maximum(
        num / np.linalg.norm(na, axis=1)[:, None], num / np.linalg.norm(nb, axis=1)[None]
    )
    da, db = a.descriptors.astype(np.float64), b.descriptors.astype(np.float64)
    dist = np.sqrt(np.maximum((da**2).sum(1)[:, None] + (db**2).sum(1)[None] - 2 * da @ db.T, 0))
    dist[sin_err > math.sin(threshold)] = np.inf
    order = np.argsort(dist, axis=1)[:, :2]
    rows = np.arange(len(dist))
    d1, d2 = dist[rows, order[:, 0]], dist[rows, order[:, 1]]
    keep = np.isfinite(d1) & (d1 < ratio * d2) & (dist.argmin(0)[order[:, 0]] == rows)
    return {(int(i), int(order[i, 0])) for i in rows[keep]}


def _features(rng, n: int) -> Features:
    bearings = rng.normal(size=(n, 3))
    bearings /= np.linalg.norm(bearings, axis=1, keepdims=True)
    return Features(bearings, rng.integers(0, 60, size=(n, 128)).astype(np.float32))


def test_blocks_match_the_whole_matrix():
    rng = np.random.default_rng(0)
    a, b = _features(rng, 2300), _features(rng, 1700)  # more rows than one block
    # b's keypoints 0..799 are a's 0..799 seen 1 m along +x, with slightly noisy descriptors.
    shift = np.array([1.0, 0.0, 0.0])
    points = a.bearings[:800] * rng.uniform(1, 5, (800, 1)) - shift
    b.bearings[:800] = points / np.linalg.norm(points, axis=1, keepdims=True)
    b.descriptors[:800] = a.descriptors[:800] + rng.normal(0, 2, (800, 128)).astype(np.float32)
    skew = np.array([[0, -shift[2], shift[1]], [shift[2], 0, -shift[0]], [-shift[1], shift[0], 0]])
    e = -skew  # x_b = x_a - shift: E = [t]x R with t = -shift, R = I
    got = match_guided(a, b, e, 0.01, 0.7)
    want = _dense(a, b, e, 0.01, 0.7)
    assert {tuple(m) for m in got.tolist()} == want
    assert len(want) > 600  # the true pairs are found
    assert all(i == j for i, j in want if i < 800)


def test_pooled_matching_is_the_plain_definition():
    """Mutual nearest neighbours passing the ratio test on the (square-rooted) distances, in
    blocks of rows and on squared distances."""
    rng = np.random.default_rng(1)
    a, b = _features(rng, 2500), _features(rng, 1900)  # more rows than one block
    b.descriptors[:900] = a.descriptors[:900] + rng.normal(0, 3, (900, 128)).astype(np.float32)
    da, db = a.descriptors.astype(np.float64), b.descriptors.astype(np.float64)
    dist = np.sqrt(np.maximum((da**2).sum(1)[:, None] + (db**2).sum(1)[None] - 2 * da @ db.T, 0))
    order = np.argsort(dist, axis=1)[:, :2]
    rows = np.arange(len(dist))
    d1, d2 = dist[rows, order[:, 0]], dist[rows, order[:, 1]]
    keep = (d1 < 0.8 * d2) & (dist.argmin(0)[order[:, 0]] == rows)
    want = {(int(i), int(order[i, 0])) for i in rows[keep]}
    got = {tuple(m) for m in match(a, b, 0.8).tolist()}
    assert got == want
    assert len(want) > 800 and all(i == j for i, j in want if i < 900)


def test_a_column_nearest_to_two_equal_rows_is_matched_once_to_the_first():
    """Mutual nearest neighbours from the columns' least distances alone: where two rows tie
    for a column, the first row is its match and the second none (one keypoint, one match)."""
    rng = np.random.default_rng(2)
    a, b = _features(rng, 300), _features(rng, 200)
    b.descriptors[:100] = a.descriptors[:100] + rng.normal(0, 1, (100, 128)).astype(np.float32)
    a.descriptors[250] = a.descriptors[7]  # rows 7 and 250 tie for column 7
    got = match(a, b, 0.8)
    assert [7, 7] in got.tolist()
    assert 250 not in got[:, 0]
    assert len(np.unique(got[:, 1])) == len(got)


def test_whole_number_descriptors_match_by_the_integer_product_as_by_the_definition():
    """SIFT's descriptors are whole numbers 0-255: the 8-bit integer product gives the same
    distances, and so the same matches, as the plain definition (0 and 255 included)."""
    from panogrf.app.poses.features import _Distances

    rng = np.random.default_rng(3)
    a = Features(np.zeros((2300, 3)), rng.integers(0, 256, (2300, 128)).astype(np.float32))
    noisy = a.descriptors[:1500] + rng.normal(0, 6, (1500, 128))
    b = Features(np.zeros((1500, 3)), np.clip(np.rint(noisy), 0, 255).astype(np.float32))
    b.descriptors[0] = 255
    a.descriptors[1] = 0
    distances = _Distances(a.descriptors, b.descriptors)
    assert distances.whole
    da, db = a.descriptors.astype(np.float64), b.descriptors.astype(np.float64)
    exact = (da**2).sum(1)[:, None] + (db**2).sum(1)[None] - 2 * da @ db.T
    assert np.array_equal(distances.block(0, 2300).numpy(), exact)
    dist = np.sqrt(exact)
    order = np.argsort(dist, axis=1)[:, :2]
    rows = np.arange(len(dist))
    d1, d2 = dist[rows, order[:, 0]], dist[rows, order[:, 1]]
    keep = (d1 < 0.8 * d2) & (dist.argmin(0)[order[:, 0]] == rows)
    want = {(int(i), int(order[i, 0])) for i in rows[keep]}
    assert {tuple(m) for m in match(a, b, 0.8).tolist()} == want
    assert len(want) > 1000
    assert not _Distances(a.descriptors + 0.5, b.descriptors).whole


def _turn(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]) @ np.array(
        [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]
    )


def test_guided_matching_of_turned_cameras_is_the_plain_definition():
    """The candidates listed around the epipole are the definition's: a turned and tilted
    second camera, whole-number descriptors (the integer product), keypoints near both
    epipoles included."""
    rng = np.random.default_rng(4)
    a = _features(rng, 2600)
    rot, t = _turn(0.7), np.array([0.3, -0.2, 0.9])
    t /= np.linalg.norm(t)
    # 20 keypoints 0.5-3 degrees from the direction of b's centre (the epipole: exactly there,
    # the test's sines are 0/0 in any precision)
    near = -rot.T @ t + rng.normal(0, 0.03, (20, 3))
    a.bearings[:20] = near / np.linalg.norm(near, axis=1, keepdims=True)
    points = a.bearings[:1200] * rng.uniform(1, 6, (1200, 1))
    b = _features(rng, 1800)
    seen = points @ rot.T + t  # x_b = R x_a + t
    b.bearings[:1200] = seen / np.linalg.norm(seen, axis=1, keepdims=True)
    b.descriptors[:1200] = np.clip(a.descriptors[:1200] + rng.integers(-2, 3, (1200, 128)), 0, 255)
    skew = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    e = skew @ rot
    for threshold in (0.004, 0.02, 0.2):
        got = match_guided(a, b, e, threshold, 0.8)
        assert {tuple(m) for m in got.tolist()} == _dense(a, b, e, threshold, 0.8)
    assert len(got) > 900


def test_guided_matching_without_an_epipole_is_pooled_matching():
    rng = np.random.default_rng(5)
    a, b = _features(rng, 1500), _features(rng, 1100)
    b.descriptors[:700] = a.descriptors[:700]
    got = match_guided(a, b, np.zeros((3, 3)), 0.01, 0.8)
    assert np.array_equal(got, match(a, b, 0.8))
    assert len(got) >= 600
