"""Hostile input, round 51: a depth run refused or stopped leaves no empty output folders;
`train` names a missing --mono file and a --limit-scenes of 0; a wrong ``$PANOGRF_WEIGHTS``
is named, not blamed on the weights; another network's weights say so; packs and weights are
as readable as the umask says; a pack that lists a scene twice and a merge of two heights are
refused."""

from __future__ import annotations

import json
import os
import shutil
import stat

import numpy as np
import pytest
from helpers.cli import run_cli

from panogrf.app import cli
from panogrf.app.synth.make import MakeConfig, make_dataset
from panogrf.app.weights import networks
from panogrf.assets import path as asset_path

DEMO = asset_path("demo")


def _error(capsys, argv: list[str]) -> str:
    """The error a refused command ends with (exit status 2, no traceback)."""
    code, line = run_cli(argv, capsys)
    assert code == 2 and line.startswith("panogrf"), line
    return line.split("\r")[-1]  # after any progress bar's carriage return


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """Two datasets of two scenes: at 32 rows and at 48."""
    root = tmp_path_factory.mktemp("tiny")
    for rows in (32, 48):
        make_dataset(MakeConfig(out=root / f"d{rows}", count=2, height=rows, seed=3))
    return root


def test_a_depth_run_refused_late_leaves_no_output_folders(tmp_path, capsys):
    scene = tmp_path / "scene"
    shutil.copytree(DEMO, scene)
    meta = json.loads((scene / "transforms.json").read_text())
    meta["frames"][1]["file_path"] = "images/missing.png"
    (scene / "transforms.json").write_text(json.dumps(meta))
    out = tmp_path / "deep" / "x" / "y"
    line = _error(capsys, ["depth", str(scene), "--out", str(out), "--no-cache"])
    assert "images/missing.png" in line and not (tmp_path / "deep").exists()


def test_train_names_a_missing_mono_file_and_a_limit_of_no_scenes(tiny, tmp_path, capsys):
    base = ["train", "depth", "--data", str(tiny / "d32"), "--steps", "1", "--height", "32"]
    out = ["--out", str(tmp_path / "w.safetensors")]
    missing = tmp_path / "nope.safetensors"
    line = _error(capsys, [*base, *out, "--stage", "mvs", "--mono", str(missing)])
    assert line.endswith(f"--mono {missing}: not found")
    line = _error(capsys, [*base, *out, "--stage", "mono", "--limit-scenes", "0"])
    assert line.endswith("--limit-scenes must be at least 1, got 0")


def test_a_wrong_weights_folder_is_named_not_blamed_on_the_weights(tmp_path, capsys, monkeypatch):
    argv = ["render", str(DEMO), "--target-frame", "1", "--height", "32", "--no-cache"]
    argv += ["--out", str(tmp_path / "v.png")]
    empty = tmp_path / "empty"
    empty.mkdir()
    for folder, state in ((empty, "a folder without this file"), (tmp_path / "nope", "no such")):
        monkeypatch.setenv("PANOGRF_WEIGHTS", str(folder))
        line = _error(capsys, argv)
        assert f"$PANOGRF_WEIGHTS is {folder} ({state}" in line and "unset it" in line
        assert "panogrf train" not in line
    swapped = tmp_path / "swapped"
    shutil.copytree(asset_path("depth_mono.safetensors").parent, swapped, ignore=_no_demo)
    shutil.copy(swapped / "lpips_alex.safetensors", swapped / "depth_mono.safetensors")
    monkeypatch.setenv("PANOGRF_WEIGHTS", str(swapped))
    networks.load_depth_estimator.cache_clear()  # loaded once per process: load these
    line = _error(capsys, argv)
    assert "depth_mono.safetensors: not the weights of this network (its settings differ in" in line
    assert len(line) < 400


def _no_demo(folder, names):
    return [n for n in names if not n.endswith(".safetensors")]


def test_packs_follow_the_umask_and_list_each_scene_once(tiny, tmp_path, capsys):
    old = os.umask(0o022)
    try:
        out = tmp_path / "p.safetensors"
        assert (
            cli.main(["dataset", "pack", "--out", str(out), str(tiny / "d32"), "--height", "32"])
            == 0
        )
        assert stat.S_IMODE(out.stat().st_mode) == 0o644
    finally:
        os.umask(old)
    twice = [str(tiny / "d32"), f"{tiny / 'd32'}:1:1"]
    line = _error(
        capsys,
        ["dataset", "pack", "--out", str(tmp_path / "q.safetensors"), *twice, "--height", "32"],
    )
    assert "scene 1 listed twice" in line and not (tmp_path / "q.safetensors").exists()


