"""Scenes far from the world's origin (issue 57, S1): geo-referenced COLMAP, OpenSfM or SLAM
output puts cameras at map-grid offsets of 1e5-1e7 m, where single precision is 0.5-1 m apart.
The poses stay float64 in the scene and are taken relative to a scene origin before they become
float32, so such a scene renders as the same scene at the origin does, from a target frame, from
a ``--c2w`` pose of its own world and along a camera path of its world.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from panogrf.app import cli
from panogrf.app.files.images import read_rgb
from panogrf.app.scene.folder import load_scene, write_scene
from panogrf.app.scene.types import RECENTRE_BEYOND_M, SceneImages, scene_origin
from panogrf.assets import path as asset_path

OFFSET = np.array([5e5, 0.0, 5e6])  # the map-grid offset
#: The networks' depth only (the refinement is not what is tested), prepared once per scene
#: and sources: each scene folder keeps its own cache.
FAST = ["--no-refine-depth"]


def _pose(x: float, y: float, z: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def test_near_scenes_are_used_as_they_are_and_far_ones_recentred_in_double_precision():
    near = np.stack([_pose(0.0, 1.5, 0.0), _pose(RECENTRE_BEYOND_M - 1, 1.5, 0.3)])
    assert np.array_equal(scene_origin(near), np.zeros(3))
    far = near.copy()
    far[:, :3, 3] += OFFSET + 0.123456  # sub-millimetre digits that float32 would lose
    origin = scene_origin(far)
    assert np.array_equal(origin, np.round(origin)) and np.abs(origin).max() > 1e6
    pixels = [np.zeros((8, 16, 3), np.uint8)] * 2
    data = SceneImages.from_arrays(pixels, [None, None], far, torch.float32)
    assert np.array_equal(data.origin, origin)
    # The float32 poses keep the cameras' 1 mm: float32 of the raw offsets would be 0.5 m off.
    back = data.world(data.c2w.double().numpy())
    assert np.abs(back - far).max() < 1e-4
    assert np.abs(np.float32(far[1, 2, 3]) - far[1, 2, 3]) > 0.01  # what S1 lost
    assert np.allclose(data.local(far), data.c2w.double().numpy(), atol=1e-4)
    assert np.array_equal(data.to("cpu").origin, origin)


def test_one_stray_camera_does_not_pull_the_origin_away_from_the_others():
    """Two cameras by the origin and one 1e7 m away: the origin (the median) stays with the two,
    whose float32 poses keep their millimetres (the mean would put them 3.3e6 m from it)."""
    c2w = np.stack([_pose(0.123456, 1.5, 0.0), _pose(1.0, 1.5, 0.5), _pose(1e7, 1.5, 0.0)])
    data = SceneImages.from_arrays(
        [np.zeros((8, 16, 3), np.uint8)] * 3, [None] * 3, c2w, torch.float32
    )
    back = data.world(data.c2w.double().numpy())
    assert np.abs(back[:2] - c2w[:2]).max() < 1e-6


@pytest.fixture(scope="module")
def demo_pair(tmp_path_factory):
    """The bundled scene at 32 rows, at its own coordinates and moved by the map-grid offset."""
    scene = load_scene(asset_path("demo"), load_images=True)
    images = torch.nn.functional.interpolate(scene.images.images, size=(32, 64), mode="area")
    names = [f.name for f in scene.frames]
    root = tmp_path_factory.mktemp("far")
    moved = scene.c2w.copy()
    moved[:, :3, 3] += OFFSET
    write_scene(root / "here", scene.c2w, images, names=names)
    write_scene(root / "far", moved, images, names=names)
    return root / "here", root / "far", scene.c2w


def _render(scene_dir, out, *extra) -> np.ndarray:
    extra = (*extra, "--cache-dir", str(scene_dir.parent / f"cache_{scene_dir.name}"))
    args = ["render", str(scene_dir), "--out", str(out), "--height", "32", "--quiet", *extra]
    assert cli.main([*args, *FAST]) == 0
    return read_rgb(out).astype(np.int16)


@pytest.mark.slow
def test_a_far_scene_renders_as_the_same_scene_at_the_origin(demo_pair, tmp_path):
    """Target frame, a --c2w pose between the sources (given in each scene's own world) and a
    camera path: the far scene's pixels equal the near scene's (a uint8 step at most, from the
    float32 rounding of the relative poses), where S1 gave 21.75 dB against 28.83."""
    here, far, c2w = demo_pair
    a = _render(here, tmp_path / "a.png", "--target-frame", "1")
    b = _render(far, tmp_path / "b.png", "--target-frame", "1")
    assert np.abs(a - b).max() <= 2
    pose = c2w[0].copy()
    pose[:3, 3] = 0.5 * (c2w[0, :3, 3] + c2w[2, :3, 3]) + [0.05, 0.0, 0.02]
    moved = pose.copy()
    moved[:3, 3] += OFFSET
    text = lambda m: " ".join(f"{x:.6f}" for x in m.reshape(16))  # noqa: E731
    a = _render(here, tmp_path / "c.png", "--c2w", text(pose))
    b = _render(far, tmp_path / "d.png", "--c2w", text(moved))
    assert np.abs(a - b).max() <= 2
    assert np.abs(a - _render(here, tmp_path / "e.png", "--target-frame", "1")).max() > 2
    for name, m in (("near.json", pose), ("far.json", moved)):
        path = {
            "camera_type": "equirectangular",
            "render_width": 64,
            "render_height": 32,
            "fps": 1,
            "seconds": 1,
            "camera_path": [{"camera_to_world": m.reshape(16).tolist(), "fov": 90}],
        }
        (tmp_path / name).write_text(json.dumps(path))
    for name, scene_dir in (("near", here), ("far", far)):
        args = ["render", str(scene_dir), "--camera-path", str(tmp_path / f"{name}.json")]
        args += ["--cache-dir", str(scene_dir.parent / f"cache_{scene_dir.name}")]
        assert cli.main([*args, "--out", str(tmp_path / name), "--quiet", *FAST]) == 0
    frames = [sorted((tmp_path / n).glob("*.png")) for n in ("near", "far")]
    assert len(frames[0]) == len(frames[1]) == 1
    a, b = (read_rgb(f[0]).astype(np.int16) for f in frames)
    assert np.abs(a - b).max() <= 2
