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
their median residual in degrees) and one per panorama.
"""

from __future__ import annotations

import contextlib
import math
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from panogrf.app.poses import CV_TO_GL
from panogrf.app.poses import features as ft
from panogrf.app.poses import geometry as geo


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
    num_threads: int = -1
    """COLMAP's threads (-1: all cores)."""
    seed: int = 0


@dataclass
class PairReport:
    """One pair of panoramas."""

    i: int
    j: int
    matches: int = 0
    """Putative matches (pooled, then grown along the verified epipolar planes)."""
    inliers: int = 0
    """Matches that passed COLMAP's geometric verification."""
    shared_points: int = 0
    """Points of the reconstruction seen by both panoramas."""
    residual_deg: float | None = None
    """Median reprojection residual of those points (degrees; None: no shared points)."""
    ok: bool = False
    reason: str = ""


@dataclass
class ViewReport:
    index: int
    registered: bool = False
    points: int = 0
    residual_deg: float | None = None
    note: str = ""


@dataclass
class ColmapEstimate:
    """Poses of the registered panoramas and the evidence behind them."""

    c2w: np.ndarray
    """[V, 4, 4] camera-to-world (OpenGL), COLMAP's world frame; NaN for unregistered views."""
    registered: np.ndarray
    """[V] bool."""
    points: np.ndarray
    """[P, 3] the reconstruction's points, same frame."""
    pairs: list[PairReport] = field(default_factory=list)
    views: list[ViewReport] = field(default_factory=list)
    residual_deg: float | None = None
    """Median reprojection residual over all observations (degrees)."""
    mapper: str = ""
    """Which of COLMAP's mappers gave the poses."""
    seconds: float = 0.0

    @property
    def view_notes(self) -> list[str]:
        return [v.note for v in self.views]


def estimate_poses_colmap(
    images: list[np.ndarray],
    cfg: ColmapConfig = ColmapConfig(),
    progress=None,
    work_dir: Path | None = None,
) -> ColmapEstimate:
    """Poses of panoramas [H, W, 3] uint8 (RGB), at least two, all the same size.

    Each step is a `panogrf.model.progress` stage ("posing: features", "posing: matching",
    "posing: verification", "posing: mapping"); ``progress(stage, done, total)`` is also called
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
    (matplotlib, the viewer's screenshots) aborts in ``deflateEnd``."""
    import zlib  # noqa: F401 - loads the system's libz first

    import PIL.Image  # noqa: F401
    import pycolmap

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
    guided_rad = cfg.guided_px * math.pi / 512.0  # equator pixels at 1024 columns -> radians
    first: dict[tuple[int, int], tuple[int, int]] = {}
    with pycolmap.Database.open(db_path) as db:
        for i, j in pair_list:
            a, b = image_ids[i], image_ids[j]
            if not db.exists_two_view_geometry(a, b):
                continue
            tvg = db.read_two_view_geometry(a, b)
            first[(i, j)] = (len(tvg.inlier_matches), int(tvg.config))
            # Guided matching harvests matches along whatever epipolar planes it is given: only
            # a calibrated geometry with a clear majority of support earns it.
            kind = pycolmap.TwoViewGeometryConfiguration
            if len(tvg.inlier_matches) < cfg.min_guided_inliers or tvg.config not in (
                kind.CALIBRATED,
                kind.PLANAR,  # a wall or the floor dominates: the pose is from the homography
            ):
                continue
            pose = tvg.cam2_from_cam1
            t_cv = np.asarray(pose.translation).reshape(3)
            if not np.linalg.norm(t_cv) > 0:
                continue
            e_cv = geo.skew(t_cv / np.linalg.norm(t_cv)) @ np.asarray(pose.rotation.matrix())
            guided = ft.match_guided(feats[i], feats[j], CV_TO_GL @ e_cv @ CV_TO_GL, guided_rad)
            if len(guided) > len(putative[(i, j)]):
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
                if inl >= cfg.min_pair_inliers:
                    pose = tvg.cam2_from_cam1
                    rel = (
                        CV_TO_GL @ np.asarray(pose.rotation.matrix()) @ CV_TO_GL,
                        CV_TO_GL @ np.asarray(pose.translation).reshape(3),
                    )
            counts[(i, j)] = (len(putative[(i, j)]), inl)
            relatives[(i, j)] = rel
    say("mapping", 0, 1)
    pano_of = {image_ids[k]: k for k in range(v_count)}
    if v_count == 2:  # COLMAP's mappers want more than one pair: the verified pair is it
        est = _two_view(db_path, image_ids, feats, counts, cfg)
    else:
        recs = _map(db_path, image_dir, work, cfg)
        est = _collect(recs, v_count, pano_of, counts, cfg, w, relatives)
        if est.registered.sum() < 2:  # no graph of pairs: the best pair alone, if it holds
            best = max(counts, key=lambda ij: counts[ij][1])
            est = _two_view(db_path, image_ids, feats, counts, cfg, best)
    say("mapping", 1, 1)
    return est


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


