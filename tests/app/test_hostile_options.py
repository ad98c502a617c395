"""Hostile input, round two (issue 57): numeric options validated where they are parsed, and
weights files checked (there, complete, finite) before any work, each refused in one line."""

from __future__ import annotations

import shutil

import pytest
import torch
from safetensors import safe_open
from safetensors.torch import load_file, save_file

from panogrf.app.cli import main
from panogrf.assets import path as asset_path


@pytest.mark.parametrize(
    "argv, option",
    [
        (["scene", "import", "x.txt", "--out", "o", "--scale", "0"], "--scale"),  # S4
        (["scene", "import", "x.txt", "--out", "o", "--scale", "-2"], "--scale"),  # S4
        (["scene", "import", "x.txt", "--out", "o", "--scale", "nan"], "--scale"),  # T7
        (["scene", "import", "x.txt", "--out", "o", "--scale", "inf"], "--scale"),  # T7
        (["render", "s", "--out", "x.png", "--threads", "100000"], "--threads"),  # T5
        (["eval", "d", "--threads", "100000"], "--threads"),  # T5
        (["view", "s", "--fixed-step=-0.5"], "--fixed-step"),  # S10
        (["view", "s", "--fixed-step", "nan"], "--fixed-step"),  # T16
        (["view", "s", "--fixed-step", "inf"], "--fixed-step"),  # T16
        (["bench", "--time-budget=-1"], "--time-budget"),  # S9
        (["train", "depth", "--lr", "nan"], "--lr"),  # T15
        (["dataset", "make", "--out", "o", "--seed=-5"], "--seed"),  # T12
        (["dataset", "make", "--out", "o", "--start=-5"], "--start"),  # T12
        (["dataset", "pack", "d", "--out", "o", "--height", "0"], "--height"),  # T13
        (["dataset", "pack", "d", "--out", "o", "--height", "-32"], "--height"),  # T13
        (["scene", "faces", "a.png", "--out", "o", "--size", "-5"], "--size"),  # T11
    ],
)
def test_a_bad_number_is_refused_in_one_line(argv, option, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert f"argument {option}" in err[-1] and "Traceback" not in "\n".join(err)
    assert list(tmp_path.iterdir()) == []  # nothing written


def _broken_weights(tmp_path, name: str, how: str):
    folder = tmp_path / "weights"
    folder.mkdir()
    for f in asset_path("").glob("*.safetensors"):
        shutil.copy(f, folder / f.name)
    target = folder / name
    if how == "nan":
        with safe_open(str(target), framework="pt") as f:
            meta = f.metadata()
        tensors = load_file(str(target))
        first = next(iter(tensors))
        tensors[first] = torch.full_like(tensors[first], float("nan"))
        save_file(tensors, str(target), metadata=meta)
    elif how == "truncated":
        target.write_bytes(target.read_bytes()[:50_000])
    else:
        target.write_bytes(b"")
    return folder


@pytest.mark.parametrize(
    "name, how",
    [
        ("renderer_panogrf.safetensors", "nan"),  # S7: the renderer's, read after the depth
        ("depth_mvs_full.safetensors", "truncated"),  # T6
        ("depth_mono.safetensors", "empty"),  # T6
    ],
)
def test_broken_weights_are_refused_before_any_work(name, how, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("PANOGRF_WEIGHTS", str(_broken_weights(tmp_path, name, how)))
    out = tmp_path / "x.png"
    argv = ["render", str(asset_path("demo")), "--target-frame", "1", "--out", str(out)]
    assert main([*argv, "--height", "32", "--no-cache", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and name in err[0], err
    assert ("non-finite" in err[0]) == (how == "nan")
    assert not out.exists()


def test_faces_of_two_panoramas_of_one_name_are_refused(tmp_path, capsys):
    """S5: a/x.png and b/x.png would write their faces into one folder, the second over the
    first, while the summary claimed both."""
    from panogrf.app.files.images import write_rgb

    for sub in ("a", "b"):
        (tmp_path / sub).mkdir()
        write_rgb(tmp_path / sub / "x.png", torch.zeros(32, 64, 3, dtype=torch.uint8).numpy())
    out = tmp_path / "faces"
    argv = ["scene", "faces", str(tmp_path / "a/x.png"), str(tmp_path / "b/x.png")]
    assert main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "share the name 'x'" in err[0]
    assert not out.exists()
    (tmp_path / "file").write_text("x")
    assert main(["scene", "faces", str(tmp_path / "a/x.png"), "--out", str(tmp_path / "file")]) == 2
    assert "is a file" in capsys.readouterr().err


def test_eval_means_leave_out_what_a_small_scene_cannot_score():
    """S8: one scene too small for SSIM and LPIPS made both means NaN (null) for all."""
    from panogrf.app.commands.eval import _means, format_table

    items = [
        {"psnr": 30.0, "ws_psnr": 29.0, "ssim": 0.9, "lpips": 0.1},
        {"psnr": 20.0, "ws_psnr": 19.0, "ssim": float("nan"), "lpips": float("nan")},
    ]
    means = _means(items)
    assert means["psnr"] == 25.0 and means["ssim"] == 0.9 and means["lpips"] == 0.1
    assert means["undefined"] == {"ssim": 1, "lpips": 1}
    row = means | {"scenes": 2, "render_ms_median": 1.0}
    table = format_table({"panogrf": {"1.0": row}}, [1.0])
    assert "lpips: 1 scene(s) too small to score, left out" in table


@pytest.mark.parametrize("out", ["/proc/m.safetensors", "folder.safetensors"])
def test_train_refuses_an_unwritable_out_before_training(out, tmp_path, monkeypatch, capsys):
    """T14: the steps trained, then the weights could not be written and were lost."""
    import panogrf.app.train.loop as loop

    monkeypatch.chdir(tmp_path)
    (tmp_path / "folder.safetensors").mkdir()
    monkeypatch.setattr(loop, "save_weights", lambda *a, **k: pytest.fail("trained first"))
    argv = ["train", "depth", "--data", str(tmp_path), "--stage", "mono", "--out", out]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--out" in err[0]


def _demo_copy(tmp_path, change=None, text=None):
    import json

    scene = tmp_path / "scene"
    shutil.copytree(asset_path("demo"), scene)
    path = scene / "transforms.json"
    if text is not None:
        path.write_text(text)
    else:
        data = json.loads(path.read_text())
        change(data)
        path.write_text(json.dumps(data))
    return scene


def _far(data):
    data["frames"][0]["transform_matrix"][0][3] = 1e300


def _long_name(data):
    data["frames"][0]["file_path"] = "images/" + "x" * 300 + ".png"


@pytest.mark.parametrize(
    "change, text, expected",
    [
        (_far, None, "farther than 1e+09 m"),  # T1: an overflow in the check
        (_long_name, None, "file name too long"),  # T2
        (None, "[" * 200_000, "nested too deeply"),  # T3: RecursionError
    ],
)
def test_scene_check_names_the_problem_instead_of_a_traceback(
    change, text, expected, tmp_path, capsys
):
    scene = _demo_copy(tmp_path, change, text)
    assert main(["scene", "check", str(scene)]) == 1  # scene check: 1 for an invalid scene
    out = capsys.readouterr()
    assert expected in out.out + out.err and "Traceback" not in out.out + out.err


def test_a_camera_path_nested_too_deeply_is_one_line(tmp_path, capsys):
    path = tmp_path / "path.json"
    path.write_text("[" * 200_000)
    argv = ["render", str(asset_path("demo")), "--camera-path", str(path)]
    assert main([*argv, "--out", str(tmp_path / "x.mp4")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nested too deeply" in err[0]


def test_a_full_disk_is_one_line_for_pack_and_import(tmp_path, capsys):
    """T10, T13: `dataset pack` and `scene import` onto a full disk gave tracebacks."""
    from helpers.disk import fill, tiny_tmpfs

    from panogrf.app.poses import importers as im
    from panogrf.app.scene.folder import load_scene

    demo = asset_path("demo")
    pose_file = tmp_path / "t.txt"
    im.write_tum(pose_file, load_scene(demo).c2w)
    images = [str(p) for p in sorted((demo / "images").glob("*.png"))]
    data = tmp_path / "data"
    data.mkdir()
    shutil.copytree(demo, data / "a")
    (data / "dataset.json").write_text('{"scenes": [{"folder": "a"}]}')
    with tiny_tmpfs(tmp_path / "disk") as disk:
        fill(disk)
        argv = ["scene", "import", "--format", "tum", str(pose_file), "--images", *images]
        assert main([*argv, "--out", str(disk / "s")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "No space left" in err[0], err
        (disk / "ballast").unlink()
        fill(disk)  # room for the probe file only
        assert main(["dataset", "pack", str(data), "--out", str(disk / "p.safetensors")]) == 2
        err = capsys.readouterr().err  # the loading progress bar, then the error
        assert "No space left" in err.strip().splitlines()[-1] and "Traceback" not in err, err