def test_a_merge_of_two_heights_is_refused(tiny, tmp_path, capsys):
    out = tmp_path / "m"
    line = _error(
        capsys, ["dataset", "merge", "--out", str(out), str(tiny / "d32"), str(tiny / "d48")]
    )
    assert "panoramas of 48 rows" in line and "32" in line and not out.exists()


def test_a_stopped_dataset_make_lists_what_it_wrote_and_leaves_no_half_scene(
    tmp_path, monkeypatch, capsys
):
    from panogrf.app.synth import make as mk

    real, calls = mk.transforms_dict, []

    def stop_at_the_third(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:  # Ctrl-C while the third scene is written
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(mk, "transforms_dict", stop_at_the_third)
    out = tmp_path / "d"
    with pytest.raises(KeyboardInterrupt):
        make_dataset(MakeConfig(out=out, count=5, height=32), progress=False)
    index = json.loads((out / "dataset.json").read_text())
    assert [e["folder"] for e in index["scenes"]] == ["train_00000", "train_00001"]
    assert sorted(p.name for p in out.iterdir()) == ["dataset.json", "train_00000", "train_00001"]
    assert "2 of 5 scenes written" in capsys.readouterr().err
    make_dataset(MakeConfig(out=out, count=3, start=2, height=32), progress=False)
    assert len(json.loads((out / "dataset.json").read_text())["scenes"]) == 5


def _demo_poses():
    from panogrf.app.scene.folder import load_scene

    return np.asarray(load_scene(DEMO).c2w, float)


def test_a_cube_face_turned_against_its_panoramas_other_faces_is_refused(tmp_path):
    from panogrf.app.errors import UserError
    from panogrf.app.poses import importers as im

    images = tmp_path / "images.txt"
    im.write_colmap(images, ["p0", "p1", "p2"], _demo_poses())
    lines = images.read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if line.endswith(" p1/right.png"))
    parts = lines[k].split()
    parts[1:5] = ["1", "0", "0", "0"]  # QW QX QY QZ: the identity, not this face's turn
    lines[k] = " ".join(parts)
    images.write_text("\n".join(lines) + "\n")
    with pytest.raises(UserError, match=r"p1/right.png is turned \d+ deg from the other faces"):
        im.read_poses("colmap", images)


def test_odd_camera_path_and_opensfm_files_say_what_is_wrong(tmp_path, capsys):
    from panogrf.app.errors import UserError
    from panogrf.app.paths.camera_path import read_camera_path
    from panogrf.app.poses import importers as im

    with pytest.raises(UserError, match="^/dev/null: not a regular file$"):
        read_camera_path("/dev/null")
    rec = tmp_path / "reconstruction.json"
    im.write_opensfm(rec, ["a.png", "b.png"], _demo_poses()[:2], 512, 256)
    data = json.loads(rec.read_text())
    data[0]["shots"]["b.png"]["camera"] = "nope"
    rec.write_text(json.dumps(data))
    with pytest.raises(UserError, match="shot 'b.png' names camera 'nope', which \"cameras\""):
        im.read_poses("opensfm", rec)
    line = _error(capsys, ["bench", str(DEMO), "--out", str(tmp_path / "b"), "--real", "/nope"])
    assert line.endswith("--real /nope: no such folder (a dataset of real triplets, or none)")


def test_a_dataset_make_that_would_replace_a_listed_scene_is_refused(tmp_path, capsys):
    out = tmp_path / "d"
    make = ["dataset", "make", "--out", str(out), "--height", "32", "--no-progress"]
    assert cli.main([*make, "--count", "2"]) == 0
    assert cli.main([*make, "--count", "2"]) == 0  # the same scenes again: nothing lost
    before = (out / "train_00000" / "images" / "frame_000.png").read_bytes()
    line = _error(capsys, [*make, "--count", "1", "--seed", "3"])
    assert "lists another train_00000" in line and "--start 2" in line
    assert (out / "train_00000" / "images" / "frame_000.png").read_bytes() == before


def test_eval_with_no_scene_left_says_why_once(tmp_path, capsys):
    scenes = tmp_path / "scenes"
    (scenes / "two").mkdir(parents=True)
    shutil.copytree(DEMO / "images", scenes / "two" / "images")
    meta = json.loads((DEMO / "transforms.json").read_text())
    meta["frames"] = meta["frames"][:2]
    (scenes / "two" / "transforms.json").write_text(json.dumps(meta))
    assert cli.main(["eval", str(scenes), "--out", str(tmp_path / "r.json")]) == 2
    said = capsys.readouterr()
    assert "no scene can be scored (" in said.err and "skipping" not in said.out
