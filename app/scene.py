"""Scene folders: posed 360-degree panoramas in a nerfstudio-style ``transforms.json``.

Layout (DESIGN.md section 3)::

    scene/
      transforms.json   {"camera_model": "EQUIRECTANGULAR", "w": W, "h": H, "frames": [...], ...}
      images/*.png      ERP panoramas, W = 2H, all the same size
      depths/*.png      optional: spherical depth, 16-bit PNG in millimetres, 0 = unknown

Each frame has ``file_path`` (relative to the folder), ``transform_matrix`` (4x4
camera-to-world, OpenGL camera frame: x right, y up, looking down -z; metres) and optionally
``depth_file_path``. Other keys (nerfstudio's ``fl_x``, ``cx``, a ``seed`` or ``baseline``) are
kept as metadata and otherwise ignored.

`inspect_scene` is the one validator: it collects every problem at once, each naming the file or
field, and both `load_scene` and ``panogrf scene check`` use it.
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from scipy.spatial import cKDTree

from panogrf.app.errors import UserError
from panogrf.app.images import (
    ImageReadError,
    read_depth,
    read_rgb_with_notes,
    write_depth,
    write_json_atomic,
    write_rgb,
)

TRANSFORMS = "transforms.json"
CAMERA_MODEL = "EQUIRECTANGULAR"
#: Largest allowed max |R^T R - I| (and last-row deviation) of a pose.
POSE_TOLERANCE = 1e-4
#: Two views closer than this (metres) are "at the same position": no baseline to triangulate.
MIN_VIEW_SEPARATION_M = 1e-3
_RESERVED_KEYS = ("camera_model", "w", "h", "frames")


class SceneError(UserError):
    """An invalid scene folder; ``problems`` lists every problem found, one line each."""

    def __init__(self, root: Path, problems: Sequence[str]) -> None:
        self.root = root
        self.problems = tuple(problems)
        n = len(self.problems)
        lines = "\n".join(f"  {p}" for p in self.problems)
        plural = "s" if n != 1 else ""
        super().__init__(f"invalid scene {root / TRANSFORMS} ({n} problem{plural}):\n{lines}")


@dataclass(frozen=True, eq=False)
class Frame:
    """One posed panorama of a scene."""

    name: str
    """Short name for messages and output files (the image file's stem)."""
    image_path: Path
    """The panorama file (scene root joined with ``file_path``)."""
    c2w: np.ndarray
    """Camera-to-world [4, 4] float64, OpenGL camera frame, metres."""
    depth_path: Path | None = None
    """Spherical depth PNG (mm, 0 = unknown), or None."""


@dataclass(frozen=True, eq=False)
class SceneImages:
    """Pixels and poses of a scene as tensors, ready for the model."""

    images: torch.Tensor
    """[V, 3, H, W] RGB in [0, 1]."""
    c2w: torch.Tensor
    """[V, 4, 4] camera-to-world, OpenGL, metres."""
    depths: torch.Tensor | None
    """[V, 1, H, W] spherical depth in metres, 0 = unknown; None when no view has depth."""

    def to(self, device: torch.device | str) -> SceneImages:
        depths = None if self.depths is None else self.depths.to(device)
        return SceneImages(self.images.to(device), self.c2w.to(device), depths)


@dataclass(frozen=True, eq=False)
class Scene:
    """A validated scene folder; pixels are loaded on request (`load_images`)."""

    root: Path
    width: int
    """Panorama width W in pixels (= 2 * height)."""
    height: int
    frames: tuple[Frame, ...]
    metadata: dict[str, Any] = field(default_factory=dict)
    """Top-level keys of transforms.json other than camera_model, w, h, frames."""
    images: SceneImages | None = None
    """Filled by ``load_scene(..., load_images=True)``."""

    @property
    def num_views(self) -> int:
        return len(self.frames)

    @property
    def c2w(self) -> np.ndarray:
        """[V, 4, 4] float64 camera-to-world poses."""
        return np.stack([f.c2w for f in self.frames])

    @property
    def has_depth(self) -> bool:
        """True when at least one view has a depth map."""
        return any(f.depth_path is not None for f in self.frames)

    def load_images(self, dtype: torch.dtype = torch.float32) -> SceneImages:
        """Read every panorama (and depth map) into tensors on the CPU."""
        pixels = [read_rgb_with_notes(f.image_path)[0] for f in self.frames]
        depths = [None if f.depth_path is None else read_depth(f.depth_path) for f in self.frames]
        return _to_tensors(pixels, depths, self.c2w, dtype)


@dataclass(frozen=True, eq=False)
class SceneReport:
    """What `inspect_scene` found: the scene when valid, else the problems."""

    root: Path
    scene: Scene | None
    """None when there are problems."""
    problems: tuple[str, ...]
    notes: tuple[str, ...]
    """Harmless findings, e.g. conversions applied on load (grayscale -> RGB)."""
    depth_range_m: tuple[float, float] | None
    """(min, max) of known depth over all depth maps, or None."""

    @property
    def ok(self) -> bool:
        return not self.problems


def _to_tensors(
    pixels: Sequence[np.ndarray],
    depths: Sequence[np.ndarray | None],
    c2w: np.ndarray,
    dtype: torch.dtype,
) -> SceneImages:
    images = torch.from_numpy(np.stack(pixels)).permute(0, 3, 1, 2).to(dtype) / 255.0
    depth = None
    if any(d is not None for d in depths):
        h, w = pixels[0].shape[:2]
        filled = [np.zeros((h, w), np.float32) if d is None else d for d in depths]
        depth = torch.from_numpy(np.stack(filled))[:, None].to(dtype)
    return SceneImages(images.contiguous(), torch.from_numpy(c2w).to(dtype), depth)


# --- validation helpers, shared with camera_path.py -------------------------------------------


def number_array(value: Any) -> np.ndarray:
    """A JSON value (nested lists of numbers) -> float64 array; ValueError saying what is wrong."""
    stack = [value]
    while stack:
        item = stack.pop()
        if isinstance(item, list):
            stack.extend(item)
        elif isinstance(item, bool) or not isinstance(item, (int, float)):
            raise ValueError(f"contains a non-number ({_short(item)})")
    try:
        return np.array(value, dtype=np.float64)
    except ValueError:
        raise ValueError("is not a rectangular list of numbers") from None


def pose_problems(m: np.ndarray, tol: float = POSE_TOLERANCE) -> list[str]:
    """Problems of a [4, 4] camera-to-world matrix: finite, rigid (R^T R = I, det +1), last row."""
    if not np.isfinite(m).all():
        return ["contains NaN or infinite values"]
    problems = []
    if np.abs(m[3] - (0.0, 0.0, 0.0, 1.0)).max() > tol:
        problems.append(f"last row is {_fmt_row(m[3])}, expected [0, 0, 0, 1]")
    r = m[:3, :3]
    err = float(np.abs(r.T @ r - np.eye(3)).max())
    if err > tol:
        problems.append(f"rotation is not orthonormal (max |R^T R - I| = {err:.3g})")
    elif np.linalg.det(r) < 0:
        problems.append("rotation is a reflection (det = -1); expected det = +1")
    return problems


def _short(value: Any) -> str:
    text = json.dumps(value) if isinstance(value, (str, bool, dict, type(None))) else repr(value)
    return text if len(text) <= 30 else text[:27] + "..."


def _fmt_row(row: np.ndarray) -> str:
    return "[" + ", ".join(f"{x:g}" for x in row) + "]"


def _positive_int(data: dict, key: str, what: str, problems: list[str]) -> int | None:
    if key not in data:
        problems.append(f"{TRANSFORMS}: {key} is missing ({what})")
        return None
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != int(value):
        problems.append(f"{TRANSFORMS}: {key} must be a positive integer, got {_short(value)}")
        return None
    if value <= 0:
        problems.append(f"{TRANSFORMS}: {key} must be a positive integer, got {value}")
        return None
    return int(value)


def _relative_path(frame: dict, key: str, where: str, problems: list[str]) -> str | None:
    value = frame[key]
    if not isinstance(value, str) or not value:
        problems.append(f"{where}.{key}: expected a file name, got {_short(value)}")
        return None
    if Path(value).is_absolute():
        problems.append(f"{where}.{key} ({value}): must be relative to the scene folder")
        return None
    return value


# --- the validator -------------------------------------------------------------------------


@dataclass
class _Found:
    """Per-frame results while inspecting (None where unusable)."""

    file_path: str | None = None
    size: tuple[int, int] | None = None  # (width, height)
    pixels: np.ndarray | None = None
    c2w: np.ndarray | None = None
    depth_file: str | None = None
    depth: np.ndarray | None = None


def _inspect_frame(root: Path, i: int, frame: Any, keep: bool, problems: list, notes: list):
    where = f"frames[{i}]"
    found = _Found()
    if not isinstance(frame, dict):
        problems.append(f"{where}: expected an object with file_path and transform_matrix")
        return found
    if "file_path" not in frame:
        problems.append(f"{where}.file_path is missing")
    else:
        found.file_path = _relative_path(frame, "file_path", where, problems)
    if found.file_path is not None:
        try:
            pixels, image_notes = read_rgb_with_notes(root / found.file_path)
            found.size = (pixels.shape[1], pixels.shape[0])
            found.pixels = pixels if keep else None
            notes.extend(f"{where} ({found.file_path}): {n}" for n in image_notes)
        except ImageReadError as exc:
            problems.append(f"{where}.file_path ({found.file_path}): {exc.reason}")

    key = f"{where}.transform_matrix"
    if "transform_matrix" not in frame:
        problems.append(f"{key} is missing (4x4 camera-to-world)")
    else:
        try:
            m = number_array(frame["transform_matrix"])
            if m.shape != (4, 4):
                shape = "x".join(map(str, m.shape)) or "a single number"
                problems.append(f"{key}: expected a 4x4 matrix, got {shape}")
            else:
                found_problems = pose_problems(m)
                problems.extend(f"{key}: {p}" for p in found_problems)
                found.c2w = None if found_problems else m
        except ValueError as exc:
            problems.append(f"{key}: {exc}")

    if frame.get("depth_file_path") is not None:
        found.depth_file = _relative_path(frame, "depth_file_path", where, problems)
    if found.depth_file is not None:
        try:
            found.depth = read_depth(root / found.depth_file)
            dh, dw = found.depth.shape
            if found.size is not None and (dw, dh) != found.size:
                problems.append(
                    f"{where}.depth_file_path ({found.depth_file}): depth map is {dw}x{dh} but "
                    f"its image is {found.size[0]}x{found.size[1]} (width x height)"
                )
        except ImageReadError as exc:
            problems.append(f"{where}.depth_file_path ({found.depth_file}): {exc.reason}")
    return found


def _check_sizes(found: list[_Found], w: int | None, h: int | None, problems: list[str]) -> None:
    sized = [(i, f) for i, f in enumerate(found) if f.size is not None]
    if not sized:
        if w is not None and h is not None and w != 2 * h:
            problems.append(f"{TRANSFORMS}: w={w}, h={h} is not 2:1 (an ERP panorama has w = 2h)")
        return
    j, ref = sized[0]
    rw, rh = ref.size
    for i, f in sized[1:]:
        if f.size != ref.size:
            problems.append(
                f"frames[{i}].file_path ({f.file_path}): image is {f.size[0]}x{f.size[1]} but "
                f"frames[{j}] ({ref.file_path}) is {rw}x{rh}; all views must have the same size"
            )
    if rw != 2 * rh:
        problems.append(
            f"frames[{j}].file_path ({ref.file_path}): image is {rw}x{rh} (width x height), "
            "not 2:1; an equirectangular panorama has width = 2 x height"
        )
    if w is not None and h is not None and (w, h) != (rw, rh):
        problems.append(f"{TRANSFORMS}: w={w}, h={h} but the images are {rw}x{rh} (width x height)")


def _check_separation(found: list[_Found], problems: list[str]) -> None:
    posed = [(i, f.c2w[:3, 3]) for i, f in enumerate(found) if f.c2w is not None]
    if len(posed) < 2:
        return
    centres = np.stack([c for _, c in posed])
    for a, b in sorted(cKDTree(centres).query_pairs(MIN_VIEW_SEPARATION_M)):
        dist_mm = 1000.0 * float(np.linalg.norm(centres[a] - centres[b]))
        problems.append(
            f"frames[{posed[a][0]}] and frames[{posed[b][0]}]: views at the same position "
            f"({dist_mm:.2f} mm apart); views must be at least "
            f"{MIN_VIEW_SEPARATION_M * 1000:g} mm apart"
        )


def _read_transforms(root: Path, problems: list[str]) -> dict | None:
    if not root.exists():
        problems.append(f"scene folder not found: {root}")
        return None
    if not root.is_dir():
        problems.append(f"not a folder: {root} (a scene is a folder with {TRANSFORMS})")
        return None
    path = root / TRANSFORMS
    if not path.is_file():
        problems.append(f"{TRANSFORMS}: file not found in {root}")
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        problems.append(f"{TRANSFORMS}: not UTF-8 text")
        return None
    except json.JSONDecodeError as exc:
        problems.append(
            f"{TRANSFORMS}: invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}"
        )
        return None
    if not isinstance(data, dict):
        problems.append(f"{TRANSFORMS}: expected a JSON object at the top level")
        return None
    return data


def _inspect(root: str | os.PathLike[str], keep_pixels: bool) -> tuple[SceneReport, list]:
    root = Path(root)
    problems: list[str] = []
    notes: list[str] = []
    data = _read_transforms(root, problems)
    if data is None:
        return SceneReport(root, None, tuple(problems), (), None), []

    model = data.get("camera_model")
    if model is None:
        problems.append(f'{TRANSFORMS}: camera_model is missing; expected "{CAMERA_MODEL}"')
    elif model != CAMERA_MODEL:
        problems.append(
            f'{TRANSFORMS}: camera_model is {_short(model)}; only "{CAMERA_MODEL}" '
            "(360-degree panoramas) is supported"
        )
    w = _positive_int(data, "w", "panorama width in pixels", problems)
    h = _positive_int(data, "h", "panorama height in pixels", problems)
    frames = data.get("frames")
    if frames is None:
        problems.append(f"{TRANSFORMS}: frames is missing (the list of views)")
        frames = []
    elif not isinstance(frames, list):
        problems.append(f"{TRANSFORMS}: frames must be a list of views")
        frames = []
    elif not frames:
        problems.append(f"{TRANSFORMS}: frames is empty; a scene needs at least one view")

    found = [
        _inspect_frame(root, i, fr, keep_pixels, problems, notes) for i, fr in enumerate(frames)
    ]
    _check_sizes(found, w, h, problems)
    _check_separation(found, problems)

    known = [f.depth[f.depth > 0] for f in found if f.depth is not None]
    known = [k for k in known if k.size]
    depth_range = None
    if known:
        depth_range = (float(min(k.min() for k in known)), float(max(k.max() for k in known)))

    scene = None
    if not problems:
        scene = Scene(
            root=root,
            width=found[0].size[0],
            height=found[0].size[1],
            frames=tuple(
                Frame(
                    name=Path(f.file_path).stem,
                    image_path=root / f.file_path,
                    c2w=f.c2w,
                    depth_path=None if f.depth_file is None else root / f.depth_file,
                )
                for f in found
            ),
            metadata={k: v for k, v in data.items() if k not in _RESERVED_KEYS},
        )
    report = SceneReport(root, scene, tuple(problems), tuple(notes), depth_range)
    return report, found


def inspect_scene(root: str | os.PathLike[str]) -> SceneReport:
    """Validate a scene folder, reading every file once; never raises for bad input."""
    return _inspect(root, keep_pixels=False)[0]


def check_scene(root: str | os.PathLike[str]) -> list[str]:
    """Every problem of a scene folder, one message each (empty when the scene is valid)."""
    return list(inspect_scene(root).problems)


def load_scene(
    root: str | os.PathLike[str], *, load_images: bool = False, dtype: torch.dtype = torch.float32
) -> Scene:
    """Validate and load a scene folder; raises `SceneError` listing every problem.

    With ``load_images`` the returned scene carries its pixels in ``scene.images``.
    """
    report, found = _inspect(root, keep_pixels=load_images)
    if report.scene is None:
        raise SceneError(report.root, report.problems)
    if not load_images:
        return report.scene
    scene = report.scene
    tensors = _to_tensors([f.pixels for f in found], [f.depth for f in found], scene.c2w, dtype)
    return dataclasses.replace(scene, images=tensors)


# --- writing -------------------------------------------------------------------------------


def _numpy(x: Any) -> np.ndarray:
    return x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)


