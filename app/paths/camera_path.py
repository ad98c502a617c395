"""nerfstudio's ``camera_path.json``: read, validate and write, so paths move between the tools.

The fields (as nerfstudio's viewer writes them)::

    {"camera_type": "equirectangular" | "perspective", "render_width": W, "render_height": H,
     "fps": 30, "seconds": 4.0,
     "camera_path": [{"camera_to_world": [16 numbers, row-major 4x4], "fov": deg, "aspect": a,
                      "render_time": t (optional)}, ...],
     "keyframes": [...], "smoothness_value": 0.5, "is_cycle": false, "crop": {...} | null,
     "default_fov": 75, "default_transition_sec": 2, ...}

Poses are camera-to-world in the OpenGL camera frame (x right, y up, looking down -z), in the
world frame of whatever wrote the file: a path exported by nerfstudio for a model it trained is
in nerfstudio's normalised (dataparser) world, not in the scene's metres. ``fov`` is the
vertical field of view in degrees (ignored for equirectangular cameras). ``keyframes``,
``crop`` and unknown top-level keys are kept as opaque JSON and written back unchanged.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from panogrf.app.errors import UserError
from panogrf.app.files.atomic import parse_json
from panogrf.app.files.images import write_json_atomic
from panogrf.app.scene.folder import number_array, pose_problems

CAMERA_TYPES = ("equirectangular", "perspective")
#: nerfstudio viewer's default vertical field of view, used where a camera has none.
DEFAULT_FOV_DEG = 75.0
#: At most this many problems are listed in one error message.
_MAX_LISTED = 20
#: The frame rate and the duration a path may give (a video encoder takes no rate below one
#: frame a minute or over a thousand a second; a day of video is more than any walk-through).
_TIME_RANGES = {"fps": (1 / 60, 1000.0), "seconds": (1e-3, 86400.0)}
_KNOWN_KEYS = (
    "camera_type",
    "render_width",
    "render_height",
    "fps",
    "seconds",
    "camera_path",
    "keyframes",
    "smoothness_value",
    "is_cycle",
    "crop",
)


@dataclass(frozen=True, eq=False)
class CameraPath:
    """A camera trajectory to render, one camera per output frame."""

    poses: np.ndarray
    """[N, 4, 4] float64 camera-to-world, OpenGL camera frame."""
    camera_type: str = "equirectangular"
    """"equirectangular" (360-degree frames) or "perspective"."""
    render_width: int = 1024
    render_height: int = 512
    fps: float = 30.0
    seconds: float | None = None
    """Duration of the video; None: N / fps."""
    fov: np.ndarray | None = None
    """[N] vertical field of view in degrees; None: `DEFAULT_FOV_DEG` for every camera."""
    aspect: np.ndarray | None = None
    """[N] width / height; None: render_width / render_height."""
    times: np.ndarray | None = None
    """[N] nerfstudio ``render_time`` (dynamic scenes), or None."""
    keyframes: Any = None
    """nerfstudio's keyframes, opaque JSON."""
    smoothness_value: float | None = None
    is_cycle: bool | None = None
    crop: Any = None
    """nerfstudio's crop box, opaque JSON."""
    extra: dict[str, Any] = field(default_factory=dict)
    """Other top-level keys (``default_fov``, ``default_transition_sec``...), opaque JSON."""

    def __post_init__(self) -> None:
        # Programmatic construction (e.g. a recorded path) is checked here; files are checked
        # field by field in `read_camera_path` first, with messages that name the field.
        poses = np.asarray(self.poses, dtype=np.float64)
        if poses.ndim != 3 or poses.shape[1:] != (4, 4) or len(poses) == 0:
            raise ValueError(f"poses must be [N, 4, 4] with N >= 1, got shape {poses.shape}")
        for i, m in enumerate(poses):
            if found := pose_problems(m):
                raise ValueError(f"poses[{i}]: {'; '.join(found)}")
        if self.camera_type not in CAMERA_TYPES:
            raise ValueError(f"camera_type must be one of {CAMERA_TYPES}, got {self.camera_type!r}")
        if self.render_width <= 0 or self.render_height <= 0 or not self.fps > 0:
            raise ValueError("render_width, render_height and fps must be positive")
        n = len(poses)
        fov = np.full(n, DEFAULT_FOV_DEG) if self.fov is None else self.fov
        aspect = (
            np.full(n, self.render_width / self.render_height)
            if self.aspect is None
            else self.aspect
        )
        per_camera = {"fov": fov, "aspect": aspect}
        if self.times is not None:
            per_camera["times"] = self.times
        for name, values in per_camera.items():
            values = np.asarray(values, dtype=np.float64)
            if values.shape != (n,):
                raise ValueError(f"{name} must have shape [{n}], got {values.shape}")
            object.__setattr__(self, name, values)
        object.__setattr__(self, "poses", poses)
        object.__setattr__(self, "seconds", n / self.fps if self.seconds is None else self.seconds)

    def __len__(self) -> int:
        return len(self.poses)


