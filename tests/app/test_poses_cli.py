"""`panogrf scene from-panoramas` on the bundled demo scene and on bad input; `panogrf eval` on
a plain folder of scenes."""

from __future__ import annotations

import json
import math
import re
import shutil

import numpy as np
import pytest

from panogrf.app import cli
from panogrf.app import progress as app_progress
from panogrf.app.files.images import write_rgb
from panogrf.app.poses import errors as er
from panogrf.app.scene import session
from panogrf.app.scene.folder import load_scene
from panogrf.assets import path as asset_path

DEMO = asset_path("demo")


@pytest.fixture(autouse=True)
def only_needed_commands(monkeypatch):
    monkeypatch.setattr(cli, "_COMMANDS", ("scene", "eval"))


def test_demo_poses_from_its_pixels(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(app_progress, "INTERVAL", 0.0)  # every stage shown, however short
    truth = load_scene(DEMO)
    images = [str(f.image_path) for f in truth.frames]
    heights = ",".join(f"{h:.4f}" for h in truth.c2w[:, 1, 3])  # the floor is at y = 0
    out = tmp_path / "est"
    assert (
        cli.main(
            ["scene", "from-panoramas", *images, "--out", str(out), "--camera-height", heights]
        )
        == 0
    )
    captured = capsys.readouterr()
    report = captured.out
    assert "matches; ok" in report and "median residual" in report and "upright:" in report
    assert "nan" not in report.lower()
    # Every stage of the posing showed its progress on stderr.
    for name in ("features", "matching", "verification", "guided matching", "mapping"):
        assert f"posing: {name}:" in captured.err
    saved = json.loads((out / "poses_report.json").read_text())
    assert len(saved["pairs"]) == 3 and all(p["ok"] for p in saved["pairs"])
    for p in saved["pairs"]:
        assert 0 < p["inliers"] <= p["matches"]
        assert math.isfinite(p["median_residual_deg"]) and p["shared_points"] > 0
    assert all(v["registered"] for v in saved["views"])
    est = load_scene(out).c2w
    errors = er.pair_errors(est, truth.c2w)
    assert max(e["rotation_deg"] for e in errors) < 0.5
    assert max(e["translation_deg"] for e in errors) < 2.0
    assert er.scale_error(est, truth.c2w) < 0.05
    assert cli.main(["scene", "check", str(out)]) == 0


#: A line of the stages' progress on stderr (`panogrf.model.progress.Stage.text`).
PROGRESS = re.compile(r"^[\w :-]+: \d+/\d+, elapsed [\d.]+ s, eta ")


def _one_line_error(capsys, args, name):
    assert cli.main(args) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if not PROGRESS.match(line)]
    assert len(lines) == 1 and err.endswith("\n"), err
    assert str(name) in lines[0], err
    return lines[0]


def test_bad_panoramas_are_one_line_errors_naming_the_file(tmp_path, capsys):
    frames = load_scene(DEMO).frames
    a, b = str(frames[0].image_path), str(frames[2].image_path)
    out = ["--out", str(tmp_path / "s")]
    cmd = ["scene", "from-panoramas"]
    assert "one panorama" in _one_line_error(capsys, [*cmd, a, *out], a)
    assert "given twice" in _one_line_error(capsys, [*cmd, a, a, *out], a)
    copy = tmp_path / "copy.png"
    copy.write_bytes(frames[0].image_path.read_bytes())
    assert f"same image as {a}" in _one_line_error(capsys, [*cmd, a, str(copy), *out], copy)
    square = tmp_path / "square.png"
    write_rgb(square, np.zeros((16, 16, 3), np.uint8))
    assert "2:1" in _one_line_error(capsys, [*cmd, a, str(square), *out], square)
    truncated = tmp_path / "truncated.png"
    truncated.write_bytes(frames[1].image_path.read_bytes()[:300])
    _one_line_error(capsys, [*cmd, a, str(truncated), *out], truncated)
    garbage = tmp_path / "garbage.jpg"
    garbage.write_bytes(b"not an image at all")
    _one_line_error(capsys, [*cmd, str(garbage), a, *out], garbage)
    # Two unrelated panoramas: smooth noise with nothing in common.
    rng = np.random.default_rng(0)
    flat = []
    for k in range(2):
        path = tmp_path / f"flat{k}.png"
        write_rgb(
            path,
            np.full((128, 256, 3), 90 + 60 * k, np.uint8)
            + rng.integers(0, 3, (128, 256, 3), dtype=np.uint8),
        )
        flat.append(str(path))
    err = _one_line_error(capsys, [*cmd, *flat, *out], flat[0])
    assert "could be posed" in err
    assert "--distance" in _one_line_error(capsys, [*cmd, a, b, *out, "--distance", "0,0=1"], "")


