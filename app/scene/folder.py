"""Scene folders: posed 360-degree panoramas in a nerfstudio-style ``transforms.json``.

Layout (docs/conventions.md)::

    scene/
      transforms.json   {"camera_model": "EQUIRECTANGULAR", "w": W, "h": H, "frames": [...], ...}
      images/*.png      ERP panoramas, W = 2H, all the same size
      depths/*.png      optional: spherical depth, 16-bit PNG in millimetres, 0 = unknown

Each frame has ``file_path`` (relative to the folder), ``transform_matrix`` (4x4
camera-to-world, OpenGL camera frame: x right, y up, looking down -z; metres) and optionally
``depth_file_path``. Other keys (nerfstudio's ``fl_x``, ``cx``, a ``seed`` or ``baseline``) are
kept as metadata and otherwise ignored.

This module loads and writes scene folders. The containers live in `panogrf.app.scene.types` and
the one validator, `inspect_scene`, in `panogrf.app.scene.check`; it collects every problem at
once, each naming the file or field, and both `load_scene` and ``panogrf scene check`` use it.
Their public names are re-exported here.
"""

from __future__ import annotations

import dataclasses
import errno
import os
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
import torch

from panogrf.app.errors import UserError
from panogrf.app.files.atomic import atomic_output
from panogrf.app.files.images import write_depth, write_json_atomic, write_rgb
from panogrf.app.scene.check import (
    SceneReport,
    check_scene,
    inspect_and_load,
    inspect_scene,
)
from panogrf.app.scene.pose_check import (
    MIN_VIEW_SEPARATION_M,
    POSE_TOLERANCE,
    far_apart_warning,
    number_array,
    pose_problems,
)
from panogrf.app.scene.types import (
    CAMERA_MODEL,
    RESERVED_KEYS,
    TRANSFORMS,
    Frame,
    Scene,
    SceneImages,
)

__all__ = [
    "CAMERA_MODEL",
    "MIN_VIEW_SEPARATION_M",
    "POSE_TOLERANCE",
    "TRANSFORMS",
    "Frame",
    "Scene",
    "SceneError",
    "SceneImages",
    "SceneReport",
    "check_scene",
    "inspect_scene",
    "load_scene",
    "number_array",
    "pose_problems",
    "write_scene",
]


class SceneError(UserError):
    """An invalid scene folder; ``problems`` lists every problem found, one line each."""

    def __init__(self, root: Path, problems: Sequence[str]) -> None:
        self.root = root
        self.problems = tuple(problems)
        # One line: the first problem, and where to see the others.
        first = self.problems[0] if self.problems else "unknown problem"
        more = len(self.problems) - 1
        rest = f" (and {more} more: panogrf scene check {root} lists them)" if more else ""
        where = "" if str(root) in first else f" {root}"  # "scene folder not found: ROOT"
        super().__init__(f"invalid scene{where}: {first}{rest}")


#: The warnings `load_scene` printed in this process.
_WARNED: set[str] = set()


def load_scene(
    root: str | os.PathLike[str], *, load_images: bool = False, dtype: torch.dtype = torch.float32
) -> Scene:
    """Validate and load a scene folder; raises `SceneError` listing every problem.

    With ``load_images`` the returned scene carries its pixels in ``scene.images``. The
    report's warnings (photos kilometres apart) go to stderr, one line each, naming the file,
    once per process.
    """
    if load_images:
        report, images = inspect_and_load(root, dtype)
    else:
        report, images = inspect_scene(root), None
    if report.scene is None:
        raise SceneError(report.root, report.problems)
    _warn(report.root, report.warnings)
    return report.scene if images is None else dataclasses.replace(report.scene, images=images)


def _warn(root: Path, warnings: Sequence[str]) -> None:
    """Print each of a scene's ``warnings`` (each names a file of ``root``) on stderr, once
    per process: a command loads a scene more than once."""
    for warning in warnings:
        line = f"warning: {root / warning}"
        if line not in _WARNED:
            _WARNED.add(line)
            print(line, file=sys.stderr, flush=True)


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
    files: Sequence[str | os.PathLike[str] | None] | None = None,
) -> Scene:
    """Write a scene folder: ``images/<name>.png``, ``depths/<name>.png``, ``transforms.json``.

    c2w: [V, 4, 4] camera-to-world (OpenGL, metres). images: [V, 3, H, W], float in [0, 1] or
    uint8, W = 2H. depths: [V, 1, H, W] spherical depth in metres (<= 0 or non-finite: unknown).
    names: output file stems (default ``view_000``...). metadata: extra top-level JSON keys.
    files: the photographs ``images`` were read from, one per view (None: not a file's own
    pixels, e.g. resized): copied as they are (``images/<name>.jpg`` for a JPEG), not
    re-encoded as PNG (an 8K JPEG of 2.6 MB is an 18 MB PNG, seconds to encode); the scene
    reads them back to the same pixels.
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
    if clash := set(metadata) & set(RESERVED_KEYS):
        raise ValueError(f"metadata may not set {sorted(clash)}")

    (root / "images").mkdir(parents=True, exist_ok=True)
    if depth is not None:
        (root / "depths").mkdir(exist_ok=True)
    frames, entries = [], []
    if files is not None and len(files) != v:
        raise ValueError(f"need {v} files, got {len(files)}")
    for i, name in enumerate(names):
        source = None if files is None else files[i]
        if source is None:
            image_file = f"images/{name}.png"
            write_rgb(root / image_file, pixels[i].transpose(1, 2, 0))
        else:
            image_file = f"images/{name}{Path(source).suffix.lower()}"
            with atomic_output(root / image_file) as tmp:
                shutil.copyfile(source, tmp)
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


def _raise_write(out: Path, exc: BaseException) -> NoReturn:
    if isinstance(exc, OSError):
        raise UserError(f"cannot write {out}: {exc.strerror or exc}") from None
    raise exc


def write_new_scene(out: Path, c2w: np.ndarray, *args: Any, **kwargs: Any) -> None:
    """`write_scene` into ``out``, a folder that is absent or empty; on a failed or interrupted
    write (a full disk, Ctrl-C) what was written goes again, so the same command can run
    again; a failed write's error is one line (UserError). Photos kilometres apart are warned
    about (`far_apart_warning`): a unit mistake is best caught where the poses come in."""
    if out.exists():  # an empty folder the user made (a mount, a link): written into
        try:
            write_scene(out, c2w, *args, **kwargs)
        except BaseException as exc:  # a full disk, Ctrl-C, SIGTERM: no half scene is left
            for item in out.iterdir():
                shutil.rmtree(item, ignore_errors=True) if item.is_dir() else item.unlink()
            _raise_write(out, exc)
    else:  # written whole beside it, then renamed: two runs at once leave one scene
        from panogrf.app.files.atomic import discard, temp_path

        tmp = temp_path(Path(os.path.abspath(out)))
        try:
            write_scene(tmp, c2w, *args, **kwargs)
            os.rename(tmp, out)  # an empty folder made meanwhile is replaced, a scene is not
        except BaseException as exc:
            discard(tmp)
            if isinstance(exc, OSError) and exc.errno in (errno.ENOTEMPTY, errno.EEXIST):
                raise UserError(
                    f"{out}: another run wrote a scene there meanwhile; choose another --out"
                ) from None
            _raise_write(out, exc)
    if (far := far_apart_warning(c2w)) is not None:
        _warn(out, [f"{TRANSFORMS}: {far}"])