def _two_view(db_path, image_ids, feats, counts, cfg: ColmapConfig, pair_ij=(0, 1)):
    """One pair of the panoramas (the only pair, or the best one when COLMAP's mappers, which
    want a graph of pairs, build nothing): COLMAP's verified relative pose, its inliers
    triangulated, and both poses refined together on angular residuals. The other panoramas
    are reported as not registered."""
    pycolmap = load_pycolmap()

    v_count = len(image_ids)
    i, j = pair_ij
    a, b = image_ids[i], image_ids[j]
    matches, inliers = counts[(i, j)]
    pairs = [
        PairReport(x, y, *counts.get((x, y), (0, 0)))
        for x in range(v_count)
        for y in range(x + 1, v_count)
    ]
    pair = next(p for p in pairs if (p.i, p.j) == (i, j))
    for p in pairs:
        if p is not pair:
            p.reason = (
                f"{p.inliers} of {p.matches} matches agree on a geometry: too little overlap "
                "or texture, or not consistent with the rest"
            )
    every = [ViewReport(k) for k in range(v_count)]
    for v in every:
        if v.index not in (i, j):
            v.note = "not registered: no pair links it to the posed pair"
    views = [every[i], every[j]]
    c2w = np.full((v_count, 4, 4), np.nan)
    registered = np.zeros(v_count, bool)
    est = ColmapEstimate(c2w, registered, np.zeros((0, 3)), pairs, every, None, "two-view")
    tvg = None
    with pycolmap.Database.open(db_path) as db:
        if db.exists_two_view_geometry(a, b):
            tvg = db.read_two_view_geometry(a, b)
    if tvg is None or inliers < cfg.min_pair_inliers:
        pair.reason = (
            f"{inliers} of {matches} matches agree on a geometry (< {cfg.min_pair_inliers}): "
            "too little overlap or texture between these two"
        )
        for v in views:
            v.note = f"not registered: {inliers} verified matches with the other panorama"
        return est
    m = np.asarray(tvg.inlier_matches)
    pose = tvg.cam2_from_cam1
    rot_cv = np.asarray(pose.rotation.matrix())
    t_cv = np.asarray(pose.translation).reshape(3)
    # OpenGL camera frames: x_gl = F x_cv on both sides.
    rot, t = CV_TO_GL @ rot_cv @ CV_TO_GL, CV_TO_GL @ t_cv
    t = t / max(np.linalg.norm(t), 1e-12)
    b1, b2 = feats[i].bearings[m[:, 0]], feats[j].bearings[m[:, 1]]
    dist, pts = geo.triangulate_pair(rot, t, b1, b2)
    front = (dist > 0).all(1)
    if front.sum() < cfg.min_pair_inliers:
        pair.reason = f"only {int(front.sum())} verified matches triangulate in front of both"
        for v in views:
            v.note = "not registered: the pair's geometry puts the points behind a camera"
        return est
    pts, b1, b2 = pts[front], b1[front], b2[front]
    # The two poses refined on a spread subset of the points (the adjustment's cost grows
    # with the points; 500 pin two poses down), then every point triangulated again.
    sub = np.random.default_rng(cfg.seed).permutation(len(pts))[:500]
    n = len(sub)
    adj = geo.bundle_adjust(
        np.stack([np.eye(3), rot]),
        np.stack([np.zeros(3), t]),
        pts[sub],
        np.repeat([0, 1], n),
        np.tile(np.arange(n), 2),
        np.concatenate([b1[sub], b2[sub]]),
        loss_scale=cfg.max_error_px * math.pi / 512.0 / 2,
    )
    rot = adj.rots[1] @ adj.rots[0].T
    t = adj.trans[1] - rot @ adj.trans[0]
    dist, pts = geo.triangulate_pair(rot, t, b1, b2)
    p2 = pts @ rot.T + t
    res = np.stack(
        [
            np.arccos(np.clip((pts * b1).sum(1) / np.linalg.norm(pts, axis=1), -1, 1)),
            np.arccos(np.clip((p2 * b2).sum(1) / np.linalg.norm(p2, axis=1), -1, 1)),
        ]
    )
    good = (dist > 0).all(1) & (res < cfg.max_error_px * math.pi / 512.0).all(0)
    for k, (r, tk) in zip((i, j), ((np.eye(3), np.zeros(3)), (rot, t)), strict=True):
        c2w[k] = np.eye(4)
        c2w[k, :3, :3] = r.T
        c2w[k, :3, 3] = -r.T @ tk
        registered[k] = True
    deg = np.degrees(res[:, good])
    est.points = pts[good]
    est.residual_deg = float(np.median(deg)) if deg.size else None
    pair.shared_points = int(good.sum())
    pair.residual_deg = est.residual_deg
    pair.ok = True
    for k, v in enumerate(views):
        v.registered, v.points = True, int(good.sum())
        v.residual_deg = float(np.median(deg[k])) if deg.size else None
        v.note = f"registered: {v.points} points, median residual {v.residual_deg:.3f} deg"
    return est