def _number(value: Any) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)


def _check_top(data: dict, problems: list[str]) -> None:
    camera_type = data.get("camera_type", "perspective")  # nerfstudio's default
    if camera_type not in CAMERA_TYPES:
        problems.append(
            'camera_type: expected "equirectangular" or "perspective", '
            f"got {json.dumps(camera_type)}"
        )
    for key in ("render_width", "render_height"):
        value = data.get(key)
        if value is None:
            problems.append(f"{key} is missing (output size in pixels)")
        elif not _number(value) or value <= 0 or value != int(value):
            problems.append(f"{key}: expected a positive integer, got {json.dumps(value)}")
    for key, (low, high) in _TIME_RANGES.items():
        value = data.get(key)
        if value is None:
            problems.append(f"{key} is missing")
        elif not _number(value) or not low <= value <= high:
            problems.append(
                f"{key}: expected a number in [{low:g}, {high:g}], got {json.dumps(value)}"
            )
    if data.get("smoothness_value") is not None and not _number(data["smoothness_value"]):
        problems.append(
            f"smoothness_value: expected a number, got {json.dumps(data['smoothness_value'])}"
        )
    if data.get("is_cycle") is not None and not isinstance(data["is_cycle"], bool):
        problems.append(f"is_cycle: expected true or false, got {json.dumps(data['is_cycle'])}")


def _check_camera(i: int, camera: Any, perspective: bool, problems: list[str]) -> np.ndarray | None:
    """Problems of ``camera_path[i]``; returns its [4, 4] pose when usable."""
    where = f"camera_path[{i}]"
    if not isinstance(camera, dict):
        problems.append(f"{where}: expected an object with camera_to_world")
        return None
    pose = None
    if "camera_to_world" not in camera:
        problems.append(f"{where}.camera_to_world is missing")
    else:
        try:
            m = number_array(camera["camera_to_world"])
            if m.size != 16 or m.ndim not in (1, 2):
                problems.append(
                    f"{where}.camera_to_world: expected 16 numbers (a row-major 4x4 matrix), "
                    f"got shape {list(m.shape)}"
                )
            else:
                m = m.reshape(4, 4)  # nerfstudio writes the flattened row-major matrix
                found = pose_problems(m)
                problems.extend(f"{where}.camera_to_world: {p}" for p in found)
                pose = None if found else m
        except ValueError as exc:
            problems.append(f"{where}.camera_to_world: {exc}")
    fov = camera.get("fov")
    if fov is None and perspective:
        problems.append(f"{where}.fov is missing (vertical field of view in degrees)")
    elif fov is not None and (not _number(fov) or not 0 < fov < 180):
        problems.append(f"{where}.fov: expected degrees in (0, 180), got {json.dumps(fov)}")
    for key in ("aspect", "render_time"):
        value = camera.get(key)
        if value is not None and (not _number(value) or (key == "aspect" and value <= 0)):
            problems.append(f"{where}.{key}: expected a positive number, got {json.dumps(value)}")
    return pose


def _raise(path: Path, problems: list[str]) -> None:
    """One line: the first problem, then the others (at most `_MAX_LISTED` in all)."""
    first, rest = problems[0], problems[1:_MAX_LISTED]
    more = ""
    if len(problems) > 1:
        unlisted = len(problems) - _MAX_LISTED
        tail = f"; and {unlisted} more" if unlisted > 0 else ""
        more = f" (and {len(problems) - 1} more: {'; '.join(rest)}{tail})"
    raise UserError(f"invalid camera path {path}: {first}{more}")


