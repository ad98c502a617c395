"""The home world: household materials, windows, rugs, cameras off the line, exact depth."""

from __future__ import annotations

import json

import numpy as np
import pytest

from panogrf.app.synth.home import HOME_LAYOUT, generate_home
from panogrf.app.synth.layout import _segment_distance
from panogrf.app.synth.make import MakeConfig, build_textures, make_dataset, scene_seed
from panogrf.app.synth.materials import GROUPS, home_texture_bank


def test_texture_bank_groups_and_range():
    bank, groups = home_texture_bank("train", np.random.default_rng(0), per_group=2, size=32)
    assert bank.shape == (2 * len(GROUPS), 32, 32, 3) and bank.dtype == np.float32
    assert set(groups) == set(GROUPS)
    assert 0 <= bank.min() and bank.max() <= 1 and np.isfinite(bank).all()
    # Every layer of a group is its own texture (not blank, not a copy of its neighbour).
    assert all(bank[i].std() > 0.005 for i in range(len(bank)))
    with pytest.raises(ValueError, match="split"):
        home_texture_bank("val", np.random.default_rng(0))


def test_splits_draw_different_textures():
    a, _ = build_textures("train", 0, 8, world="home")
    b, _ = build_textures("test", 0, 8, world="home")
    assert a.shape == b.shape and not np.allclose(a, b)


@pytest.mark.parametrize("index", range(6))
def test_home_layout(index):
    _, groups = build_textures("train", 0, 8, world="home")
    seed = scene_seed("train", 1, index)
    scene = generate_home(seed, "train", groups)
    again = generate_home(seed, "train", groups)
    assert np.array_equal(scene.cameras, again.cameras)  # deterministic
    n_layers = max(r.stop for r in groups.values())
    assert all(0 <= o.material.layer < n_layers for o in scene.objects)
    names = [o.name for o in scene.objects]
    assert any(n.startswith("window") for n in names)
    # Windows are blown out: tinted far above 1, and taken from the window group.
    for o in scene.objects:
        if o.name.startswith("window"):
            assert min(o.material.tint) > 2.5 and o.material.layer in groups["window"]
    heights = scene.cameras[:, 1, 3]
    lo, hi = HOME_LAYOUT.camera_height
    assert np.all((heights >= lo - 1e-9) & (heights <= hi + 1e-9))
    c = scene.cameras[:, :3, 3]
    assert np.isclose(np.linalg.norm(c[2] - c[0]), scene.baseline)
    # The middle camera may leave the line, but by less than the clearance around it.
    off = _segment_distance(c[1, [0, 2]], c[0, [0, 2]], c[2, [0, 2]])
    assert off <= min(0.3, 0.15 * scene.baseline) + 1e-9
    assert scene.meta["world"] == "home"


def test_home_baselines_reach_past_two_metres():
    _, groups = build_textures("train", 0, 8, world="home")
    baselines = [
        generate_home(scene_seed("train", 1, i), "train", groups).baseline for i in range(40)
    ]
    assert max(baselines) > 2.5 and min(baselines) < 1.5


@pytest.mark.gl
def test_make_home_dataset(tmp_path):
    from panogrf.app.files.images import read_depth, read_rgb

    make_dataset(MakeConfig(out=tmp_path, count=2, height=32, world="home"), progress=False)
    index = json.loads((tmp_path / "dataset.json").read_text())
    assert index["world"] == "home" and len(index["scenes"]) == 2
    for entry in index["scenes"]:
        meta = json.loads((tmp_path / entry["folder"] / "transforms.json").read_text())
        for frame in meta["frames"]:
            rgb = read_rgb(tmp_path / entry["folder"] / frame["file_path"])
            depth = read_depth(tmp_path / entry["folder"] / frame["depth_file_path"])
            assert rgb.shape == (32, 64, 3) and np.all(depth > 0.05)
    with pytest.raises(ValueError, match="world"):
        make_dataset(MakeConfig(out=tmp_path, count=1, height=32, world="castle"), False)
