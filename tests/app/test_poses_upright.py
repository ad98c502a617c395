"""`panogrf.app.poses.upright`: the level-camera search on synthetic bearings with most matches
wrong, as between two rooms that share a doorway."""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from panogrf.app.poses import errors as er
from panogrf.app.poses import upright


def _unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _pair(rng, inliers: int, outliers: int, yaw_deg: float, tilt_deg: float = 0.0):
    """Bearings b1, b2 [M, 3] of two cameras 3 m apart (the second 5 cm higher, turned by
    ``yaw_deg`` and tilted by ``tilt_deg``), ``inliers`` true matches then ``outliers``
    random ones, and the truth (R, t) with x2 = R x1 + t."""
    points = rng.uniform([-4, -1.4, -6], [4, 1.2, 2], (inliers, 3))
    centre = np.array([2.4, 0.05, -1.8])
    r21 = (
        Rotation.from_rotvec([math.radians(tilt_deg), 0, 0])
        * Rotation.from_euler("y", yaw_deg, degrees=True)
    ).as_matrix()  # camera 2's axes in camera 1's
    b1 = _unit(points + 1e-3 * rng.normal(size=points.shape))
    b2 = _unit((points - centre) @ r21)
    b1 = np.concatenate([b1, _unit(rng.normal(size=(outliers, 3)))])
    b2 = np.concatenate([b2, _unit(rng.normal(size=(outliers, 3)))])
    order = rng.permutation(len(b1))
    rot = r21.T
    return b1[order], b2[order], rot, -rot @ centre


def _errors(found, rot, t):
    rot_err = er.rotation_angle_deg(found.rot @ rot.T)
    dir_err = math.degrees(math.acos(np.clip(found.t @ _unit(t), -1, 1)))
    return rot_err, dir_err


def test_a_pair_with_six_percent_true_matches_is_posed():
    rng = np.random.default_rng(0)
    b1, b2, rot, t = _pair(rng, inliers=30, outliers=470, yaw_deg=137.0)
    found = upright.search(b1, b2)
    assert found is not None
    rot_err, dir_err = _errors(found, rot, t)
    # a seed for guided matching, whose band is half a degree wide
    assert rot_err < 0.5 and dir_err < 0.5, (rot_err, dir_err)
    assert found.support >= 24 and found.runner_up < found.support / 1.5
    # the essential matrix holds the true matches: most within a quarter of a degree
    normal = b1 @ found.essential.T
    sines = np.abs((normal * b2).sum(1)) / np.linalg.norm(normal, axis=1)
    assert (sines < np.sin(np.radians(0.25))).sum() >= 25


def test_a_slightly_tilted_camera_is_refined_off_the_level_grid():
    rng = np.random.default_rng(1)
    b1, b2, rot, t = _pair(rng, inliers=60, outliers=240, yaw_deg=-64.0, tilt_deg=1.5)
    found = upright.search(b1, b2)
    assert found is not None
    rot_err, dir_err = _errors(found, rot, t)
    assert rot_err < 0.5 and dir_err < 0.5, (rot_err, dir_err)


def test_random_matches_give_no_pose():
    rng = np.random.default_rng(2)
    for _ in range(3):
        b1 = _unit(rng.normal(size=(250, 3)))
        b2 = _unit(rng.normal(size=(250, 3)))
        assert upright.search(b1, b2) is None


def test_too_few_true_matches_among_many_give_no_pose():
    rng = np.random.default_rng(3)
    b1, b2, _, _ = _pair(rng, inliers=4, outliers=220, yaw_deg=20.0)
    assert upright.search(b1, b2) is None


def test_a_real_pair_that_colmap_did_not_verify_is_posed_from_the_search(monkeypatch):
    """The pipeline's path for a pair without a verified geometry, on the real pair of
    `tests/data/real_pair` (level cameras, CC0): with COLMAP's first verification ignored, the
    search seeds the guided matching, COLMAP verifies the grown matches and the report says so."""
    from pathlib import Path

    from panogrf.app.commands.scene_poses_report import pose_report
    from panogrf.app.files.images import read_rgb
    from panogrf.app.poses import colmap

    pair = Path(__file__).parents[1] / "data" / "real_pair"
    files = [pair / "studio_small_03.jpg", pair / "studio_small_07.jpg"]
    images = [read_rgb(f) for f in files]
    monkeypatch.setattr(colmap, "_seed", lambda *args: None)
    est = colmap.estimate_poses_colmap(images, colmap.ColmapConfig(num_threads=2))
    (report,) = est.pairs
    assert report.level_search is not None and report.level_search[0] >= 20
    assert report.ok and est.registered.all()
    line = pose_report(files, est)[2]
    assert "level-camera search" in line and "ok" in line
    # the same relative pose as the product's path with COLMAP's verification
    monkeypatch.undo()
    plain = colmap.estimate_poses_colmap(images, colmap.ColmapConfig(num_threads=2))
    assert plain.pairs[0].level_search is None
    rel = [np.linalg.inv(e.c2w[0]) @ e.c2w[1] for e in (est, plain)]
    assert er.rotation_angle_deg(rel[0][:3, :3] @ rel[1][:3, :3].T) < 0.5
    assert math.degrees(math.acos(np.clip(_unit(rel[0][:3, 3]) @ _unit(rel[1][:3, 3]), -1, 1))) < 2
