"""Typed containers of a scene folder (`Frame`, `Scene`, `SceneImages`) and its format constants.

Kept apart from `panogrf.app.scene.folder` (loading, writing) and `panogrf.app.scene.check` (the
validator) so that both can build scenes without importing each other.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from panogrf.app.files.images import read_depth, read_rgb_with_notes

TRANSFORMS = "transforms.json"
CAMERA_MODEL = "EQUIRECTANGULAR"
#: Top-level keys of transforms.json that are not metadata.
RESERVED_KEYS = ("camera_model", "w", "h", "frames")
#: Camera centres farther than this from the world's origin (metres; geo-referenced COLMAP,
#: OpenSfM or SLAM output puts them at map-grid offsets of 1e5-1e7 m) are re-centred before
#: the poses become single precision, whose spacing there is 1-60 cm; at 1 km it is 0.06 mm.
RECENTRE_BEYOND_M = 1000.0


def shifted(c2w: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Camera-to-world pose(s) [..., 4, 4] moved by ``offset`` [3], as a float64 copy."""
    out = np.array(c2w, np.float64)
    out[..., :3, 3] += offset
    return out


def scene_origin(c2w: np.ndarray) -> np.ndarray:
    """[3] float64: the point the model's single-precision poses are taken relative to, the
    camera centres' median (per axis) rounded to whole metres (the median: one stray camera
    far from the rest does not pull the others away from it); zeros when every centre lies
    within `RECENTRE_BEYOND_M` of the world's origin (the poses are then used as they are)."""
    centres = np.asarray(c2w, np.float64)[:, :3, 3]
    if not np.abs(centres).max(initial=0.0) > RECENTRE_BEYOND_M:
        return np.zeros(3)
    return np.round(np.median(centres, axis=0))


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
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """[3] float64: the world point ``c2w`` is relative to (`scene_origin`): a pose of the
    scene's world is ``local(pose)`` here, and one of here is ``world(pose)`` there."""

    def to(self, device: torch.device | str) -> SceneImages:
        depths = None if self.depths is None else self.depths.to(device)
        return SceneImages(self.images.to(device), self.c2w.to(device), depths, self.origin)

    def local(self, c2w: np.ndarray) -> np.ndarray:
        """World camera-to-world pose(s) [..., 4, 4] -> this container's frame, float64."""
        return shifted(c2w, -self.origin)

    def world(self, c2w: np.ndarray) -> np.ndarray:
        """Pose(s) [..., 4, 4] of this container's frame -> the scene's world, float64."""
        return shifted(c2w, self.origin)

    @classmethod
    def from_arrays(
        cls,
        pixels: Sequence[np.ndarray],
        depths: Sequence[np.ndarray | None],
        c2w: np.ndarray,
        dtype: torch.dtype,
    ) -> SceneImages:
        """Stack per-view arrays: pixels [H, W, 3] uint8, depths [H, W] metres or None each,
        c2w [V, 4, 4] float64; views without depth get zeros (unknown) when any view has depth.
        Poses far from the world's origin are taken relative to `scene_origin` first, in
        double precision, so that ``dtype`` keeps their millimetres."""
        # Channels first while still bytes, then one conversion (a quarter of the memory moved).
        images = torch.from_numpy(np.stack(pixels)).permute(0, 3, 1, 2).contiguous()
        images = images.to(dtype).div_(255.0)
        depth = None
        if any(d is not None for d in depths):
            h, w = pixels[0].shape[:2]
            filled = [np.zeros((h, w), np.float32) if d is None else d for d in depths]
            depth = torch.from_numpy(np.stack(filled))[:, None].to(dtype)
        origin = scene_origin(c2w)
        local = shifted(c2w, -origin)
        return cls(images, torch.from_numpy(local).to(dtype), depth, origin)


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
        """Read every panorama (and depth map) into tensors on the CPU; the panoramas are
        decoded side by side (the decoder leaves Python's lock)."""
        workers = max(1, min(len(self.frames), os.cpu_count() or 1))

        def read(f: Frame) -> tuple[np.ndarray, np.ndarray | None]:
            depth = None if f.depth_path is None else read_depth(f.depth_path)
            return read_rgb_with_notes(f.image_path)[0], depth

        with ThreadPoolExecutor(workers) as pool:  # errors come out in the frames' order
            pixels, depths = zip(*pool.map(read, self.frames), strict=True)
        return SceneImages.from_arrays(pixels, depths, self.c2w, dtype)
