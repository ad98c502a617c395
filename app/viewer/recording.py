"""Keyframes recorded in the viewer: the camera path through them, and the viewer's file writes.

A keyframe keeps what the camera showed when it was added (pose, field of view) and how long
the transition to the next one lasts. The recorded path samples the smooth path through the
keyframes (`panogrf.app.paths.trajectory`) at the path's fps, in real time: ``seconds`` is the
sum of the transitions and the path holds ``seconds x fps`` cameras, one per video frame, each
with the field of view interpolated between its keyframes and the aspect of the recorded image.

Saving never takes the viewer down: a camera path or an image that cannot be written (a missing
or unwritable folder, a folder where the file should be) gives a message that says why, and the
keyframes stay in the session.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from panogrf.app.paths.camera_path import DEFAULT_FOV_DEG, CameraPath, write_camera_path
from panogrf.app.paths.trajectory import frame_times, sample_keyframes, sample_values

#: Seconds of a new keyframe's transition to the next one (nerfstudio's default).
DEFAULT_TRANSITION_S = 2.0
#: Step of the retime keys (, and .), and the shortest transition, seconds.
RETIME_STEP_S = 0.5
#: Height of a perspective path recorded from the viewer; the width follows the window.
PERSPECTIVE_HEIGHT = 720


@dataclass
class Keyframe:
    """One recorded keyframe."""

    c2w: np.ndarray
    """[4, 4] camera-to-world, OpenGL frame, metres."""
    fov: float
    """Vertical field of view, degrees (perspective paths)."""
    transition: float = DEFAULT_TRANSITION_S
    """Seconds from this keyframe to the next one."""


def durations(keys: list[Keyframe]) -> np.ndarray:
    """[K - 1] seconds of the segments between consecutive keyframes."""
    return np.array([k.transition for k in keys[:-1]], np.float64)


def pose_at(keys: list[Keyframe], t: float) -> tuple[np.ndarray, float]:
    """(c2w [4, 4], fov in degrees) on the path through ``keys`` at ``t`` seconds."""
    c2w = np.stack([k.c2w for k in keys])
    d = durations(keys)
    pose = sample_keyframes(c2w, [t], d)[0]
    fov = float(sample_values([k.fov for k in keys], [t], d)[0])
    return pose, fov


def recorded_path(
    keys: list[Keyframe], perspective: bool, pano_height: int, fps: float, aspect: float
) -> CameraPath:
    """The nerfstudio camera path through ``keys`` (K >= 1): ``seconds x fps`` cameras.

    ``pano_height``: rows of an equirectangular path (2:1). ``aspect``: width / height of a
    perspective path (the window's); cameras and keyframes carry the same aspect."""
    if not keys:
        raise ValueError("a camera path needs at least one keyframe")
    d = durations(keys)
    seconds = float(d.sum())
    frames = max(1, round(seconds * fps))
    times = frame_times(frames, seconds)
    poses = sample_keyframes(np.stack([k.c2w for k in keys]), times, d)
    fov = sample_values([k.fov for k in keys], times, d)
    if perspective:
        height = PERSPECTIVE_HEIGHT
        width = max(2, 2 * round(height * aspect / 2))
    else:
        height, width = pano_height, 2 * pano_height
    aspect = width / height
    keyframes = [
        {
            # nerfstudio's keyframes hold the three.js matrix: column-major.
            "matrix": k.c2w.T.reshape(16).tolist(),
            "fov": float(k.fov),
            "aspect": aspect,
            "override_transition_enabled": True,
            "override_transition_sec": float(k.transition),
        }
        for k in keys
    ]
    return CameraPath(
        poses=poses,
        camera_type="perspective" if perspective else "equirectangular",
        render_width=width,
        render_height=height,
        fps=fps,
        seconds=frames / fps,
        fov=fov,
        aspect=np.full(frames, aspect),
        keyframes=keyframes,
        extra={"default_fov": float(keys[0].fov), "default_transition_sec": DEFAULT_TRANSITION_S},
    )


def output_problem(path: Path) -> str | None:
    """Why a file cannot be written at ``path`` (None: no reason known before trying)."""
    path = Path(path)
    parent = path.parent
    if path.is_dir():
        return "it is a folder"
    if not parent.exists():
        return f"the folder {parent} does not exist"
    if not parent.is_dir():
        return f"{parent} is not a folder"
    if not os.access(parent, os.W_OK | os.X_OK):
        return f"the folder {parent} is not writable"
    return None


def _reason(exc: Exception) -> str:
    return getattr(exc, "strerror", None) or str(exc)


def save_path_file(out: Path, path: CameraPath) -> tuple[bool, str]:
    """Write ``path`` to ``out``; (written, a message saying what happened or why not)."""
    problem = output_problem(out)
    if problem is None:
        try:
            write_camera_path(out, path)
        except (OSError, ValueError) as exc:
            problem = _reason(exc)
    if problem is not None:
        return False, f"cannot save the camera path to {out}: {problem} (keyframes kept)"
    return True, (
        f"saved {len(path)} cameras ({path.seconds:.1f} s at {path.fps:g} fps, "
        f"{path.camera_type} {path.render_width}x{path.render_height}) to {out}"
    )


def save_image_file(out: Path, rgb: np.ndarray) -> tuple[bool, str | None]:
    """Write RGB uint8 [H, W, 3] to ``out``; (written, why not or None)."""
    from panogrf.app.files.images import write_rgb

    problem = output_problem(out)
    if problem is None:
        try:
            write_rgb(out, np.ascontiguousarray(rgb))
        except (OSError, ValueError) as exc:
            problem = _reason(exc)
    return problem is None, problem


#: A camera path without nerfstudio keyframes gives at most this many of its cameras as keyframes
#: (evenly spaced, the last one kept), each held for its share of the path's duration.
MAX_LOADED_KEYFRAMES = 64


#: Longest transition a loaded keyframe may ask for (seconds).
MAX_TRANSITION_S = 600.0


def _number(value, where: str, low: float, high: float) -> float:
    """``value`` as a float in (low, high], or a `ValueError` naming ``where``."""
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    if not ok or not low < float(value) <= high:
        raise ValueError(f"{where}: expected a number in ({low:g}, {high:g}], got {value!r}")
    return float(value)


def _keyframe(k, i: int) -> Keyframe:
    """One nerfstudio keyframe checked: a rigid pose within reach, a field of view, a
    transition; a `ValueError` naming the field otherwise."""
    from panogrf.app.scene.pose_check import pose_problems

    where = f"keyframes[{i}]"
    if not isinstance(k, dict) or "matrix" not in k:
        raise ValueError(f"{where}: expected an object with a matrix")
    values = k["matrix"]
    numbers = isinstance(values, list) and len(values) == 16
    if not numbers or not all(
        isinstance(x, int | float) and not isinstance(x, bool) for x in values
    ):
        raise ValueError(f"{where}.matrix: expected 16 numbers (a column-major 4x4 matrix)")
    m = np.asarray(values, np.float64).reshape(4, 4).T
    if problems := pose_problems(m):
        raise ValueError(f"{where}.matrix: {problems[0]}")
    fov = _number(k.get("fov", DEFAULT_FOV_DEG), f"{where}.fov", 0.0, 179.0)
    sec = k.get("override_transition_sec")
    sec = DEFAULT_TRANSITION_S if sec is None else sec
    sec = _number(sec, f"{where}.override_transition_sec", 0.0, MAX_TRANSITION_S)
    return Keyframe(m, fov, sec)


def keyframes_from_path(path: CameraPath) -> list[Keyframe]:
    """The keyframes of a camera path read back (`read_camera_path`), in its world: nerfstudio's
    own keyframes (``matrix`` column-major, ``fov``, ``override_transition_sec``; what the
    viewer's O saves) where it holds them (each checked: a `ValueError` naming the first bad
    field), else cameras of the path itself."""
    if path.keyframes is not None and not isinstance(path.keyframes, list):
        raise ValueError("keyframes: expected a list")
    keys = [_keyframe(k, i) for i, k in enumerate(path.keyframes or [])]
    if keys:
        return keys
    n = len(path.poses)
    pick = np.unique(np.linspace(0, n - 1, min(n, MAX_LOADED_KEYFRAMES)).round().astype(int))
    seconds = path.seconds if path.seconds else n / path.fps
    step = seconds / (len(pick) - 1) if len(pick) > 1 and seconds > 0 else DEFAULT_TRANSITION_S
    fov = path.fov if path.fov is not None else np.full(n, DEFAULT_FOV_DEG)
    return [Keyframe(np.array(path.poses[i], np.float64), float(fov[i]), step) for i in pick]


class KeyframeSession:
    """The keyframes of a viewer session and their playback, without a window.

    The window forwards the keys (K add, C clear, G go to the next, Backspace/Delete delete
    the selected, , . retime it, P play/stop) and shows the messages these methods return."""

    def __init__(self) -> None:
        self.keys: list[Keyframe] = []
        self.selected: int | None = None  # the keyframe G went to or K added
        self.playback: list[Keyframe] | None = None  # a copy: edits do not disturb it
        self.play_time = 0.0
        self.play_pose: np.ndarray | None = None

    def edit(self, name: str, pose: np.ndarray, fov: float) -> tuple[str, Keyframe | None]:
        """Apply key ``name`` at the camera's ``pose`` and ``fov``: (message, the keyframe
        the camera should go to, or None)."""
        keys = self.keys
        if name == "K":
            keys.append(Keyframe(np.array(pose, np.float64), float(fov)))
            self.selected = len(keys) - 1
            return f"keyframe {len(keys)} added (fov {fov:.0f} deg)", None
        if not keys:
            return "no keyframes (K adds one)", None
        sel = len(keys) - 1 if self.selected is None else min(self.selected, len(keys) - 1)
        if name == "C":
            keys.clear()
            self.selected = None
            return "keyframes cleared", None
        if name == "G":
            sel = 0 if self.selected is None else (self.selected + 1) % len(keys)
            self.selected = sel
            return f"at keyframe {sel + 1}/{len(keys)}", keys[sel]
        if name in ("BACKSPACE", "DELETE"):
            keys.pop(sel)
            self.selected = min(sel, len(keys) - 1) if keys else None
            return f"keyframe {sel + 1} deleted, {len(keys)} left", None
        if name in ("COMMA", "PERIOD"):
            step = RETIME_STEP_S * (1 if name == "PERIOD" else -1)
            keys[sel].transition = max(RETIME_STEP_S, keys[sel].transition + step)
            total = float(durations(keys).sum())
            return (
                f"keyframe {sel + 1}: {keys[sel].transition:.1f} s to the next (path {total:.1f} s)"
            ), None
        raise ValueError(f"not a keyframe key: {name}")

    def toggle_playback(self) -> str:
        """P: play the path from its start, or stop it where it is."""
        if self.playback is not None:
            self.stop()
            return "playback stopped"
        if len(self.keys) < 2:
            return "add at least two keyframes (K) to play a path"
        self.playback = [Keyframe(k.c2w.copy(), k.fov, k.transition) for k in self.keys]
        self.play_time = 0.0
        return f"playing {len(self.playback)} keyframes, {durations(self.playback).sum():.1f} s"

    def advance(self, dt: float) -> tuple[np.ndarray, float, bool]:
        """(pose, fov, finished) at the playback time, which then advances by ``dt`` seconds
        (the frame's wall-clock time: playback in real time)."""
        end = float(durations(self.playback).sum())
        t = min(self.play_time, end)
        self.play_pose, fov = pose_at(self.playback, t)
        pose = self.play_pose
        self.play_time += dt
        if t >= end:
            self.stop()
        return pose, fov, t >= end

    def stop(self) -> np.ndarray | None:
        """End the playback; returns the pose it had reached (None: none)."""
        pose = self.play_pose
        self.playback, self.play_pose = None, None
        return pose

    def status(self) -> str:
        """The overlay's keyframe line."""
        text = f"keyframes {len(self.keys)}"
        if self.selected is not None and self.keys:
            sel = min(self.selected, len(self.keys) - 1)
            text += f" (at {sel + 1}, {self.keys[sel].transition:.1f} s)"
        if self.playback is not None:
            text += f"  playing {self.play_time:.1f} s"
        return text