def _check_pairs(pairs, c2w, registered, relatives) -> dict:
    """{(i, j): why} for registered pairs whose relative pose in the reconstruction disagrees
    with their own verified two-view geometry."""
    out = {}
    for p in pairs:
        rel = relatives.get((p.i, p.j))
        if rel is None or not (registered[p.i] and registered[p.j]):
            continue
        rot_v, t_v = rel  # x_j = rot_v x_i + t_v (camera frames, OpenGL)
        w2c = [np.linalg.inv(c2w[k]) for k in (p.i, p.j)]
        rot = w2c[1][:3, :3] @ w2c[0][:3, :3].T
        t = w2c[1][:3, 3] - rot @ w2c[0][:3, 3]
        d_rot = _angle_deg((np.trace(rot.T @ rot_v) - 1) / 2)
        norm = np.linalg.norm(t) * np.linalg.norm(t_v)
        d_dir = _angle_deg(float(t @ t_v / norm)) if norm > 0 else 180.0
        if d_rot > MAX_PAIR_ROTATION_DEG or d_dir > MAX_PAIR_DIRECTION_DEG:
            out[(p.i, p.j)] = (
                f"its place in the reconstruction disagrees with its own geometry (rotation "
                f"by {d_rot:.1f} deg, direction by {d_dir:.1f} deg)"
            )
    return out


def _num_images(db_path: Path) -> int:
    pycolmap = load_pycolmap()

    with pycolmap.Database.open(db_path) as db:
        return db.num_images()


#: A registered pair's relative pose may differ from its own verified two-view geometry by this
#: much (rotation, translation direction; degrees) before the pair counts as inconsistent.
MAX_PAIR_ROTATION_DEG = 3.0
MAX_PAIR_DIRECTION_DEG = 10.0


