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


@pytest.mark.parametrize("index", range(4))
def test_trims_finish_the_walls_without_moving_the_room(index):
    """Rails, a frieze and maybe a wainscot: thin parts on the main room's walls, nowhere in
    the doorway, and the rest of the scene the same scene as without them."""
    _, groups = build_textures("train", 0, 8, world="home")
    seed = scene_seed("train", 2, index)
    plain = generate_home(seed, "train", groups)
    zero = generate_home(seed, "train", groups, trims=0.0)
    trimmed = generate_home(seed, "train", groups, trims=1.0)

    def same(a, b) -> bool:
        return (
            a.name == b.name
            and a.material == b.material
            and np.array_equal(a.mesh.vertices, b.mesh.vertices)
        )

    n = len(plain.objects)
    assert len(zero.objects) == n and all(map(same, plain.objects, zero.objects))
    assert all(map(same, plain.objects, trimmed.objects[:n]))
    assert np.array_equal(plain.cameras, trimmed.cameras)
    added = trimmed.objects[n:]
    names = [o.name for o in added]
    assert any(n.startswith("frieze") for n in names) and any(n.startswith("rail") for n in names)
    lx, ha, lz = trimmed.meta["room_a"]
    door = trimmed.meta["doorway"]
    for o in added:
        v = np.asarray(o.mesh.vertices)
        # Against a wall of room A: within 3 cm of x = 0, x = lx, z = 0 or z = lz.
        gaps = np.stack([v[:, 0], lx - v[:, 0], v[:, 2], lz - v[:, 2]], 1)
        assert (gaps.min(1) <= 0.0251).all() and (gaps.min(1) >= -1e-9).all(), o.name
        assert v[:, 1].min() >= -1e-9 and v[:, 1].max() <= ha + 1e-9
        if o.name.startswith("frieze"):
            assert v[:, 1].min() > door["height"]  # above the doorway's head
        on_divider = np.all(lx - v[:, 0] < 0.03)
        if on_divider:  # nothing in the doorway's opening
            in_gap = (v[:, 2] > door["z"] + 1e-6) & (v[:, 2] < door["z"] + door["width"] - 1e-6)
            assert not np.any(in_gap & (v[:, 1] < door["height"] - 1e-6)), o.name


@pytest.mark.parametrize("index", range(4))
def test_coves_soften_the_ceiling_corner_only(index):
    """A cove or a crown moulding: strips in the corner between the main room's walls and its
    ceiling, added after everything else, the rest of the scene unchanged."""
    _, groups = build_textures("train", 0, 8, world="home")
    seed = scene_seed("train", 3, index)
    plain = generate_home(seed, "train", groups, trims=1.0)
    coved = generate_home(seed, "train", groups, trims=1.0, coves=1.0)
    n = len(plain.objects)
    assert [o.name for o in coved.objects[:n]] == [o.name for o in plain.objects]
    assert all(
        np.array_equal(a.mesh.vertices, b.mesh.vertices)
        for a, b in zip(plain.objects, coved.objects[:n], strict=True)
    )
    added = coved.objects[n:]
    assert len(added) == 4 and len({o.name.split("_")[0] for o in added}) == 1
    assert added[0].name.split("_")[0] in ("cove", "crown")
    lx, ha, lz = coved.meta["room_a"]
    for o in added:
        v = np.asarray(o.mesh.vertices)
        own = {"x0": v[:, 0], "x1": lx - v[:, 0], "z0": v[:, 2], "z1": lz - v[:, 2]}
        gap = own[o.name.split("_")[1]]  # distance from its own wall
        assert (gap >= 0).all() and (gap <= 0.31).all(), o.name  # along that wall
        assert (v[:, 1] >= ha - 0.31).all() and (v[:, 1] < ha).all(), o.name  # under the ceiling
        # The profile runs from the wall (low) to the ceiling (out in the room).
        low, high = v[:, 1] < ha - 0.05, gap > 0.05
        assert low.any() and high.any() and not (low & high).any()


