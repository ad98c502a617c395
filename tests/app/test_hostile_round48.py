"""Hostile input, round 48: an option that means nothing to the method asked for, poses in the
wrong unit, a setting listed twice, outputs written into a scene or a folder of other files.
Each refused (or, where the render still works, warned about) in one line, before any work,
with inputs and earlier outputs left as they were."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import pytest
from helpers.cli import run_cli as _run

from panogrf.app.cli import main
from panogrf.app.errors import UserError
from panogrf.assets import path as asset_path


def _digest(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _make_args(out: Path, *extra: str) -> list[str]:
    args = ["dataset", "make", "--split", "test", "--no-progress", "--count", "1"]
    return [*args, "--height", "32", "--baselines", "1.0", *extra, "--out", str(out)]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """A one-scene dataset at 32 rows."""
    out = tmp_path_factory.mktemp("data") / "ds"
    assert main(_make_args(out)) == 0
    return out


@pytest.fixture
def scene(tmp_path) -> Path:
    return Path(shutil.copytree(asset_path("demo"), tmp_path / "my scene"))


def test_render_refuses_a_quality_for_a_method_that_does_not_sample(tmp_path, capsys):
    out = tmp_path / "p.png"
    args = ["render", str(asset_path("demo")), "--out", str(out), "--target-frame", "1"]
    args += ["--height", "16"]
    for method, quality in (("nearest", "paper"), ("meshwarp", "fast"), ("snerf", "paper")):
        code, line = _run([*args, "--method", method, "--quality", quality], capsys)
        assert code == 2 and line.endswith(
            f"--quality {quality} does nothing for --method {method} (only the neural methods "
            "sample): drop --quality"
        )
        assert not out.exists()
    assert _run([*args, "--method", "nearest"], capsys)[0] == 0  # the default still works
    assert out.exists()


def _scaled(scene: Path, scale: float, value: str | None = None) -> None:
    """Multiply the scene's camera positions by ``scale`` (a unit mistake); with ``value``,
    frame 1's x is that raw JSON text instead."""
    path = scene / "transforms.json"
    data = json.loads(path.read_text())
    for frame in data["frames"]:
        for row in frame["transform_matrix"][:3]:
            row[3] *= scale
    data["frames"][1]["transform_matrix"][0][3] = "X"
    text = json.dumps(data).replace(
        '"X"', value or repr(data["frames"][0]["transform_matrix"][0][3])
    )
    path.write_text(text)


def test_poses_kilometres_apart_are_warned_about_and_non_finite_ones_refused(
    scene, tmp_path, capsys
):
    out = tmp_path / "p.png"
    args = ["render", str(scene), "--out", str(out), "--target-frame", "1", "--height", "16"]
    assert main([*args, "--method", "nearest"]) == 0
    assert "warning" not in capsys.readouterr().err  # the demo's poses, in metres
    _scaled(scene, 1e6)  # millimetres read as metres, and then some
    assert main([*args, "--method", "nearest"]) == 0  # the nearest source is still a render
    warnings = [x for x in capsys.readouterr().err.splitlines() if x.startswith("warning")]
    assert len(warnings) == 1
    assert warnings[0].startswith(f"warning: {scene / 'transforms.json'}: photos ")
    assert "m apart" in warnings[0] and warnings[0].endswith(
        "check the units of the poses (metres expected)"
    )
    metres = float(warnings[0].split("photos ")[1].split(" m apart")[0])
    assert 1e5 < metres < 1e7
    assert main(["scene", "check", str(scene)]) == 0
    assert "  warning: transforms.json: photos" in capsys.readouterr().out
    trajectory = tmp_path / "poses.txt"  # TUM, in millimetres
    trajectory.write_text("0 0 0 0 0 0 0 1\n1 1500 0 0 0 0 0 1\n")
    images = [str(asset_path(f"demo/images/frame_00{i}.png")) for i in (0, 1)]
    imported = tmp_path / "imported"
    args_import = ["scene", "import", "--format", "tum", str(trajectory), "--out", str(imported)]
    assert main([*args_import, "--images", *images]) == 0
    assert capsys.readouterr().err.strip() == (
        f"warning: {imported / 'transforms.json'}: photos 1500 m apart (frames[0] and its "
        "nearest, frames[1]): check the units of the poses (metres expected)"
    )
    for value in ("NaN", "Infinity", "1e400"):
        _scaled(scene, 1.0, value)
        code, line = _run([*args, "--method", "nearest"], capsys)
        assert code == 2 and "frames[1].transform_matrix: contains NaN or infinite" in line


def test_bench_refuses_a_setting_listed_twice(dataset, tmp_path, capsys):
    out = tmp_path / "bench"
    args = ["bench", str(dataset), "--out", str(out), "--settings", "nearest,meshwarp, nearest"]
    code, line = _run(args, capsys)
    assert code == 2 and line.endswith(
        "--settings: nearest is listed twice; give each setting once"
    )
    assert not out.exists()