def write_scene(
    root: str | os.PathLike[str],
    c2w: np.ndarray | torch.Tensor,
    images: np.ndarray | torch.Tensor,
    depths: np.ndarray | torch.Tensor | None = None,
    *,
    names: Sequence[str] | None = None,
    metadata: dict[str, Any] | None = None,
) -> Scene:
    """Write a scene folder: ``images/<name>.png``, ``depths/<name>.png``, ``transforms.json``.

    c2w: [V, 4, 4] camera-to-world (OpenGL, metres). images: [V, 3, H, W], float in [0, 1] or
    uint8, W = 2H. depths: [V, 1, H, W] spherical depth in metres (<= 0 or non-finite: unknown).
    names: output file stems (default ``view_000``...). metadata: extra top-level JSON keys.
    Every file is written atomically and transforms.json last, so an interrupted write never
    leaves a transforms.json that points at missing files. Raises ValueError for bad arrays.
    """
    root = Path(root)
    poses = _numpy(c2w).astype(np.float64)
    pixels = _numpy(images)
    if pixels.ndim != 4 or pixels.shape[1] != 3:
        raise ValueError(f"images must be [V, 3, H, W], got shape {pixels.shape}")
    v, _, h, w = pixels.shape
    if v == 0 or w != 2 * h:
        raise ValueError(f"need at least one 2:1 panorama, got images of shape {pixels.shape}")
    if poses.shape != (v, 4, 4):
        raise ValueError(f"c2w must be [{v}, 4, 4] to match the images, got {poses.shape}")
    for i, m in enumerate(poses):
        if found := pose_problems(m):
            raise ValueError(f"c2w[{i}]: {'; '.join(found)}")
    depth = None if depths is None else _numpy(depths)
    if depth is not None and depth.shape != (v, 1, h, w):
        raise ValueError(f"depths must be [{v}, 1, {h}, {w}], got shape {depth.shape}")
    names = [f"view_{i:03d}" for i in range(v)] if names is None else list(names)
    if len(names) != v or len(set(names)) != v:
        raise ValueError(f"need {v} distinct names, got {names}")
    for name in names:
        if not name or name.startswith(".") or "/" in name or "\\" in name:
            raise ValueError(f"invalid view name {name!r}: use a plain file stem")
    metadata = dict(metadata or {})
    if clash := set(metadata) & set(_RESERVED_KEYS):
        raise ValueError(f"metadata may not set {sorted(clash)}")

    (root / "images").mkdir(parents=True, exist_ok=True)
    if depth is not None:
        (root / "depths").mkdir(exist_ok=True)
    frames, entries = [], []
    for i, name in enumerate(names):
        image_file = f"images/{name}.png"
        write_rgb(root / image_file, pixels[i].transpose(1, 2, 0))
        entry: dict[str, Any] = {"file_path": image_file, "transform_matrix": poses[i].tolist()}
        depth_path = None
        if depth is not None:
            entry["depth_file_path"] = f"depths/{name}.png"
            depth_path = root / entry["depth_file_path"]
            write_depth(depth_path, depth[i, 0])
        entries.append(entry)
        frames.append(Frame(name, root / image_file, poses[i], depth_path))
    data = {"camera_model": CAMERA_MODEL, "w": w, "h": h, **metadata, "frames": entries}
    write_json_atomic(root / TRANSFORMS, data)
    return Scene(root, w, h, tuple(frames), metadata)