def read_camera_path(path: str | os.PathLike[str]) -> CameraPath:
    """Read and validate a nerfstudio ``camera_path.json``; `UserError` lists every problem."""
    path = Path(path)
    if path.is_dir():
        raise UserError(f"{path}: a folder, not a camera path file")
    if not path.is_file():
        what = "not a regular file" if path.exists() else "camera path file not found"
        raise UserError(f"{path}: {what}")
    try:
        data = parse_json(path.read_text(encoding="utf-8-sig"))
    except UnicodeDecodeError:
        raise UserError(f"{path}: not UTF-8 text") from None
    except OSError as exc:
        raise UserError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    except RecursionError:
        raise UserError(f"{path}: nested too deeply to be a camera path") from None
    except json.JSONDecodeError as exc:
        raise UserError(
            f"{path}: invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}"
        ) from None
    if not isinstance(data, dict):
        raise UserError(f"{path}: expected a JSON object at the top level")

    problems: list[str] = []
    _check_top(data, problems)
    cameras = data.get("camera_path")
    if not isinstance(cameras, list):
        what = "missing" if cameras is None else "not a list"
        problems.append(f"camera_path is {what} (the list of cameras to render)")
        cameras = []
    elif not cameras:
        problems.append("camera_path is empty: no cameras to render")
    perspective = data.get("camera_type", "perspective") == "perspective"
    poses = [_check_camera(i, cam, perspective, problems) for i, cam in enumerate(cameras)]
    if problems:
        _raise(path, problems)

    width, height = int(data["render_width"]), int(data["render_height"])
    fov = [cam.get("fov", DEFAULT_FOV_DEG) for cam in cameras]
    aspect = [cam.get("aspect", width / height) for cam in cameras]
    times = [cam.get("render_time") for cam in cameras]
    return CameraPath(
        poses=np.stack(poses),
        camera_type=data.get("camera_type", "perspective"),
        render_width=width,
        render_height=height,
        fps=float(data["fps"]),
        seconds=float(data["seconds"]),
        fov=np.array(fov, dtype=np.float64),
        aspect=np.array(aspect, dtype=np.float64),
        # nerfstudio uses times only when every camera has one; so do we.
        times=np.array(times, dtype=np.float64) if None not in times else None,
        keyframes=data.get("keyframes"),
        smoothness_value=data.get("smoothness_value"),
        is_cycle=data.get("is_cycle"),
        crop=data.get("crop"),
        extra={k: v for k, v in data.items() if k not in _KNOWN_KEYS},
    )


def duration_note(path: CameraPath) -> str | None:
    """A note when the path's ``seconds`` disagrees with its cameras: a video has one frame per
    camera at ``fps``, so it lasts ``len(path) / fps`` whatever ``seconds`` says (nerfstudio
    writes ``seconds x fps`` cameras; a hand-edited file may not). None when they agree to
    within a frame."""
    video = len(path) / path.fps
    if abs(video - path.seconds) <= 1.0 / path.fps + 1e-9:
        return None
    return (
        f"note: the path says seconds {path.seconds:g} but holds {len(path)} cameras at "
        f"{path.fps:g} fps: the video has one frame per camera and lasts {video:.2f} s "
        f"(to change its length, resample the path; to change its speed, its fps)"
    )


def camera_path_to_json(path: CameraPath) -> dict[str, Any]:
    """The JSON object nerfstudio reads (optional fields only where set)."""
    data: dict[str, Any] = dict(path.extra)
    if path.keyframes is not None:
        data["keyframes"] = path.keyframes
    data.update(
        camera_type=path.camera_type,
        render_height=int(path.render_height),
        render_width=int(path.render_width),
        fps=float(path.fps),
        seconds=float(path.seconds),
    )
    if path.is_cycle is not None:
        data["is_cycle"] = bool(path.is_cycle)
    if path.smoothness_value is not None:
        data["smoothness_value"] = float(path.smoothness_value)
    cameras = []
    for i, pose in enumerate(path.poses):
        camera = {
            "camera_to_world": pose.reshape(16).tolist(),
            "fov": float(path.fov[i]),
            "aspect": float(path.aspect[i]),
        }
        if path.times is not None:
            camera["render_time"] = float(path.times[i])
        cameras.append(camera)
    data["camera_path"] = cameras
    if path.crop is not None:
        data["crop"] = path.crop
    return data


def write_camera_path(path: str | os.PathLike[str], camera_path: CameraPath) -> None:
    """Write ``camera_path`` as nerfstudio's ``camera_path.json``, atomically."""
    write_json_atomic(path, camera_path_to_json(camera_path))
