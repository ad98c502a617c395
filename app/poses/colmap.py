"""Relative poses of V panoramas: SIFT on cube faces, pooled matching, COLMAP's geometry.

The front end is the one measured to find matches in blank real rooms
(`panogrf.app.poses.features`): SIFT on six locally equalised 90-degree cube faces per
panorama, every keypoint a unit bearing; each pair of panoramas matched as a whole (mutual
nearest neighbours with the ratio test, every keypoint of one panorama against every keypoint
of the other). Keypoints far below the horizon (tripod, hand, operator) are dropped: they move
with the camera and pull the poses towards a rotation only.

The geometry is COLMAP's (pycolmap), on its native EQUIRECTANGULAR camera: each panorama is
one image whose keypoints are the bearings' panorama pixels; COLMAP verifies every pair
(essential matrix on the bearings, RANSAC), the matches are then grown along the verified
epipolar planes (guided matching) and verified again, and the poses come from COLMAP's global
mapper (rotation averaging, global positioning, bundle adjustment), or its incremental mapper
where that registers more panoramas.

Output poses are camera-to-world [V, 4, 4] in the OpenGL camera frame, in COLMAP's arbitrary
world frame and unit; `panogrf.app.poses.scale` makes them upright and metric. The report has
one entry per pair of panoramas (putative matches, verified inliers, the points both see and
their median residual in degrees) and one per panorama; the poses and the report are made from
the reconstruction by `panogrf.app.poses.colmap_report`.
"""

from __future__ import annotations

import contextlib
import math
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from panogrf.app.poses import CV_TO_GL, upright
from panogrf.app.poses import features as ft
from panogrf.app.poses import geometry as geo
from panogrf.app.poses.colmap_report import ColmapEstimate, _collect, _two_view
from panogrf.app.poses.colmap_report import PairReport as PairReport
from panogrf.app.poses.colmap_report import ViewReport as ViewReport


@dataclass(frozen=True)
class ColmapConfig:
    """Settings of `estimate_poses_colmap`."""

    max_width: int = 2048
    """Wider panoramas are downsampled for the features (the poses do not depend on it)."""
    nadir_deg: float = 70.0
    """Keypoints more than this below the horizon are dropped: a tripod's legs (0.4 m spread
    under a camera at 1.5 m) or a hand-held stick lie within 15-20 degrees of the nadir, and
    the floor above them is what fixes the scale from the camera height."""
    ratio: float = 0.8
    """Lowe's ratio test of the pooled matching."""
    guided_px: float = 3.0
    """Guided matching: candidates within this many equator pixels of the epipolar plane."""
    min_guided_inliers: int = 30
    """A pair's first verification must keep this many inliers before matches are grown along
    its epipolar planes."""
    min_pair_inliers: int = 30
    """Fewer verified inliers than this: the pair is reported failed and gives no geometry (on
    real homes the pairs that pose have hundreds; a wrong geometry finds a dozen or two, and a
    pair alone, or a chain of pairs, has nothing to check it against)."""
    max_error_px: float = 4.0
    """COLMAP's RANSAC and reprojection thresholds, in panorama pixels at 1024 columns."""
    level_search: upright.UprightConfig | None = upright.UprightConfig()
    """Pairs without a verified geometry, between panoramas no verified pair links: the
    exhaustive search for level cameras (`panogrf.app.poses.upright`) seeds their guided
    matching (None: not tried)."""
    num_threads: int = -1
    """COLMAP's threads (-1: all cores)."""
    seed: int = 0


def estimate_poses_colmap(
    images: list[np.ndarray],
    cfg: ColmapConfig = ColmapConfig(),
    progress=None,
    work_dir: Path | None = None,
) -> ColmapEstimate:
    """Poses of panoramas [H, W, 3] uint8 (RGB), at least two, all the same size.

    Each step is a `panogrf.model.progress` stage ("posing: features", "posing: matching",
    "posing: verification", "posing: level-camera search" where pairs were not verified,
    "posing: guided matching", "posing: mapping"); ``progress(stage, done, total)`` is also called
    when given. ``work_dir``: where COLMAP's database goes (default: a temporary folder,
    removed after)."""
    start = time.perf_counter()
    say = _Stages(progress)
    with contextlib.ExitStack() as stack:
        stack.callback(say.close)
        if work_dir is None:
            work_dir = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="panogrf-")))
        est = _run(images, cfg, say, Path(work_dir))
    est.seconds = time.perf_counter() - start
    return est


