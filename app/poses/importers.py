"""Poses from tools people already run, converted to this project's convention.

Every reader returns `ImportedPoses`: camera-to-world [V, 4, 4] in the OpenGL camera frame
(x right, y up, looking down -z), in the tool's world frame and units (levelling and scale are
`panogrf.app.poses.scale`'s job). The tools' camera frames are OpenCV's (x right, y down,
looking down +z), converted with `CV_TO_GL`.

- **TUM trajectory** (stella_vslam / OpenVSLAM ``frame_trajectory.txt`` or
  ``keyframe_trajectory.txt`` in TUM format): one line per pose,
  ``timestamp tx ty tz qx qy qz qw``, the camera-to-world pose (centre t, rotation q, Hamilton
  quaternion with w last). stella_vslam's equirectangular bearing is
  ``(cos(lat) sin(lon), -sin(lat), cos(lat) cos(lon))``: the centre column looks down +z, y
  down; that is the OpenCV frame. Lines starting with ``#`` are comments.
- **OpenSfM** ``reconstruction.json``: a list of reconstructions (the largest is used), each
  with ``cameras`` (``projection_type`` "spherical" or "equirectangular") and ``shots`` keyed by
  image file name with ``rotation`` (axis-angle) and ``translation``: world-to-camera,
  ``x_cam = R x_world + t``, OpenCV camera frame (OpenSfM's spherical bearing has the same
  axes as stella_vslam's).
- **COLMAP** text model ``images.txt`` of panoramas split into cube faces: lines
  ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` (world-to-camera, OpenCV frame) each
  followed by a line of 2D points. NAME is ``<panorama stem>/<face>.<ext>`` (or
  ``<stem>_<face>.<ext>``) with ``<face>`` one of front, right, back, left, up, down: 90-degree
  pinhole faces as `panogrf.model.cubemap` renders them (front looks at the panorama's centre
  column, right at its right quarter; ``panogrf scene faces`` writes them). A panorama's pose
  is the chordal mean of its registered faces' poses, each turned back by its face rotation.

The ``write_*`` functions write the same formats; the round-trip tests use them.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from panogrf.app.errors import UserError
from panogrf.app.files.atomic import parse_json, write_text_atomic
from panogrf.app.poses import CV_TO_GL
from panogrf.model.cubemap import FACE_NAMES, face_rotations

FORMATS = ("tum", "opensfm", "colmap")


@dataclass(frozen=True)
class ImportedPoses:
    """Poses read from another tool's file."""

    names: list[str] | None
    """Image names (OpenSfM shot names, COLMAP panorama stems), or None (TUM: in file order)."""
    c2w: np.ndarray
    """[V, 4, 4] camera-to-world, OpenGL camera frame, the tool's world frame and units."""
    notes: list[str] = field(default_factory=list)
    """What was skipped or averaged, one line each."""