def test_dataset_make_refuses_a_scene_or_a_folder_of_other_files(dataset, scene, tmp_path, capsys):
    before = _digest(scene)
    for out in (scene, scene / "images"):
        code, line = _run(_make_args(out), capsys)
        assert code == 2 and f"--out {out} is not empty (" in line
        assert "holds no earlier `dataset make` output" in line
    assert _digest(scene) == before
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    code, line = _run(_make_args(mine), capsys)
    assert code == 2 and "(notes.txt)" in line
    assert [p.name for p in mine.iterdir()] == ["notes.txt"]
    # An earlier output of `dataset make` takes more scenes, as before.
    more = Path(shutil.copytree(dataset, tmp_path / "more"))
    assert _run(_make_args(more, "--start", "1"), capsys)[0] == 0
    assert sorted(p.name for p in more.iterdir()) == ["dataset.json", "test_00000", "test_00001"]
    stopped = tmp_path / "stopped"  # a run stopped before its index: run again, it completes
    shutil.copytree(dataset / "test_00000", stopped / "test_00000")
    assert _run(_make_args(stopped), capsys)[0] == 0
    assert sorted(p.name for p in stopped.iterdir()) == ["dataset.json", "test_00000"]


def test_bench_refuses_a_scene_or_a_folder_of_other_files(dataset, scene, tmp_path, capsys):
    from panogrf.app.bench.report import OUTPUTS, earlier_output
    from panogrf.app.files.atomic import refuse_foreign_folder

    before = _digest(dataset), _digest(scene)
    for out in (scene, dataset, dataset / "test_00000"):
        args = ["bench", str(dataset), "--out", str(out), "--settings", "nearest"]
        code, line = _run(args, capsys)
        assert code == 2 and "holds no earlier `bench` output" in line and str(out) in line
    assert (_digest(dataset), _digest(scene)) == before
    earlier = tmp_path / "earlier"
    earlier.mkdir()
    for name in OUTPUTS:
        (earlier / name).write_text("{}")
    (earlier / "results.json").write_text(json.dumps({"config": {}, "results": {}}))
    refuse_foreign_folder(earlier, "bench", earlier_output)  # replaced, as before
    (earlier / "notes.txt").write_text("mine")
    with pytest.raises(UserError, match=r"is not empty \(frontier.png, gallery.png, notes.txt"):
        refuse_foreign_folder(earlier, "bench", earlier_output)


def test_outputs_that_cannot_be_written_are_refused_before_any_work(tmp_path, capsys):
    demo = str(asset_path("demo"))
    folder = tmp_path / "p.png"  # a folder where the picture goes
    folder.mkdir()
    args = ["render", demo, "--out", str(folder), "--target-frame", "1", "--height", "16"]
    code, line = _run(args, capsys)
    assert code == 2 and line.endswith(f"--out: {folder} is a folder, expected a file name")
    code, line = _run(
        ["view", demo, "--window", "headless", "--screenshot-dir", str(tmp_path / "no")], capsys
    )
    assert code == 2 and line.endswith(f"--screenshot-dir {tmp_path / 'no'}: does not exist")
    a_file = str(asset_path("demo/transforms.json"))
    render = ["render", demo, "--out", str(tmp_path / "p.jpg"), "--target-frame", "1"]
    for command in (["scene", "prepare", demo], render):
        code, line = _run([*command, "--cache-dir", a_file], capsys)
        assert code == 2 and "--cache-dir" in line and line.endswith("is a file, expected a folder")
    assert not (tmp_path / "p.jpg").exists()  # refused before any work
    photos = tmp_path / "photos"
    photos.mkdir()
    (photos / "a.jpg").write_bytes(b"mine")
    code, line = _run(["demo", "--out", str(photos)], capsys)
    assert code == 2 and "(a.jpg) and holds no earlier `demo` output" in line
    assert [p.name for p in photos.iterdir()] == ["a.jpg"]


def test_numbers_that_cannot_work_are_refused_in_one_line(dataset, tmp_path, capsys):
    report = str(tmp_path / "r.json")
    for baselines in ("1,nan", "-1", "0.01"):
        code, line = _run(
            [
                "eval",
                str(dataset),
                "--methods",
                "nearest",
                "--out",
                report,
                "--baselines",
                baselines,
            ],
            capsys,
        )
        assert code == 2 and line.endswith(
            f"--baselines {baselines}: expected metres, each at least 0.1 (scenes are matched "
            "to 0.1 m)"
        )
    out = tmp_path / "many"
    code, line = _run(_make_args(out, "--start", "999999", "--count", "2"), capsys)
    assert code == 2 and "--start 999999 + --count 2: at most 1000000 scenes per --seed" in line
    assert not out.exists()
    weights = str(tmp_path / "w.safetensors")
    for kind, rows in (("depth", "32"), ("renderer", "64")):
        args = ["train", kind, "--data", str(dataset), "--out", weights, "--height", "0"]
        code, line = _run([*args, *(["--stage", "mono"] if kind == "depth" else [])], capsys)
        assert code == 2 and line.endswith(f"--height must be a positive multiple of {rows}, got 0")


def test_running_out_of_memory_is_one_line(monkeypatch, capsys):
    from panogrf.app.commands import compare

    def greedy(args):
        raise RuntimeError(
            "[enforce fail at alloc_cpu.cpp:127] err == 0. DefaultCPUAllocator: can't allocate "
            "memory: you tried to allocate 614400000000 bytes. Error code 12"
        )

    monkeypatch.setattr(compare, "run", greedy)
    code, line = _run(["compare", "a.png", "b.png"], capsys)
    assert code == 1 and line == (
        "panogrf compare: error: out of memory (572.2 GiB asked for): ask for less (--height, "
        "--batch, ...)"
    )
    monkeypatch.setattr(compare, "run", lambda args: 1 / 0)  # any other error stays a bug
    with pytest.raises(ZeroDivisionError):
        main(["compare", "a.png", "b.png"])
