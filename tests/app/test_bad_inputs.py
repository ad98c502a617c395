"""Bad and edge inputs (issue 14, "Tracebacks"): each ends in one line naming the problem and a
non-zero exit, never a traceback. In process with seeded random networks, so each case is fast;
`benchmarks/bad_inputs.py` runs the whole battery as subprocesses."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys

import pytest
import torch
from helpers.nets import random_models

from panogrf.app import cli, scoring
from panogrf.app.scene import session
from panogrf.app.viewer.window import parse_script
from panogrf.assets import path as asset_path
from panogrf.model.metrics import ssim

DEMO = asset_path("demo")


@pytest.fixture
def random_nets(monkeypatch):
    monkeypatch.setattr(session, "default_models", random_models)


def run(argv: list[str], capsys) -> tuple[int, str, str]:
    """Exit status, stdout and stderr of ``panogrf ARGV``; any other exception fails the test."""
    try:
        code = cli.main([str(a) for a in argv])
    except SystemExit as exc:  # argparse
        code = exc.code
    out = capsys.readouterr()
    return code, out.out, out.err


def refused(argv: list[str], capsys, *words: str) -> str:
    code, _, err = run(argv, capsys)
    assert code != 0, err
    assert "Traceback" not in err
    for word in words:
        assert word in err, err
    return err


@pytest.mark.slow
def test_render_draft_quality_is_offered_and_works(random_nets, tmp_path, capsys):
    out = tmp_path / "d.png"
    code, stdout, err = run(
        ["render", DEMO, "--out", out, "--target-frame", 1, "--height", 16, "--quality", "draft"],
        capsys,
    )
    assert code == 0, err
    assert out.is_file() and "draft" in stdout


@pytest.mark.parametrize("height", [8, 10])
def test_render_json_scores_tiny_heights_with_null_not_nan(random_nets, tmp_path, capsys, height):
    out = tmp_path / "t.png"
    argv = ["render", DEMO, "--out", out, "--target-frame", 1, "--height", height, "--json"]
    argv += ["--method", "nearest"]  # no network: the scores are what is tested
    code, stdout, err = run(argv, capsys)
    assert code == 0, err
    summary = json.loads(stdout, parse_constant=lambda c: pytest.fail(f"{c} in JSON"))
    assert summary["metrics"]["ssim"] is None and summary["metrics"]["lpips"] is None
    assert math.isfinite(summary["metrics"]["psnr"])


def test_banded_ssim_equals_whole_image_ssim(monkeypatch):
    g = torch.Generator().manual_seed(0)
    x, y = torch.rand(1, 3, 40, 80, generator=g), torch.rand(1, 3, 40, 80, generator=g)
    monkeypatch.setattr(scoring, "SSIM_BAND_PIXELS", 7 * 80)  # bands of 7 rows, uneven end
    assert scoring.banded_ssim(x, y) == pytest.approx(float(ssim(x, y)), abs=1e-6)
    assert math.isnan(scoring.banded_ssim(x[..., :10, :], y[..., :10, :]))


@pytest.mark.parametrize(
    "command",
    [
        ["render", DEMO, "--out", "x.png", "--target-frame", 1],
        ["view", DEMO, "--window", "headless"],
        ["eval", DEMO, "--out", "x.json"],
        ["train", "renderer", "--data", DEMO, "--out", "x.safetensors"],
    ],
    ids=["render", "view", "eval", "train"],
)
def test_negative_threads_are_refused(capsys, command):
    refused([*command, "--threads", "-1"], capsys, "--threads")


def _path(tmp_path, width: int, height: int, camera_type: str = "equirectangular"):
    c2w = [1, 0, 0, 8.5, 0, 1, 0, 1.5, 0, 0, 1, 2.0, 0, 0, 0, 1]
    data = {
        "camera_type": camera_type,
        "render_width": width,
        "render_height": height,
        "fps": 30,
        "seconds": 1 / 30,
        "camera_path": [{"camera_to_world": c2w, "fov": 60, "aspect": 1.0}],
    }
    path = tmp_path / "path.json"
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize(
    "size",
    [(40000, 20000, "equirectangular"), (9000, 100, "perspective"), (4, 2, "equirectangular")],
)
def test_camera_path_sizes_that_cannot_render_are_refused_up_front(tmp_path, capsys, size):
    path = _path(tmp_path, *size)
    argv = ["render", DEMO, "--camera-path", path, "--out", tmp_path / "v.mp4"]
    err = refused(argv, capsys, "out of range", f"{size[0]}x{size[1]}")
    assert len(err.strip().splitlines()) == 1
    assert not list(tmp_path.glob("*.mp4"))


@pytest.mark.gl
def test_preview_over_the_gl_texture_limit_is_refused_before_the_work():
    from panogrf.app.errors import UserError
    from panogrf.app.paths.frames import FrameRenderer
    from panogrf.app.scene.folder import load_scene
    from panogrf.renderer.methods import SourceViews

    data = load_scene(DEMO, load_images=True).images
    frames = FrameRenderer(SourceViews(data.images, data.c2w), random_models(), "preview")
    try:
        limit = frames._context().info["GL_MAX_TEXTURE_SIZE"]
        frames.check_height(limit // 6)  # 3 sources x 2H columns fit
        with pytest.raises(UserError, match="texture|limit"):
            frames.check_height(limit // 6 + 1)
    finally:
        frames.release()


@pytest.mark.parametrize(
    "index",
    [
        '{"scenes": [{"folder": 5}]}',
        '{"scenes": ["a"]}',
        '{"scenes": {"folder": "a"}}',
        "[1, 2]",
        "{",
        b"\xff\xfe{",
        None,  # dataset.json is a folder
        '{"scenes": [{"folder": "s"}, {"folder": "s"}]}',
    ],
)
def test_eval_refuses_malformed_dataset_index(tmp_path, capsys, index):
    target = tmp_path / "dataset.json"
    if index is None:
        target.mkdir()
    elif isinstance(index, bytes):
        target.write_bytes(index)
    else:
        target.write_text(index)
    shutil.copytree(DEMO, tmp_path / "s")
    refused(["eval", tmp_path, "--out", tmp_path / "r.json"], capsys, "dataset.json")


@pytest.mark.parametrize(
    "option",
    [["--height", "-5"], ["--height", "100000"], ["--limit", "0"], ["--subset-size", "-1"]],
)
def test_eval_refuses_bad_numbers(tmp_path, capsys, option):
    refused(["eval", DEMO, "--out", tmp_path / "r.json", *option], capsys, option[0])
    assert not (tmp_path / "r.json").exists()


@pytest.mark.parametrize("tol", ["-1", "nan", "inf", "0"])
def test_reproject_refuses_bad_occlusion_tolerance(capsys, tol):
    refused(["scene", "reproject", DEMO, f"--occlusion-tol={tol}"], capsys, "--occlusion-tol")


def test_unknown_option_prints_the_subcommands_usage(capsys):
    err = refused(["scene", "check", DEMO, "--bogus"], capsys, "--bogus")
    assert "usage: panogrf scene check" in err
    err = refused(["view", DEMO, "--bogus"], capsys, "--bogus")
    assert "usage: panogrf view" in err and "--script" in err


@pytest.mark.parametrize("script", ["jump", "zz*3", "w*x", "w*0", "w*-2"])
def test_script_typos_are_errors(script, capsys):
    with pytest.raises(ValueError, match="unknown key|count"):
        parse_script(script)
    argv = ["view", DEMO, "--window", "headless", "--no-refine", "--script", script]
    refused(argv, capsys, "--script")


def test_script_keys_still_parse():
    assert parse_script("w*30, x ,wait*10,refined,1,[,esc,tab") == [
        ("W", 30),
        ("X", 0),
        ("WAIT", 10),
        ("REFINED", 0),
        ("NUMBER_1", 0),
        ("LEFT_BRACKET", 0),
        ("ESCAPE", 0),
        ("TAB", 0),
    ]


def test_closed_pipe_ends_quietly():
    """``panogrf scene check DIR | head`` with the reader gone: no BrokenPipeError."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "panogrf.app.cli", "scene", "check", str(DEMO)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    proc.stdout.close()  # the reader goes away before the command prints
    err = proc.stderr.read().decode()
    proc.wait(timeout=60)
    assert "Traceback" not in err and "BrokenPipeError" not in err, err
    assert proc.returncode == 141
