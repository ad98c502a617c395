"""The scene validator: `inspect_scene` reads a scene folder once and lists every problem.

Each problem names the file or field (and frame index) and says what is wrong; `load_scene` and
``panogrf scene check`` both use it. `number_array` and `pose_problems` are shared with
`panogrf.app.paths.camera_path` and `panogrf.app.scene.folder.write_scene` (they live in
`panogrf.app.scene.pose_check`).
"""

from __future__ import annotations

import json
import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from panogrf.app.files.atomic import parse_json
from panogrf.app.files.images import ImageReadError, read_depth, read_rgb_with_notes
from panogrf.app.scene.pose_check import (
    MAX_LISTED_PAIRS,
    _short,
    far_apart_warning,
    number_array,
    pose_problems,
    same_position_problems,
)
from panogrf.app.scene.types import (
    CAMERA_MODEL,
    RESERVED_KEYS,
    TRANSFORMS,
    Frame,
    Scene,
    SceneImages,
)
from panogrf.model.progress import stage


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
    warnings: tuple[str, ...] = ()
    """Findings of a valid scene that likely spoil its renders (`far_apart_warning`); loading
    the scene prints them (`panogrf.app.scene.folder.load_scene`)."""

    @property
    def ok(self) -> bool:
        return not self.problems


def _positive_int(data: dict, key: str, what: str, problems: list[str]) -> int | None:
    if key not in data:
        problems.append(f"{TRANSFORMS}: {key} is missing ({what})")
        return None
    value = data[key]
    numeric = isinstance(value, (int, float)) and not isinstance(value, bool)
    if not numeric or not math.isfinite(value) or value != int(value):
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
    if os.path.normpath(value).split(os.sep)[0] == os.pardir:  # a scene is one folder
        problems.append(f"{where}.{key} ({value}): must stay inside the scene folder")
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
        except OSError as exc:  # a name too long, a folder it cannot enter
            problems.append(f"{where}.file_path ({_short(found.file_path)}): {_os_reason(exc)}")

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
            if not (found.depth > 0).any():  # every score against it would be NaN
                notes.append(
                    f"{where}.depth_file_path ({found.depth_file}): no known depth (every pixel "
                    "is 0, unknown): left out"
                )
                found.depth_file = found.depth = None
            elif found.size is not None and (dw, dh) != found.size:
                problems.append(
                    f"{where}.depth_file_path ({found.depth_file}): depth map is {dw}x{dh} but "
                    f"its image is {found.size[0]}x{found.size[1]} (width x height)"
                )
        except ImageReadError as exc:
            problems.append(f"{where}.depth_file_path ({found.depth_file}): {exc.reason}")
        except OSError as exc:
            problems.append(
                f"{where}.depth_file_path ({_short(found.depth_file)}): {_os_reason(exc)}"
            )
    return found


def _os_reason(exc: OSError) -> str:
    return f"cannot be read ({(exc.strerror or str(exc)).lower()})"


def _check_sizes(found: list[_Found], w: int | None, h: int | None, problems: list[str]) -> None:
    sized = [(i, f) for i, f in enumerate(found) if f.size is not None]
    if not sized:
        if w is not None and h is not None and w != 2 * h:
            problems.append(f"{TRANSFORMS}: w={w}, h={h} is not 2:1 (an ERP panorama has w = 2h)")
        return
    # The size the others are held to: transforms.json's where a frame has it, else the most
    # common one (not simply the first frame's: one odd frame is then the one named).
    sizes = [f.size for _, f in sized]
    common = max(sizes, key=sizes.count)
    want = (w, h) if (w, h) in sizes else common
    j, ref = next((i, f) for i, f in sized if f.size == want)
    rw, rh = want
    for i, f in sized:
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


def _check_shared_files(found: list[_Found], problems: list[str]) -> None:
    """Two frames reading one panorama: one photograph cannot have two poses."""
    first: dict[str, int] = {}
    shared = []
    for i, f in enumerate(found):
        if f.file_path is None:
            continue
        key = os.path.normpath(f.file_path)
        if key in first:
            shared.append(f"frames[{first[key]}] and frames[{i}] both read {f.file_path}")
        else:
            first[key] = i
    if len(shared) > MAX_LISTED_PAIRS:
        problems.append(
            f"{len(shared)} frames read a panorama another frame reads; the first follow"
        )
    problems.extend(f"{p}: each view needs its own panorama" for p in shared[:MAX_LISTED_PAIRS])


