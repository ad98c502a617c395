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


def test_a_real_pair_a_step_apart_is_not_seeded_and_still_poses(monkeypatch):
    """The pipeline's path for a pair without a verified seed, on the real pair of
    `tests/data/real_pair` (CC0; the camera moved a step): with COLMAP's first verification
    ignored, the search runs on the real matches; a step's baseline leaves the direction
    ambiguous, so it seeds nothing, and COLMAP's own verification still poses the pair."""
    from pathlib import Path

    from panogrf.app.files.images import read_rgb
    from panogrf.app.poses import colmap

    pair = Path(__file__).parents[1] / "data" / "real_pair"
    images = [read_rgb(pair / f) for f in ("studio_small_03.jpg", "studio_small_07.jpg")]
    calls = []
    search = upright.search

    def spy(b1, b2, cfg):
        calls.append(len(b1))
        return search(b1, b2, cfg)

    monkeypatch.setattr(colmap, "_seed", lambda *args: (None, False))
    monkeypatch.setattr(upright, "search", spy)
    est = colmap.estimate_poses_colmap(images, colmap.ColmapConfig(num_threads=2))
    assert calls and calls[0] >= 100
    (report,) = est.pairs
    assert report.level_search is None
    assert report.ok and est.registered.all()


def test_the_report_names_a_pair_the_search_seeded():
    from pathlib import Path

    from panogrf.app.commands.scene_poses_report import pose_report
    from panogrf.app.poses.colmap_report import ColmapEstimate, PairReport

    pair = PairReport(0, 1, 2186, 613, 468, 0.16, ok=True, level_search=(38, 20))
    est = ColmapEstimate(np.eye(4)[None].repeat(2, 0), np.ones(2, bool), np.zeros((0, 3)))
    est.pairs = [pair]
    line = pose_report([Path("a.jpg"), Path("b.jpg")], est)[2]
    assert "ok, 613 inliers" in line
    assert "level-camera search: 38 agree at its peak, at most 20 elsewhere" in line


def test_the_bundled_scene_poses_from_the_search_alone(monkeypatch):
    """End to end on rendered pixels: with no pair's RANSAC geometry used as a seed, the search
    seeds the pairs of the bundled scene (level cameras at three heights, 0.5 and 1 m apart),
    COLMAP verifies the grown matches and maps, and the poses match the truth."""
    from panogrf.app.files.images import read_rgb
    from panogrf.app.poses import colmap
    from panogrf.app.scene.folder import load_scene
    from panogrf.assets import path as asset_path

    truth = load_scene(asset_path("demo"))
    images = [read_rgb(f.image_path) for f in truth.frames]
    monkeypatch.setattr(colmap, "_seed", lambda *args: (None, False))
    est = colmap.estimate_poses_colmap(images, colmap.ColmapConfig(num_threads=2))
    seeded = {(p.i, p.j): p.level_search for p in est.pairs if p.level_search is not None}
    # the two pairs 1 m and 0.5 m apart; the other 0.5 m pair's heading stays ambiguous and
    # COLMAP's own verification of it is kept
    assert len(seeded) >= 2, est.pairs
    assert all(peak >= 1.5 * elsewhere for peak, elsewhere in seeded.values())
    assert est.registered.all()
    for e in er.pair_errors(est.c2w, truth.c2w):
        assert e["rotation_deg"] < 1.0 and e["translation_deg"] < 3.0, e
