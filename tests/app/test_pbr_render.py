"""The pyrender (physically based) synthetic renderer: depth, shadows, determinism, workers.

pyrender draws on its own EGL context, which must not share a process with moderngl's
(DESIGN.md section 6): the dataset tests go through `make_dataset`, whose pyrender workers are
spawned processes, and the shadow test renders in a subprocess of its own.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import torch

from panogrf.app.files.images import read_depth, read_rgb
from panogrf.app.synth.make import MakeConfig, make_dataset
from panogrf.model.erp import direction_to_pixel

pytestmark = pytest.mark.gl

_SHADOW_SCRIPT = r"""
import sys
import numpy as np
from panogrf.app.synth.layout import Light, Material, SceneObject, SynthScene, _box, _quad
from panogrf.app.synth.pbr_render import PyrenderPanoramaRenderer

def room(with_slab):
    grey = Material(layer=0, scale=1.0, offset=(0.0, 0.0), tint=(0.8, 0.8, 0.8))
    q = lambda c: _quad(np.array(c, float))
    objects = [
        SceneObject("roomA_floor", q([[0, 0, 0], [6, 0, 0], [6, 0, 6], [0, 0, 6]]), grey),
        SceneObject("roomA_ceiling", q([[0, 3, 0], [0, 3, 6], [6, 3, 6], [6, 3, 0]]), grey),
        SceneObject("roomA_wall_x0", q([[0, 0, 0], [0, 0, 6], [0, 3, 6], [0, 3, 0]]), grey),
        SceneObject("roomA_wall_x1", q([[6, 0, 0], [6, 3, 0], [6, 3, 6], [6, 0, 6]]), grey),
        SceneObject("roomA_wall_z0", q([[0, 0, 0], [0, 3, 0], [6, 3, 0], [6, 0, 0]]), grey),
        SceneObject("roomA_wall_z1", q([[0, 0, 6], [6, 0, 6], [6, 3, 6], [0, 3, 6]]), grey),
    ]
    if with_slab:  # a slab between the light and the floor, above the camera's eyes
        objects.append(SceneObject("A_slab_0", _box([1.0, 0.05, 1.0], [4.5, 2.0, 3.0]), grey))
    cams = np.repeat(np.eye(4)[None], 3, 0)
    cams[:, :3, 3] = [[1.5, 1.5, 2.5], [1.5, 1.5, 3.0], [1.5, 1.5, 3.5]]
    light = Light(np.array([4.5, 2.7, 3.0]), np.array([3.0, 3.0, 3.0]))
    return SynthScene(objects, [light], np.full(3, 0.2), cams, 1.0, 7, "train",
                      {"room_a": [6.0, 3.0, 6.0]})

out = {}
with PyrenderPanoramaRenderer() as r:
    r.set_textures(np.full((1, 8, 8, 3), 0.8, np.float32))
    for slab in (False, True):
        r.set_scene(room(slab))
        rgb, depth = r.render(room(slab).cameras[1], 64, 128)
        out[f"rgb{int(slab)}"], out[f"depth{int(slab)}"] = rgb, depth