def load_pycolmap():
    """``pycolmap``, imported after the system's zlib: the wheel's extension brings zlib
    symbols of its own, and a process that loads it first and then writes a PNG with Pillow
    (matplotlib, the viewer's screenshots) aborts in ``deflateEnd``. Its logging library takes
    over SIGTERM to print a page of C++ stack trace; the default (end quietly) is put back."""
    import signal
    import threading
    import zlib  # noqa: F401 - loads the system's libz first

    import PIL.Image  # noqa: F401
    import pycolmap

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, signal.getsignal(signal.SIGTERM))
    return pycolmap


class _Stages:
    """``say(name, done, total)`` -> one `panogrf.model.progress` stage per name."""

    def __init__(self, callback=None) -> None:
        self.callback = callback
        self.current = None

    def __call__(self, name: str, done: int, total: int) -> None:
        from panogrf.model.progress import open_stage

        if self.callback is not None:
            self.callback(name, done, total)
        label = f"posing: {name}"
        if self.current is None or self.current.name != label:
            self.close()
            self.current = open_stage(label, total)
        if done > self.current.done:
            self.current.advance(done - self.current.done)

    def close(self) -> None:
        if self.current is not None:
            self.current.close()
            self.current = None


def _camera(width: int, height: int):
    pycolmap = load_pycolmap()

    return pycolmap.Camera.create_from_model_id(
        camera_id=1,
        model=pycolmap.CameraModelId.EQUIRECTANGULAR,
        focal_length=0.0,
        width=width,
        height=height,
    )


def _pixels(camera, bearings_gl: np.ndarray) -> np.ndarray:
    """Bearings [K, 3] (OpenGL camera frame) -> COLMAP panorama pixels [K, 2]."""
    if len(bearings_gl) == 0:
        return np.zeros((0, 2))
    return np.asarray(camera.img_from_cam(bearings_gl @ CV_TO_GL))