def _check_separation(found: list[_Found], problems: list[str]) -> None:
    posed = [(i, f.c2w[:3, 3]) for i, f in enumerate(found) if f.c2w is not None]
    problems.extend(same_position_problems([i for i, _ in posed], [c for _, c in posed]))


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
        data = parse_json(path.read_text(encoding="utf-8-sig"))
    except UnicodeDecodeError:
        problems.append(f"{TRANSFORMS}: not UTF-8 text")
        return None
    except OSError as exc:  # unreadable: permissions, a folder of that name
        problems.append(f"{TRANSFORMS}: {_os_reason(exc)}")
        return None
    except RecursionError:
        problems.append(f"{TRANSFORMS}: nested too deeply to be a scene")
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


def _check_nadir(data: dict, problems: list[str]) -> None:
    """The scene's own nadir cap, as `render` and `view` will read it."""
    from panogrf.renderer.nadir import METADATA_KEY, parse_nadir

    if METADATA_KEY in data:
        try:
            parse_nadir(data[METADATA_KEY])
        except ValueError as exc:
            problems.append(f"{TRANSFORMS}: {METADATA_KEY}: {exc}")


def _inspect(root: str | os.PathLike[str], keep_pixels: bool) -> tuple[SceneReport, list[_Found]]:
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
    _check_nadir(data, problems)
    frames = data.get("frames")
    if frames is None:
        problems.append(f"{TRANSFORMS}: frames is missing (the list of views)")
        frames = []
    elif not isinstance(frames, list):
        problems.append(f"{TRANSFORMS}: frames must be a list of views")
        frames = []
    elif not frames:
        problems.append(f"{TRANSFORMS}: frames is empty; a scene needs at least one view")

    def inspect(item: tuple[int, Any]) -> tuple[_Found, list[str], list[str]]:
        frame_problems: list[str] = []
        frame_notes: list[str] = []
        frame = _inspect_frame(root, *item, keep_pixels, frame_problems, frame_notes)
        return frame, frame_problems, frame_notes

    # The panoramas are decoded side by side (the decoder leaves Python's lock); problems and
    # notes keep the frames' order.
    workers = max(1, min(len(frames), os.cpu_count() or 1, 8))
    with (
        stage("reading the panoramas", len(frames)) as progress,
        ThreadPoolExecutor(workers) as pool,
    ):
        inspected = []
        for item in pool.map(inspect, enumerate(frames)):
            inspected.append(item)
            progress.advance()
    found = [f for f, _, _ in inspected]
    for _, frame_problems, frame_notes in inspected:
        problems.extend(frame_problems)
        notes.extend(frame_notes)
    _check_sizes(found, w, h, problems)
    _check_shared_files(found, problems)
    _check_separation(found, problems)

    known = [f.depth[f.depth > 0] for f in found if f.depth is not None]
    known = [k for k in known if k.size]
    depth_range = None
    if known:
        depth_range = (float(min(k.min() for k in known)), float(max(k.max() for k in known)))

    scene, warnings = None, []
    if not problems:
        far = far_apart_warning(np.stack([f.c2w for f in found]))
        warnings = [] if far is None else [f"{TRANSFORMS}: {far}"]
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
            metadata={k: v for k, v in data.items() if k not in RESERVED_KEYS},
        )
    report = SceneReport(root, scene, tuple(problems), tuple(notes), depth_range, tuple(warnings))
    return report, found


def inspect_scene(root: str | os.PathLike[str]) -> SceneReport:
    """Validate a scene folder, reading every file once; never raises for bad input."""
    return _inspect(root, keep_pixels=False)[0]


def check_scene(root: str | os.PathLike[str]) -> list[str]:
    """Every problem of a scene folder, one message each (empty when the scene is valid)."""
    return list(inspect_scene(root).problems)


def inspect_and_load(
    root: str | os.PathLike[str], dtype: torch.dtype = torch.float32
) -> tuple[SceneReport, SceneImages | None]:
    """`inspect_scene`, keeping the pixels read on the way: (report, images or None if invalid)."""
    report, found = _inspect(root, keep_pixels=True)
    if report.scene is None:
        return report, None
    pixels = [f.pixels for f in found]
    depths = [f.depth for f in found]
    return report, SceneImages.from_arrays(pixels, depths, report.scene.c2w, dtype)