def test_eval_on_a_plain_folder_of_scenes_and_on_one_scene(tmp_path, monkeypatch, capsys):
    from panogrf.renderer.methods import Models

    def no_network(_):
        raise AssertionError("the nearest method needs no network")

    monkeypatch.setattr(
        session, "default_models", lambda device=None: Models(no_network, no_network)
    )
    folder = tmp_path / "mine"
    for name in ("kitchen", "hall"):
        shutil.copytree(DEMO, folder / name)
    (folder / "notes").mkdir()  # not a scene: ignored
    out = tmp_path / "r.json"
    args = ["--out", str(out), "--methods", "nearest", "--height", "32"]
    assert cli.main(["eval", str(folder), *args]) == 0
    report = json.loads(out.read_text())
    (row,) = report["results"]["nearest"].values()
    assert row["scenes"] == 2
    assert cli.main(["eval", str(DEMO), *args]) == 0
    (row,) = json.loads(out.read_text())["results"]["nearest"].values()
    assert row["scenes"] == 1
    capsys.readouterr()
    assert cli.main(["eval", str(tmp_path / "mine" / "notes"), *args]) == 2
    assert "no scene folder" in capsys.readouterr().err


def test_pycolmap_and_pillow_png_in_one_process(tmp_path):
    """pycolmap's wheel carries zlib symbols of its own: loaded the product's way, a later PNG
    written by Pillow must not abort the process (run in a child: an abort is not an error)."""
    import subprocess
    import sys

    code = (
        "from panogrf.app.poses.colmap import load_pycolmap; load_pycolmap()\n"
        "import io, numpy as np, PIL.Image\n"
        "for _ in range(5):\n"
        "    PIL.Image.fromarray(np.random.default_rng(0).integers(0, 255, (64, 128, 3),"
        " dtype=np.uint8)).save(io.BytesIO(), format='PNG')\n"
        "print('saved')\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "saved" in done.stdout, done.stderr[-2000:]


def test_two_panoramas_pose_and_an_unrelated_one_is_left_out_with_a_reason(tmp_path, capsys):
    truth = load_scene(DEMO)
    a, b = (str(truth.frames[k].image_path) for k in (0, 2))
    noise = tmp_path / "elsewhere.png"
    rng = np.random.default_rng(1)
    write_rgb(noise, rng.integers(0, 255, (256, 512, 3), dtype=np.uint8))
    out = tmp_path / "est"
    args = ["scene", "from-panoramas", a, str(noise), b, "--out", str(out), "--distance", "0,2=1"]
    assert cli.main(args) == 0
    report = capsys.readouterr().out
    assert "left out 1 panorama(s) that could not be posed: elsewhere.png" in report
    est = load_scene(out)
    assert est.num_views == 2
    (err,) = er.pair_errors(est.c2w, truth.c2w[[0, 2]])
    assert err["rotation_deg"] < 1.0 and err["translation_deg"] < 3.0
    saved = json.loads((out / "poses_report.json").read_text())
    views = {v["file"]: v for v in saved["views"]}
    assert not views[str(noise)]["registered"] and views[str(noise)]["note"]
    assert all(views[p]["registered"] for p in (a, b))