def _angle_deg(cos: float) -> float:
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def _collect(
    recs, v_count, pano_of, counts, cfg: ColmapConfig, width: int, relatives=None
) -> ColmapEstimate:
    """The reconstruction that registers most panoramas (then: the smaller residual) as poses
    and the report. A panorama is kept only if it sees ``min_pair_inliers`` points of the
    reconstruction and one of its pairs agrees with that pair's own verified geometry: the
    mapper can place a panorama on a handful of points, and then it is wrong."""
    c2w = np.full((v_count, 4, 4), np.nan)
    registered = np.zeros(v_count, bool)
    px_to_deg = 360.0 / width  # at the equator; towards the poles a pixel is less
    views = [ViewReport(k) for k in range(v_count)]
    pairs = [
        PairReport(i, j, *counts.get((i, j), (0, 0)))
        for i in range(v_count)
        for j in range(i + 1, v_count)
    ]
    points = np.zeros((0, 3))
    residual, mapper = None, ""
    usable = [(n, r) for n, r in recs if r.num_reg_images() >= 2]
    if usable:
        mapper, rec = max(
            usable,
            key=lambda nr: (nr[1].num_reg_images(), -nr[1].compute_mean_reprojection_error()),
        )
        for image in rec.images.values():
            if not image.has_pose:
                continue
            k = pano_of[image.image_id]
            m = np.eye(4)
            m[:3, :4] = np.asarray(image.cam_from_world().matrix())
            c2w_cv = np.linalg.inv(m)
            registered[k] = True
            c2w[k] = c2w_cv
            c2w[k, :3, :3] = c2w_cv[:3, :3] @ CV_TO_GL
        ids = list(rec.points3D.keys())
        points = np.array([rec.points3D[i].xyz for i in ids]).reshape(-1, 3)
        errors = np.array([rec.points3D[i].error for i in ids])
        seen = [{pano_of[e.image_id] for e in rec.points3D[i].track.elements} for i in ids]
        if len(errors):
            residual = float(np.median(errors) * px_to_deg)
        for v in views:
            if registered[v.index]:
                sel = [n for n, s in enumerate(seen) if v.index in s]
                v.registered, v.points = True, len(sel)
                v.residual_deg = float(np.median(errors[sel]) * px_to_deg) if sel else None
                v.note = f"registered: {v.points} points" + (
                    f", median residual {v.residual_deg:.3f} deg" if sel else ""
                )
        for p in pairs:
            sel = [n for n, s in enumerate(seen) if p.i in s and p.j in s]
            p.shared_points = len(sel)
            if sel:
                p.residual_deg = float(np.median(errors[sel]) * px_to_deg)
    inconsistent = _check_pairs(pairs, c2w, registered, relatives or {})
    for v in views:
        if not registered[v.index]:
            continue
        links = [p for p in pairs if v.index in (p.i, p.j) and registered[p.i] and registered[p.j]]
        agreeing = [p for p in links if (p.i, p.j) not in inconsistent and p.inliers]
        if v.points < cfg.min_pair_inliers or not agreeing:
            registered[v.index] = False
            c2w[v.index] = np.nan
            v.registered = False
            v.note = (
                f"not registered: placed on {v.points} points only"
                if v.points < cfg.min_pair_inliers
                else "not registered: its place disagrees with its own pairs' geometry"
            ) + " (wrong matches, or too little overlap)"
    for p in pairs:
        if (p.i, p.j) in inconsistent:
            p.reason = inconsistent[(p.i, p.j)]
        elif p.inliers < cfg.min_pair_inliers:
            p.reason = (
                f"{p.inliers} of {p.matches} matches agree on a geometry "
                f"(< {cfg.min_pair_inliers}): too little overlap or texture between these two"
            )
        elif not (registered[p.i] and registered[p.j]):
            lost = p.i if not registered[p.i] else p.j
            p.reason = f"{p.inliers} inliers, but view {lost} could not be placed (see views)"
        else:
            p.ok = True
    for v in views:
        if not registered[v.index] and not v.note:
            links = [p for p in pairs if v.index in (p.i, p.j)]
            best = max(links, key=lambda p: p.inliers) if links else None
            v.note = "not registered: " + (
                f"at most {best.inliers} verified matches with another panorama"
                if best is not None
                else "no other panorama"
            )
    return ColmapEstimate(c2w, registered, points, pairs, views, residual, mapper)
