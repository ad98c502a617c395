"""Hostile input, round 44: outputs that would replace an input (training data, a dataset's
index, an image), broken dataset indexes, datasets joined with other settings, one photograph
at several poses, scenes too small for a command, names that are not valid text. Each refused
in one line, before any work, with the inputs left as they were."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from helpers.cli import run_cli as _run

from panogrf.app.cli import main
from panogrf.assets import path as asset_path


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """A two-scene test-split dataset at 32 rows."""
    out = tmp_path_factory.mktemp("data") / "ds"
    args = ["dataset", "make", "--split", "test", "--no-progress", "--count", "2"]
    assert main([*args, "--height", "32", "--baselines", "1.0", "--out", str(out)]) == 0
    return out


def _copy(dataset: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(dataset, tmp_path / "ds"))


def test_training_refuses_to_write_over_its_data(dataset, tmp_path, capsys):
    ds = _copy(dataset, tmp_path)
    before = (ds / "dataset.json").read_bytes()
    pack = tmp_path / "pk.safetensors"
    assert main(["dataset", "pack", str(ds), "--out", str(pack), "--height", "32"]) == 0
    packed = pack.read_bytes()
    args = ["train", "depth", "--stage", "mono", "--steps", "1", "--height", "32"]
    code, line = _run([*args, "--data", str(pack), "--out", str(pack)], capsys)
    assert code == 2 and "is the training data" in line
    weights = str(tmp_path / "w.safetensors")
    code, line = _run([*args, "--data", str(ds), "--out", weights, "--log", str(ds)], capsys)
    assert code == 2 and "--log" in line
    index = str(ds / "dataset.json")
    code, line = _run([*args, "--data", str(ds), "--out", weights, "--log", index], capsys)
    assert code == 2 and "--log" in line
    assert (ds / "dataset.json").read_bytes() == before and pack.read_bytes() == packed
    assert not Path(weights).exists()


def test_eval_refuses_the_dataset_index_as_its_report(dataset, tmp_path, capsys):
    ds = _copy(dataset, tmp_path)
    before = (ds / "dataset.json").read_bytes()
    argv = ["eval", str(ds), "--out", str(ds / "dataset.json"), "--methods", "nearest"]
    code, line = _run([*argv, "--height", "32"], capsys)
    assert code == 2 and "the dataset's own index" in line
    assert (ds / "dataset.json").read_bytes() == before


def test_eval_refuses_a_method_twice_and_a_subset_it_does_not_run(dataset, tmp_path, capsys):
    argv = ["eval", str(dataset), "--out", str(tmp_path / "r.json"), "--height", "32"]
    code, line = _run([*argv, "--methods", "nearest,nearest"], capsys)
    assert code == 2 and "twice" in line
    code, line = _run([*argv, "--methods", "nearest", "--subset", "bogus"], capsys)
    assert code == 2 and "--subset bogus" in line
    assert not (tmp_path / "r.json").exists()


@pytest.mark.parametrize("text", ["{", "[1]", '{"scenes": [{"x": 1}]}', '{"scenes": 5}'])
def test_a_broken_dataset_index_is_one_line_everywhere(text, tmp_path, capsys):
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "dataset.json").write_text(text)
    out = tmp_path / "out"
    for argv in (
        ["dataset", "make", "--split", "test", "--no-progress", "--count", "1", "--height", "32"]
        + ["--out", str(bad)],
        ["dataset", "merge", "--out", str(out), str(bad)],
        ["dataset", "pack", str(bad), "--out", str(tmp_path / "p.safetensors"), "--height", "32"],
        ["train", "depth", "--data", str(bad), "--stage", "mono", "--out"]
        + [str(tmp_path / "m.safetensors"), "--steps", "1", "--height", "32"],
    ):
        code, line = _run(argv, capsys)
        assert code == 2 and "dataset.json" in line, argv
    assert (bad / "dataset.json").read_text() == text
    assert sorted(p.name for p in bad.iterdir()) == ["dataset.json"]  # nothing rendered


def test_scenes_join_a_dataset_only_with_its_settings(dataset, tmp_path, capsys):
    ds = _copy(dataset, tmp_path)
    before = (ds / "dataset.json").read_bytes()
    base = ["dataset", "make", "--no-progress", "--count", "1", "--start", "5", "--out", str(ds)]
    for extra, word in (
        (["--split", "test", "--height", "64"], "height"),
        (["--split", "train", "--height", "32"], "train split"),
        (["--split", "test", "--height", "32", "--world", "home"], "world"),
    ):
        code, line = _run([*base, *extra], capsys)
        assert code == 2 and word in line
    assert (ds / "dataset.json").read_bytes() == before


def test_pack_names_the_missing_input_not_its_output(dataset, tmp_path, capsys):
    ds = _copy(dataset, tmp_path)
    index = json.loads((ds / "dataset.json").read_text())
    index["scenes"].append({"folder": "gone"})
    (ds / "dataset.json").write_text(json.dumps(index))
    out = tmp_path / "p.safetensors"
    code, line = _run(["dataset", "pack", str(ds), "--out", str(out), "--height", "32"], capsys)
    assert code == 2 and "gone" in line and "cannot write" not in line
    assert not out.exists()


def _demo(tmp_path: Path, frames: int | None = None) -> Path:
    scene = Path(shutil.copytree(asset_path("demo"), tmp_path / "demo"))
    if frames is not None:
        meta = json.loads((scene / "transforms.json").read_text())
        meta["frames"] = meta["frames"][:frames]
        (scene / "transforms.json").write_text(json.dumps(meta))
    return scene


def test_the_same_photograph_at_several_poses_is_refused_by_import(tmp_path, capsys):
    scene = _demo(tmp_path)
    poses = tmp_path / "t.txt"
    poses.write_text("0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n")
    photo = str(scene / "images" / "frame_000.png")
    out = tmp_path / "imp"
    argv = ["scene", "import", "--format", "tum", str(poses), "--out", str(out)]
    code, line = _run([*argv, "--images", photo, photo], capsys)
    assert code == 2 and "given twice" in line and not out.exists()


def test_a_one_view_scene_says_so(tmp_path, capsys):
    scene = _demo(tmp_path, frames=1)
    code, line = _run(["render", str(scene), "--out", str(tmp_path / "b.png")]
                      + ["--target-frame", "0", "--method", "nearest"], capsys)  # fmt: skip
    assert code == 2 and "only 1 view" in line
    code, line = _run(["demo", "--scene", str(scene), "--out", str(tmp_path / "dm")], capsys)
    assert code == 2 and "two or more" in line and not (tmp_path / "dm").exists()


def test_view_saves_its_camera_path_only_as_json(tmp_path, capsys):
    scene = _demo(tmp_path)
    keep = tmp_path / "keep.png"
    keep.write_bytes(b"an image")
    argv = ["view", str(scene), "--window", "headless", "--no-refine", "--frames", "2"]
    code, line = _run([*argv, "--path-out", str(keep)], capsys)
    assert code == 2 and "--path-out must end in .json" in line
    assert keep.read_bytes() == b"an image"


def test_an_empty_cache_folder_is_refused(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    scene = _demo(tmp_path)
    code, line = _run(["scene", "prepare", str(scene), "--cache-dir", ""], capsys)
    assert code == 2 and "--cache-dir" in line and "empty" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo"]


def test_a_file_name_that_is_not_text_is_printed_escaped(tmp_path):
    """A real stdout (a UTF-8 pipe, not pytest's capture) cannot encode a lone surrogate."""
    scene = _demo(tmp_path)
    meta = json.loads((scene / "transforms.json").read_text())
    meta["frames"][0]["file_path"] = "images/\ud800.png"
    (scene / "transforms.json").write_text(json.dumps(meta))
    argv = [sys.executable, "-m", "panogrf.app.cli", "scene", "check", str(scene)]
    run = subprocess.run(argv, capture_output=True, env=os.environ | {"PYTHONIOENCODING": "utf-8"})
    assert run.returncode == 1 and b"Traceback" not in run.stderr
    assert b"images/\\ud800.png" in run.stdout and b"file not found" in run.stdout


def test_reproject_needs_another_view_and_distinct_sources(tmp_path, capsys):
    code, line = _run(["scene", "reproject", str(_demo(tmp_path / "a", frames=1))], capsys)
    assert code == 2 and "one view" in line and line.startswith("panogrf scene reproject:")
    scene = _demo(tmp_path / "b")
    code, line = _run(["scene", "reproject", str(scene), "--sources", "0,0"], capsys)
    assert code == 2 and "distinct" in line


def test_an_output_folder_that_cannot_be_made_is_refused_before_posing(tmp_path, capsys):
    scene = _demo(tmp_path)
    photos = sorted(str(p) for p in (scene / "images").iterdir())
    code, line = _run(["scene", "from-panoramas", *photos, "--out", "/proc/panogrf"], capsys)
    assert code == 2 and "cannot make this folder" in line


def test_eval_says_why_no_scene_can_be_scored(tmp_path, capsys):
    scenes = tmp_path / "scenes"
    _demo(scenes, frames=2)
    code, line = _run(["eval", str(scenes), "--out", str(tmp_path / "r.json")], capsys)
    assert code == 2 and "no scene can be scored" in line and "expected three views" in line