def test_sheers_hang_in_front_of_the_windows_only():
    """Sheer curtains: pleats between the glass and any side curtains, glowing only in front of
    the glass, added after everything else with the rest of the scene unchanged."""
    _, groups = build_textures("train", 0, 8, world="home")
    glowing = 0
    for index in range(6):
        seed = scene_seed("train", 4, index)
        plain = generate_home(seed, "train", groups, trims=1.0, coves=1.0)
        hung = generate_home(seed, "train", groups, trims=1.0, coves=1.0, sheers=1.0)
        n = len(plain.objects)
        assert [o.name for o in hung.objects[:n]] == [o.name for o in plain.objects]
        assert all(
            np.array_equal(a.mesh.vertices, b.mesh.vertices) and a.material == b.material
            for a, b in zip(plain.objects, hung.objects[:n], strict=True)
        )
        assert np.array_equal(plain.cameras, hung.cameras)
        lx, ha, lz = hung.meta["room_a"]
        windows = {o.name.removeprefix("window_"): o for o in plain.objects if "window" in o.name}
        for o in hung.objects[n:]:
            kind, wall = o.name.rsplit("_", 1)
            assert kind in ("sheer", "sheer_glow") and wall in windows
            assert o.material.layer in groups["sheer"]
            v = np.asarray(o.mesh.vertices)
            own = {"x0": v[:, 0], "x1": lx - v[:, 0], "z0": v[:, 2], "z1": lz - v[:, 2]}[wall]
            assert (own >= 0.02 - 1e-9).all() and (own <= 0.0451).all(), o.name  # pleats
            assert own.max() - own.min() > 0.005  # folded, not flat
            assert v[:, 1].min() >= 0 and v[:, 1].max() <= ha
            lo, hi = windows[wall].mesh.bounds
            along = 2 if wall == "x0" else 0
            if kind == "sheer_glow":  # bright, and only where the glass is behind it
                glowing += 1
                assert min(o.material.tint) > 1.5
                assert v[:, along].min() >= lo[along] - 1e-9
                assert v[:, along].max() <= hi[along] + 1e-9
                assert v[:, 1].min() >= lo[1] - 1e-9 and v[:, 1].max() <= hi[1] + 1e-9
            else:
                assert max(o.material.tint) <= 1.0
    assert glowing >= 3


def test_trims_need_the_home_world_and_a_probability(tmp_path):
    with pytest.raises(ValueError, match="trims"):
        make_dataset(MakeConfig(out=tmp_path, count=1, height=32, trims=0.5), False)
    with pytest.raises(ValueError, match="trims"):
        make_dataset(MakeConfig(out=tmp_path, count=1, height=32, world="home", trims=1.5), False)
    with pytest.raises(ValueError, match="coves"):
        make_dataset(MakeConfig(out=tmp_path, count=1, height=32, coves=0.5), False)
    with pytest.raises(ValueError, match="sheers"):
        make_dataset(MakeConfig(out=tmp_path, count=1, height=32, sheers=-0.5), False)


@pytest.mark.parametrize(
    "extra,message",
    [
        (["--trims", "1.5"], "between 0 and 1"),
        (["--trims", "0.5"], "needs --world home"),
        (["--world", "home", "--coves", "-0.1"], "between 0 and 1"),
        (["--coves", "1"], "needs --world home"),
        (["--world", "home", "--sheers", "2"], "between 0 and 1"),
        (["--sheers", "0.3"], "needs --world home"),
    ],
)
def test_cli_refuses_bad_trims_in_one_line(tmp_path, extra, message):
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "panogrf.app.cli", "dataset", "make", "--out", str(tmp_path)]
    run = subprocess.run([*cmd, "--count", "1", *extra], capture_output=True, text=True)
    assert run.returncode != 0 and "Traceback" not in run.stderr
    assert message in run.stderr
    assert not any(tmp_path.iterdir())  # nothing written