def _run(images, cfg: ColmapConfig, say, work: Path) -> ColmapEstimate:
    pycolmap = load_pycolmap()

    pycolmap.logging.minloglevel = 3  # quiet: what fails is in our own report
    pycolmap.set_random_seed(cfg.seed)
    v_count = len(images)
    if images[0].shape[1] > cfg.max_width:  # features need no more (bearings are unchanged)
        size = (cfg.max_width, cfg.max_width // 2)
        images = [cv2.resize(img, size, interpolation=cv2.INTER_AREA) for img in images]
    h, w = images[0].shape[:2]
    floor = -math.sin(math.radians(cfg.nadir_deg))
    feats = []
    for k, img in enumerate(images):
        say("features", k, v_count)
        f = ft.detect(img)
        keep = f.bearings[:, 1] > floor
        feats.append(ft.Features(f.bearings[keep], f.descriptors[keep]))
    say("features", v_count, v_count)
    camera = _camera(w, h)
    image_dir = work / "images"
    image_dir.mkdir(parents=True, exist_ok=True)
    names = [f"p{k:03d}.jpg" for k in range(v_count)]
    for k, img in enumerate(images):
        # COLMAP reads the files only for the size and the points' colours: a small copy will
        # do, but the size must match the camera.
        if not cv2.imwrite(str(image_dir / names[k]), cv2.cvtColor(img, cv2.COLOR_RGB2BGR)):
            raise OSError(f"cannot write COLMAP's images in {work}")
    db_path = work / "database.db"
    pycolmap.Database.open(db_path).close()
    pycolmap.import_images(
        db_path,
        image_dir,
        camera_mode=pycolmap.CameraMode.SINGLE,
        options=pycolmap.ImageReaderOptions(camera_model="EQUIRECTANGULAR"),
    )
    scale_px = w / 1024.0
    verify = pycolmap.TwoViewGeometryOptions()
    verify.min_num_inliers = cfg.min_pair_inliers
    verify.ransac.max_error = cfg.max_error_px * scale_px
    verify.ransac.random_seed = cfg.seed
    verify.compute_relative_pose = True
    with pycolmap.Database.open(db_path) as db:
        ids = {im.name: im.image_id for im in db.read_all_images()}
        image_ids = [ids[n] for n in names]
        for k, f in enumerate(feats):
            db.write_keypoints(image_ids[k], _pixels(camera, f.bearings).astype(np.float32))
        pair_list = [(i, j) for i in range(v_count) for j in range(i + 1, v_count)]
        putative = {}
        for n, (i, j) in enumerate(pair_list):
            say("matching", n, len(pair_list))
            m = ft.match(feats[i], feats[j], cfg.ratio)
            putative[(i, j)] = m
            db.write_matches(image_ids[i], image_ids[j], m.astype(np.uint32))
        say("matching", len(pair_list), len(pair_list))
    say("verification", 0, 2)
    _verify(db_path, verify, cfg)
    with pycolmap.Database.open(db_path) as db:
        first = {(i, j): _seed(db, image_ids[i], image_ids[j], cfg) for i, j in pair_list}
    seeds = {ij: e_gl for ij, (e_gl, _) in first.items()}
    found_level: dict[tuple[int, int], tuple[int, int]] = {}
    # The search links panoramas no verified pair links: the most matches first, and a pair
    # whose panoramas are linked already (by verified pairs or an earlier find) is skipped, so
    # a tour of many photos pays for its gaps, not for every pair that sees nothing in common.
    group = list(range(v_count))

    def root(k: int) -> int:
        while group[k] != k:
            k = group[k]
        return k

    for i, j in pair_list:
        if first[(i, j)][1]:
            group[root(i)] = root(j)
    unverified = sorted(
        (ij for ij in pair_list if not first[ij][1]), key=lambda ij: -len(putative[ij])
    )
    if cfg.level_search is not None and unverified:
        for n, (i, j) in enumerate(unverified):
            say("level-camera search", n, len(unverified))
            if root(i) == root(j):
                continue
            m = putative[(i, j)]
            b_i, b_j = feats[i].bearings[m[:, 0]], feats[j].bearings[m[:, 1]]
            found = upright.search(b_i, b_j, cfg.level_search)
            if found is not None:
                found_level[(i, j)] = (found.support, found.runner_up)
                seeds[(i, j)] = found.essential
                group[root(i)] = root(j)
        say("level-camera search", len(unverified), len(unverified))
    guided_rad = cfg.guided_px * math.pi / 512.0  # equator pixels at 1024 columns -> radians
    seeded = [ij for ij in pair_list if seeds[ij] is not None]
    level: dict[tuple[int, int], tuple[int, int]] = {}
    with pycolmap.Database.open(db_path) as db:
        for n, (i, j) in enumerate(seeded):
            say("guided matching", n, len(seeded))
            a, b = image_ids[i], image_ids[j]
            guided = ft.match_guided(feats[i], feats[j], seeds[(i, j)], guided_rad)
            if len(guided) > len(putative[(i, j)]):
                if (i, j) in found_level:  # the report names only pairs it grew
                    level[(i, j)] = found_level[(i, j)]
                merged = np.unique(np.concatenate([putative[(i, j)], guided]), axis=0)
                # One keypoint, one match: the pooled match wins where they disagree.
                _, first_a = np.unique(merged[:, 0], return_index=True)
                merged = merged[np.sort(first_a)]
                _, first_b = np.unique(merged[:, 1], return_index=True)
                merged = merged[np.sort(first_b)]
                putative[(i, j)] = merged
                db.delete_matches(a, b)
                db.delete_two_view_geometry(a, b)
                db.write_matches(a, b, merged.astype(np.uint32))
        if seeded:
            say("guided matching", len(seeded), len(seeded))
    say("verification", 1, 2)
    _verify(db_path, verify, cfg)
    say("verification", 2, 2)
    counts, relatives = {}, {}
    with pycolmap.Database.open(db_path) as db:
        for i, j in pair_list:
            a, b = image_ids[i], image_ids[j]
            inl, rel = 0, None
            if db.exists_two_view_geometry(a, b):
                tvg = db.read_two_view_geometry(a, b)
                inl = len(tvg.inlier_matches)
                pose = tvg.cam2_from_cam1
                if inl >= cfg.min_pair_inliers and pose is not None:
                    rel = (
                        CV_TO_GL @ np.asarray(pose.rotation.matrix()) @ CV_TO_GL,
                        CV_TO_GL @ np.asarray(pose.translation).reshape(3),
                    )
            counts[(i, j)] = (len(putative[(i, j)]), inl)
            relatives[(i, j)] = rel
    say("mapping", 0, 1)
    pano_of = {image_ids[k]: k for k in range(v_count)}
    if v_count == 2:  # COLMAP's mappers want more than one pair: the verified pair is it
        est = _two_view(db_path, image_ids, feats, counts, cfg, w)
    else:
        recs = _map(db_path, image_dir, work, cfg)
        est = _collect(recs, v_count, pano_of, counts, cfg, w, relatives)
        if est.registered.sum() < 2:  # no graph of pairs: the best pair alone, if it holds
            best = max(counts, key=lambda ij: counts[ij][1])
            est = _two_view(db_path, image_ids, feats, counts, cfg, w, best)
    for p in est.pairs:
        p.level_search = level.get((p.i, p.j))
    say("mapping", 1, 1)
    return est


def _seed(db, a: int, b: int, cfg: ColmapConfig) -> tuple[np.ndarray | None, bool]:
    """(The essential matrix (OpenGL frames) of a verified pair that earns guided matching, or
    None; whether the pair has a verified geometry of ``min_pair_inliers``). Guided matching
    harvests matches along whatever epipolar planes it is given: only a calibrated geometry with
    a clear majority of support earns it."""
    pycolmap = load_pycolmap()

    if not db.exists_two_view_geometry(a, b):
        return None, False
    tvg = db.read_two_view_geometry(a, b)
    verified = len(tvg.inlier_matches) >= cfg.min_pair_inliers
    kind = pycolmap.TwoViewGeometryConfiguration
    if len(tvg.inlier_matches) < cfg.min_guided_inliers or tvg.config not in (
        kind.CALIBRATED,
        kind.PLANAR,  # a wall or the floor dominates: the pose is from the homography
    ):
        return None, verified
    pose = tvg.cam2_from_cam1  # None where the matches fit no camera motion
    if pose is None:
        return None, verified
    t_cv = np.asarray(pose.translation).reshape(3)
    if not np.linalg.norm(t_cv) > 0:
        return None, verified
    e_cv = geo.skew(t_cv / np.linalg.norm(t_cv)) @ np.asarray(pose.rotation.matrix())
    return CV_TO_GL @ e_cv @ CV_TO_GL, verified


def _verify(db_path: Path, verify, cfg: ColmapConfig) -> None:
    pycolmap = load_pycolmap()

    pycolmap.geometric_verification(
        db_path,
        verifier_options=pycolmap.GeometricVerifierOptions(num_threads=cfg.num_threads),
        two_view_geometry_options=verify,
    )


def _map(db_path: Path, image_dir: Path, work: Path, cfg: ColmapConfig) -> list[tuple]:
    """[(mapper name, reconstruction)] of COLMAP's global and incremental mappers."""
    pycolmap = load_pycolmap()

    out = []
    gopts = pycolmap.GlobalPipelineOptions(num_threads=cfg.num_threads, random_seed=cfg.seed)
    # COLMAP's global mapper is made for large collections and keeps only points seen by three
    # views or more; a few panoramas have mostly two-view points, and without them a third
    # panorama hangs on a handful of points.
    gopts.mapper.track_min_num_views_per_track = 2
    gopts.mapper.global_positioning.min_num_view_per_track = 2
    gopts.mapper.bundle_adjustment.min_track_length = 2
    gopts.mapper.retriangulation.ignore_two_view_tracks = False
    recs = pycolmap.global_mapping(db_path, image_dir, work / "global", gopts)
    out += [("global", r) for r in recs.values()]
    if not out or max(r.num_reg_images() for _, r in out) < _num_images(db_path):
        iopts = pycolmap.IncrementalPipelineOptions(
            num_threads=cfg.num_threads, random_seed=cfg.seed, min_model_size=2
        )
        # Few panoramas: the first pair may be all there is.
        iopts.mapper.init_min_num_inliers = 2 * cfg.min_pair_inliers
        iopts.mapper.init_min_tri_angle = 4.0
        iopts.mapper.abs_pose_min_num_inliers = cfg.min_pair_inliers
        recs = pycolmap.incremental_mapping(db_path, image_dir, work / "incremental", iopts)
        out += [("incremental", r) for r in recs.values()]
    return out


def _num_images(db_path: Path) -> int:
    pycolmap = load_pycolmap()

    with pycolmap.Database.open(db_path) as db:
        return db.num_images()
