"""Hostile input, round 47: outputs written into the input scene or over a folder's own files,
settings checked only after outputs were written, training on one scene or from a file that is
not weights. Each refused in one line, before any work, with inputs and earlier outputs left as
they were."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import pytest
from helpers.cli import run_cli as _run

from panogrf.app.cli import main
from panogrf.assets import path as asset_path


def _digest(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """A one-scene dataset at 32 rows."""
    out = tmp_path_factory.mktemp("data") / "ds"
    args = ["dataset", "make", "--split", "test", "--no-progress", "--count", "1"]
    assert main([*args, "--height", "32", "--baselines", "1.0", "--out", str(out)]) == 0
    return out


def test_demo_refuses_to_write_into_its_scene_and_checks_the_nadir_cap_first(tmp_path, capsys):
    scene = Path(shutil.copytree(asset_path("demo"), tmp_path / "scene"))
    before = _digest(scene)
    for out in (scene, scene / "images"):
        code, line = _run(["demo", "--scene", str(scene), "--out", str(out)], capsys)
        assert code == 2 and "holds the scene's own files" in line
    out = tmp_path / "out"
    code, line = _run(
        ["demo", "--scene", str(scene), "--out", str(out), "--nadir-cap", "abc"], capsys
    )
    assert code == 2 and "--nadir-cap" in line and not out.exists()
    assert _digest(scene) == before


def test_eval_checks_the_nadir_cap_before_replacing_its_report(dataset, tmp_path, capsys):
    report = tmp_path / "report.json"
    report.write_text('{"earlier": true}')
    args = ["eval", str(dataset), "--methods", "nearest", "--out", str(report)]
    code, line = _run([*args, "--nadir-cap", "95"], capsys)
    assert code == 2 and "--nadir-cap" in line
    assert json.loads(report.read_text()) == {"earlier": True}


def test_depth_refuses_to_replace_a_folder_holding_more_than_its_earlier_output(tmp_path, capsys):
    out = tmp_path / "depth_out"
    scene = str(asset_path("demo"))
    args = ["depth", scene, "--out", str(out), "--mode", "mono"]
    assert _run(args, capsys)[0] == 0
    assert _run(args, capsys)[0] == 0  # its own earlier output is replaced
    (out / "notes.txt").write_text("mine")
    code, line = _run(args, capsys)
    assert code == 2 and "notes.txt" in line
    assert (out / "notes.txt").read_text() == "mine"


def test_merge_refuses_a_folder_it_did_not_write_and_a_dataset_given_twice(
    dataset, tmp_path, capsys
):
    other = Path(shutil.copytree(dataset, tmp_path / "other"))
    before = _digest(other)
    code, line = _run(["dataset", "merge", "--out", str(other), str(dataset)], capsys)
    assert code == 2 and "no earlier `dataset merge` output" in line
    assert _digest(other) == before
    code, line = _run(
        ["dataset", "merge", "--out", str(tmp_path / "m"), str(dataset), str(dataset)], capsys
    )
    assert code == 2 and "listed twice" in line
    merged = str(tmp_path / "m2")
    assert _run(["dataset", "merge", "--out", merged, str(dataset)], capsys)[0] == 0
    assert _run(["dataset", "merge", "--out", merged, str(dataset)], capsys)[0] == 0  # again


def test_training_refuses_one_scene_a_bad_init_and_a_log_folder(dataset, tmp_path, capsys):
    args = ["train", "depth", "--stage", "mono", "--steps", "1", "--height", "32"]
    weights = str(tmp_path / "w.safetensors")
    code, line = _run([*args, "--data", str(dataset), "--out", weights], capsys)
    assert code == 2 and "none to train on" in line
    junk = tmp_path / "junk.safetensors"
    junk.write_text("junk")
    for init in (junk, tmp_path):
        code, line = _run(
            [*args, "--data", str(dataset), "--out", weights, "--init", str(init)], capsys
        )
        assert code == 2 and "--init" in line
    logs = tmp_path / "logs"
    logs.mkdir()
    code, line = _run([*args, "--data", str(dataset), "--out", weights, "--log", str(logs)], capsys)
    assert code == 2 and "--log" in line and "folder" in line
    assert not Path(weights).exists()


def test_messages_name_the_option_at_fault(dataset, tmp_path, capsys):
    out = str(tmp_path / "r.json")
    code, line = _run(
        ["eval", str(dataset), "--methods", "nearest", "--out", out, "--baselines", ","], capsys
    )
    assert code == 2 and "--baselines" in line
    pack = str(tmp_path / "p.safetensors")
    code, line = _run(["dataset", "pack", str(dataset), "--out", pack, "--height", "4096"], capsys)
    assert code == 2 and "cannot be averaged to --height 4096" in line