np.savez(sys.argv[1], **out)
"""


def _pixel(point, camera):
    d = torch.tensor(np.asarray(point, float) - np.asarray(camera, float), dtype=torch.float32)
    uv = direction_to_pixel(d / d.norm(), 64, 128)
    return int(uv[1]), int(uv[0])


def test_spot_lights_cast_shadows(tmp_path):
    path = tmp_path / "shadow.npz"
    subprocess.run([sys.executable, "-c", _SHADOW_SCRIPT, str(path)], check=True, timeout=300)
    data = np.load(path)
    camera = (1.5, 1.5, 3.0)
    under = _pixel((4.5, 0.0, 3.0), camera)  # floor right below the slab (and the light)
    aside = _pixel((4.5, 0.0, 5.2), camera)  # floor beside the slab's shadow
    lum0, lum1 = data["rgb0"].astype(float).mean(-1), data["rgb1"].astype(float).mean(-1)
    assert lum1[under] < 0.7 * lum0[under]  # in the slab's shadow
    assert abs(lum1[aside] - lum0[aside]) < 0.2 * lum0[aside]  # lit either way
    # The floor below the slab is still what that pixel sees (the slab is above the eyes), at
    # the floor's distance (within the 64-row pixel's extent at this grazing angle).
    assert data["depth1"][under] == pytest.approx(data["depth0"][under], rel=1e-3)
    d = np.linalg.norm(np.subtract((4.5, 0.0, 3.0), camera))
    assert abs(data["depth1"][under] - d) < 0.1 * d


def test_pyrender_dataset_depth_matches_gl(tmp_path):
    common = {"split": "train", "count": 2, "height": 64, "world": "home", "seed": 5}
    make_dataset(MakeConfig(out=tmp_path / "gl", **common), progress=False)
    summary = make_dataset(
        MakeConfig(out=tmp_path / "pbr", renderer="pyrender", workers=2, **common), progress=False
    )
    assert summary["renderer"] == "pyrender" and summary["panoramas"] == 6
    index = json.loads((tmp_path / "pbr" / "dataset.json").read_text())
    assert index["renderer"] == "pyrender" and len(index["scenes"]) == 2
    for entry in index["scenes"]:
        folder = entry["folder"]
        pbr_meta = json.loads((tmp_path / "pbr" / folder / "transforms.json").read_text())
        gl_meta = json.loads((tmp_path / "gl" / folder / "transforms.json").read_text())
        assert pbr_meta["frames"] == gl_meta["frames"]  # the same scene and cameras
        for frame in pbr_meta["frames"]:
            d_pbr = read_depth(tmp_path / "pbr" / folder / frame["depth_file_path"])
            d_gl = read_depth(tmp_path / "gl" / folder / frame["depth_file_path"])
            rel = np.abs(d_pbr - d_gl) / d_gl
            # A face pixel's distance at the nearest face pixel (about 2 degrees at 64 rows)
            # against the GL renderer's exact ray-plane distance.
            assert np.median(rel) < 0.01 and (rel < 0.05).mean() > 0.9
            rgb_pbr = read_rgb(tmp_path / "pbr" / folder / frame["file_path"]).astype(float)
            rgb_gl = read_rgb(tmp_path / "gl" / folder / frame["file_path"]).astype(float)
            assert 25 < rgb_pbr.mean() < 230  # exposed, neither black nor blown out
            assert np.abs(rgb_pbr - rgb_gl).mean() > 5  # lit differently from the GL world
    # Deterministic: the same seed renders the same bytes, whatever worker drew it.
    make_dataset(
        MakeConfig(out=tmp_path / "again", renderer="pyrender", workers=1, **common), False
    )
    name = "train_00001/images/frame_002.png"
    assert (tmp_path / "pbr" / name).read_bytes() == (tmp_path / "again" / name).read_bytes()


def test_unknown_renderer_refused(tmp_path):
    with pytest.raises(ValueError, match="renderer"):
        make_dataset(MakeConfig(out=tmp_path, renderer="raytracer"), progress=False)


def test_workers_end_with_a_killed_parent(tmp_path):
    """kill -9 of `dataset make` must not leave its pyrender workers rendering on."""
    import time

    import psutil

    cmd = [sys.executable, "-m", "panogrf.app.cli", "dataset", "make", "--out", str(tmp_path)]
    cmd += ["--world", "home", "--renderer", "pyrender", "--count", "200", "--height", "32"]
    parent = subprocess.Popen([*cmd, "--no-progress"], stdout=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while not list(tmp_path.glob("*/transforms.json")):
            assert parent.poll() is None and time.monotonic() < deadline
            time.sleep(0.2)
        workers = [
            p
            for p in psutil.Process(parent.pid).children(recursive=True)
            if "spawn_main" in " ".join(p.cmdline())
        ]
        assert len(workers) == 2
    finally:
        parent.kill()
        parent.wait()
    _, alive = psutil.wait_procs(workers, timeout=20)
    for p in alive:
        p.kill()
    assert not alive
    assert not (tmp_path / "dataset.json").exists()  # the index is written only when done


def test_a_failed_scene_stops_the_run(tmp_path):
    """A scene that cannot be written ends the run with its error; the queue is dropped."""
    (tmp_path / "train_00001").write_text("in the way")  # a file where a scene folder goes
    cfg = MakeConfig(out=tmp_path, world="home", renderer="pyrender", count=40, height=32)
    with pytest.raises(NotADirectoryError):
        make_dataset(cfg, progress=False)
    done = list(tmp_path.glob("*/transforms.json"))
    assert len(done) < 10  # not the other 39 scenes first
    # The scenes written are listed (the dataset is usable); the user's file stays.
    index = json.loads((tmp_path / "dataset.json").read_text())
    assert sorted(e["folder"] for e in index["scenes"]) == sorted(p.parent.name for p in done)
    assert (tmp_path / "train_00001").read_text() == "in the way"


def test_cli_refuses_a_folder_with_a_file_where_a_scene_goes_in_one_line(tmp_path):
    (tmp_path / "train_00000").write_text("in the way")
    cmd = [sys.executable, "-m", "panogrf.app.cli", "dataset", "make", "--out", str(tmp_path)]
    run = subprocess.run(
        [*cmd, "--count", "1", "--height", "16", "--no-progress"], capture_output=True, text=True
    )
    assert run.returncode != 0 and "Traceback" not in run.stderr
    assert "is not empty (train_00000)" in run.stderr  # refused before any work
    assert (tmp_path / "train_00000").read_text() == "in the way"