def _pose(rot_c2w_cv: np.ndarray, centre: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = rot_c2w_cv @ CV_TO_GL
    out[:3, 3] = centre
    return out


def _read_text(path: Path) -> str:
    try:
        return Path(path).read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: cannot read ({exc.__class__.__name__})") from None


# --- TUM ----------------------------------------------------------------------------------


def read_tum(path: str | Path) -> ImportedPoses:
    """A TUM-format trajectory (camera-to-world, OpenCV camera frame) -> poses in file order."""
    path = Path(path)
    poses = []
    for n, line in enumerate(_read_text(path).splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        try:
            values = [float(x) for x in line.split()]
        except ValueError:
            values = []
        if len(values) != 8 or not np.all(np.isfinite(values)):
            raise UserError(f"{path}:{n}: expected 'timestamp tx ty tz qx qy qz qw'")
        q = np.array(values[4:8])
        if np.abs(q).max() > 2 or abs(np.linalg.norm(q) - 1) > 1e-3:  # no overflow in the norm
            raise UserError(f"{path}:{n}: the quaternion is not unit length")
        poses.append(_pose(Rotation.from_quat(q).as_matrix(), np.array(values[1:4])))
    if not poses:
        raise UserError(f"{path}: no poses in the file")
    return ImportedPoses(None, np.stack(poses))


def write_tum(path: str | Path, c2w: np.ndarray, timestamps: list[float] | None = None) -> None:
    """Write poses [V, 4, 4] (OpenGL camera frame) as a TUM trajectory (OpenCV frame)."""
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for i, m in enumerate(c2w):
        q = Rotation.from_matrix(m[:3, :3] @ CV_TO_GL).as_quat()
        ts = float(i if timestamps is None else timestamps[i])
        lines.append(" ".join(f"{x:.9f}" for x in (ts, *m[:3, 3], *q)))
    write_text_atomic(path, "\n".join(lines) + "\n")


# --- OpenSfM ------------------------------------------------------------------------------

_SPHERICAL = ("spherical", "equirectangular")


def read_opensfm(path: str | Path) -> ImportedPoses:
    """An OpenSfM reconstruction.json with spherical cameras -> poses sorted by shot name."""
    path = Path(path)
    try:
        data = parse_json(_read_text(path))
    except json.JSONDecodeError as exc:
        raise UserError(f"{path}: not JSON ({exc.msg}, line {exc.lineno})") from None
    except RecursionError:
        raise UserError(f"{path}: nested too deeply to be an OpenSfM reconstruction") from None
    if isinstance(data, dict):
        data = [data]
    if not isinstance(data, list) or not all(isinstance(r, dict) for r in data) or not data:
        raise UserError(f"{path}: expected a list of reconstructions")
    sizes = [len(r["shots"]) if isinstance(r.get("shots"), dict) else 0 for r in data]
    rec = data[int(np.argmax(sizes))]
    notes = []
    if len(data) > 1:
        notes.append(f"{len(data)} reconstructions; used the largest ({max(sizes)} shots)")
    cameras = rec.get("cameras") or {}
    shots = rec.get("shots") or {}
    if not isinstance(cameras, dict) or not isinstance(shots, dict):
        raise UserError(f'{path}: "cameras" and "shots" must be objects keyed by name')
    names, poses = [], []
    for name in sorted(shots):
        shot = shots[name]
        if (
            isinstance(shot, dict)
            and isinstance(shot.get("camera"), str)
            and (shot["camera"] not in cameras)
        ):
            raise UserError(
                f'{path}: shot {name!r} names camera {shot["camera"]!r}, which "cameras" '
                "does not define"
            )
        try:
            camera = cameras[shot["camera"]]
            r = np.asarray(shot["rotation"], float)
            t = np.asarray(shot["translation"], float)
        except (KeyError, TypeError, ValueError):
            raise UserError(
                f"{path}: shot {name!r} lacks camera, rotation or translation"
            ) from None
        if not isinstance(camera, dict):
            raise UserError(f"{path}: camera {shot['camera']!r} is not an object")
        kind = camera.get("projection_type")
        if kind not in _SPHERICAL:
            raise UserError(
                f"{path}: shot {name!r} has a {kind!r} camera; only spherical (equirectangular) "
                "cameras are panoramas"
            )
        if r.shape != (3,) or t.shape != (3,) or not np.all(np.isfinite(np.r_[r, t])):
            raise UserError(f"{path}: shot {name!r}: rotation and translation must be 3 numbers")
        rot_w2c = Rotation.from_rotvec(r).as_matrix()
        if not np.all(np.isfinite(rot_w2c)):  # an angle too large to turn into a rotation
            raise UserError(
                f"{path}: shot {name!r}: rotation {r.tolist()} is too large to be an angle"
            )
        names.append(name)
        poses.append(_pose(rot_w2c.T, -rot_w2c.T @ t))
    if not poses:
        raise UserError(f"{path}: the reconstruction has no shots")
    return ImportedPoses(names, np.stack(poses), notes)


def write_opensfm(
    path: str | Path, names: list[str], c2w: np.ndarray, width: int, height: int
) -> None:
    """Write poses [V, 4, 4] (OpenGL camera frame) as a one-reconstruction OpenSfM file."""
    shots = {}
    for name, m in zip(names, c2w, strict=True):
        rot_w2c = (m[:3, :3] @ CV_TO_GL).T
        shots[name] = {
            "camera": "pano",
            "rotation": Rotation.from_matrix(rot_w2c).as_rotvec().tolist(),
            "translation": (-rot_w2c @ m[:3, 3]).tolist(),
        }
    camera = {"projection_type": "spherical", "width": width, "height": height}
    write_text_atomic(path, json.dumps([{"cameras": {"pano": camera}, "shots": shots}], indent=1))


# --- COLMAP -------------------------------------------------------------------------------

_FACE_NAME = re.compile(r"^(?P<pano>.+)[/_](?P<face>" + "|".join(FACE_NAMES) + r")\.[^./]+$")


def _chordal_mean(rots: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(rots.sum(0))
    return u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt


def _number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


#: The most the faces of one panorama may disagree on its rotation (a reconstruction of a rig
#: puts them within a degree or so).
MAX_FACE_DISAGREEMENT_DEG = 10.0


def read_colmap(path: str | Path) -> ImportedPoses:
    """COLMAP images.txt of cube-face views -> one pose per panorama, sorted by stem."""
    path = Path(path)
    lines = [x for x in _read_text(path).splitlines() if not x.startswith("#")]
    faces = face_rotations(torch.float64).numpy()
    per_pano: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    skipped, seen = [], set()
    for k in range(0, len(lines), 2):
        parts = lines[k].split()
        if not parts:
            continue
        if len(parts) < 10:
            raise UserError(f"{path}: expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'")
        after = lines[k + 1].split() if k + 1 < len(lines) else []
        if len(after) >= 10 and not _number(after[9]):  # POINTS2D lines are all numbers
            raise UserError(
                f"{path}: image {parts[0]} is followed by another image line where its POINTS2D "
                "line belongs (images.txt has two lines per image; the second may be empty)"
            )
        try:
            qw, qx, qy, qz, tx, ty, tz = (float(x) for x in parts[1:8])
        except ValueError:
            raise UserError(f"{path}: image {parts[0]}: pose values are not numbers") from None
        values = np.array([qw, qx, qy, qz, tx, ty, tz])
        if not np.isfinite(values).all():
            raise UserError(f"{path}: image {parts[0]}: pose values must be finite numbers")
        if abs(np.linalg.norm(values[:4]) - 1) > 1e-3:
            raise UserError(f"{path}: image {parts[0]}: the quaternion is not unit length")
        name = " ".join(parts[9:])
        if name in seen:
            raise UserError(f"{path}: {name} is listed twice")
        seen.add(name)
        match = _FACE_NAME.match(name)
        if match is None:
            skipped.append(name)
            continue
        rot_w2c = Rotation.from_quat([qx, qy, qz, qw]).as_matrix()
        face_c2w = _pose(rot_w2c.T, -rot_w2c.T @ np.array([tx, ty, tz]))
        rot_pano = face_c2w[:3, :3] @ faces[FACE_NAMES.index(match["face"])].T
        per_pano.setdefault(match["pano"], []).append((rot_pano, face_c2w[:3, 3], name))
    notes = []
    if skipped:
        notes.append(f"{len(skipped)} images not named <panorama>/<face>.<ext>, skipped")
    if not per_pano:
        raise UserError(
            f"{path}: no image named <panorama>/<face>.<ext> with a face in {list(FACE_NAMES)}"
        )
    names, poses = sorted(per_pano), []
    for name in names:
        rots = np.stack([r for r, _, _ in per_pano[name]])
        centres = np.stack([c for _, c, _ in per_pano[name]])
        m = np.eye(4)
        m[:3, :3] = _chordal_mean(rots)
        m[:3, 3] = centres.mean(0)
        off = [np.degrees(Rotation.from_matrix(m[:3, :3].T @ r).magnitude()) for r in rots]
        spread = max(off)
        if spread > MAX_FACE_DISAGREEMENT_DEG:  # one rig: its faces turn together
            face = per_pano[name][int(np.argmax(off))][2]
            raise UserError(
                f"{path}: {face} is turned {spread:.0f} deg from the other faces of {name} "
                "(a cube's faces share one rotation): fix or remove its line"
            )
        if len(rots) > 1:
            notes.append(
                f"{name}: {len(rots)} faces, rotations within {spread:.2f} deg, centres within "
                f"{np.linalg.norm(centres - m[:3, 3], axis=1).max():.3g} of their mean"
            )
        poses.append(m)
    return ImportedPoses(names, np.stack(poses), notes)


def write_colmap(
    path: str | Path, names: list[str], c2w: np.ndarray, faces: tuple[str, ...] = FACE_NAMES
) -> None:
    """Write panorama poses [V, 4, 4] as COLMAP images.txt lines of their cube faces."""
    rots = face_rotations(torch.float64).numpy()
    lines = ["# IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME", "# POINTS2D[] as (X, Y, POINT3D_ID)"]
    k = 0
    for name, m in zip(names, c2w, strict=True):
        for face in faces:
            k += 1
            rot_c2w_cv = m[:3, :3] @ rots[FACE_NAMES.index(face)] @ CV_TO_GL
            rot_w2c = rot_c2w_cv.T
            qx, qy, qz, qw = Rotation.from_matrix(rot_w2c).as_quat()
            t = -rot_w2c @ m[:3, 3]
            lines += [
                " ".join(str(x) for x in (k, qw, qx, qy, qz, *t, 1, f"{name}/{face}.png")),
                "",
            ]
    write_text_atomic(path, "\n".join(lines) + "\n")


def read_poses(fmt: str, path: str | Path) -> ImportedPoses:
    """Dispatch on ``fmt`` (one of `FORMATS`)."""
    readers = {"tum": read_tum, "opensfm": read_opensfm, "colmap": read_colmap}
    if fmt not in readers:
        raise UserError(f"--format: choose from {list(FORMATS)}, got {fmt!r}")
    if not Path(path).is_file():
        raise UserError(f"{path}: file not found")
    return readers[fmt](path)
