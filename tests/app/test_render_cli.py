"""`panogrf render`, `panogrf eval` and `panogrf train renderer`: outputs, errors, plumbing.

Plumbing tests use seeded random networks (monkeypatched loaders); the tests marked with the
shipped weights run the real networks on the bundled demo scene.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from helpers.nets import random_models

from panogrf.app import cli
from panogrf.app.files.images import read_rgb
from panogrf.app.scene import session
from panogrf.assets import path as asset_path

DEMO = asset_path("demo")


@pytest.fixture
def random_nets(monkeypatch):
    monkeypatch.setattr(session, "default_models", random_models)


@pytest.mark.parametrize("method", ["panogrf", "meshwarp", "nearest", "no_mvs"])
def test_render_target_frame_writes_the_panorama_and_scores_it(random_nets, tmp_path, method):
    out = tmp_path / "mid.png"
    args = ["render", str(DEMO), "--out", str(out), "--target-frame", "1", "--height", "32"]
    assert cli.main([*args, "--method", method, "--json"]) == 0
    img = read_rgb(out)
    assert img.shape == (32, 64, 3)


def test_render_any_pose_and_summary(random_nets, tmp_path, capsys):
    out = tmp_path / "p.png"
    c2w = "1 0 0 0.2 0 1 0 1.5 0 0 1 0.1 0 0 0 1"
    args = ["render", str(DEMO), "--out", str(out), "--c2w", c2w, "--height", "16", "--json"]
    assert cli.main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["sources"] == [0, 1, 2] and summary["size"] == [32, 16]
    assert "metrics" not in summary
    assert read_rgb(out).shape == (16, 32, 3)


def test_render_refines_the_sources_depth_by_default(random_nets, tmp_path):
    """The per-scene refinement reaches the preparation by default (``--refine-depth``) and
    ``--no-refine-depth`` skips it: the same pose renders differently, because the sources'
    depth was refined (a short refinement in tests: conftest's ``quick_scene_refinement``)."""
    args = ["render", str(DEMO), "--target-frame", "1", "--height", "32", "--sources", "0,2"]
    plain, refined, again = (tmp_path / f"{n}.png" for n in ("plain", "refined", "again"))
    assert cli.main([*args, "--out", str(plain), "--no-refine-depth"]) == 0
    assert cli.main([*args, "--out", str(refined)]) == 0
    assert cli.main([*args, "--out", str(again), "--refine-depth"]) == 0
    assert not np.array_equal(read_rgb(plain), read_rgb(refined))
    assert np.array_equal(read_rgb(refined), read_rgb(again))


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--target-frame", "7"], "frames 0..2"),
        (["--target-frame", "1", "--sources", "0,1"], "must not contain the target"),
        (["--c2w", "1 2 3"], "16 numbers"),
        (["--c2w", "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 0"], "last row"),
        (["--c2w", "2 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1"], "not a rotation"),
        (["--c2w", "nan 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1"], "NaN"),
        (["--c2w", "1 0 0 1e12 0 1 0 0 0 0 1 0 0 0 0 1"], "farther than 1e+09 m"),
        (["--target-frame", "1", "--height", "3"], "--height"),
    ],
)
def test_render_bad_input_is_one_line_and_exit_2(random_nets, tmp_path, capsys, extra, message):
    out = tmp_path / "x.png"
    assert cli.main(["render", str(DEMO), "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_render_missing_scene_and_bad_output(tmp_path, capsys):
    assert (
        cli.main(
            [
                "render",
                str(tmp_path / "nope"),
                "--out",
                str(tmp_path / "a.png"),
                "--target-frame",
                "0",
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"scene folder not found: {tmp_path / 'nope'}" in err
    bad = tmp_path / "missing_dir" / "a.png"
    assert cli.main(["render", str(DEMO), "--out", str(bad), "--target-frame", "0"]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert (
        cli.main(["render", str(DEMO), "--out", str(tmp_path / "a.txt"), "--target-frame", "0"])
        == 2
    )
    assert ".png" in capsys.readouterr().err


def _tiny_dataset(tmp_path):
    """Two copies of the demo scene as a dataset (its baseline, 1.0 m, rounded)."""
    root = tmp_path / "data"
    root.mkdir()
    for name in ("a", "b"):
        shutil.copytree(DEMO, root / name)
    (root / "dataset.json").write_text(json.dumps({"scenes": [{"folder": "a"}, {"folder": "b"}]}))
    c = json.loads((DEMO / "transforms.json").read_text())["frames"]
    p = np.array([f["transform_matrix"] for f in c])[:, :3, 3]
    return root, round(float(np.linalg.norm(p[2] - p[0])), 1)


def test_eval_scores_every_method_per_baseline(random_nets, tmp_path, capsys):
    root, baseline = _tiny_dataset(tmp_path)
    out = tmp_path / "results.json"
    args = ["eval", str(root), "--out", str(out), "--baselines", str(baseline), "--height", "32"]
    methods = "panogrf,panogrf:paper,nearest,meshwarp"
    assert (
        cli.main([*args, "--methods", methods, "--subset", "panogrf:paper", "--subset-size", "1"])
        == 0
    )
    report = json.loads(out.read_text())
    res = report["results"]
    assert set(res) == {"panogrf", "panogrf:paper", "nearest", "meshwarp"}
    assert res["panogrf"][str(baseline)]["scenes"] == 2
    assert res["panogrf:paper"][str(baseline)]["scenes"] == 1
    for r in res.values():
        row = r[str(baseline)]
        assert np.isfinite([row[k] for k in ("psnr", "ws_psnr", "ssim", "lpips")]).all()
        assert row["render_ms_median"] > 0
    # The two scenes are identical: identical scores.
    ps = report["per_scene"]["nearest"][str(baseline)]
    assert ps[0]["ws_psnr"] == pytest.approx(ps[1]["ws_psnr"])
    assert "WS-PSNR" in capsys.readouterr().out


def test_eval_errors(random_nets, tmp_path, capsys):
    root, _ = _tiny_dataset(tmp_path)
    out = str(tmp_path / "r.json")
    assert cli.main(["eval", str(root), "--out", out, "--methods", "bogus"]) == 2
    assert "unknown method" in capsys.readouterr().err
    assert cli.main(["eval", str(root), "--out", out, "--methods", "nearest:paper"]) == 2
    assert "no sampling choice" in capsys.readouterr().err
    assert cli.main(["eval", str(root), "--out", out, "--baselines", "3.0"]) == 2
    assert "no scene with baseline" in capsys.readouterr().err
    assert cli.main(["eval", str(tmp_path), "--out", out]) == 2
    assert "dataset.json" in capsys.readouterr().err


def _write_path(path, camera_type="equirectangular", n=3, w=64, h=32):
    from panogrf.app.paths.camera_path import CameraPath, write_camera_path
    from panogrf.app.paths.trajectory import interpolate_keyframes
    from panogrf.app.scene.folder import load_scene

    poses = interpolate_keyframes(load_scene(DEMO).c2w, n)
    write_camera_path(path, CameraPath(poses, camera_type, w, h, fps=10.0))


@pytest.mark.gl
@pytest.mark.parametrize("quality", ["preview", "fast"])
def test_camera_path_to_mp4_opens_with_every_frame(random_nets, tmp_path, quality, capsys):
    import cv2

    cam = tmp_path / "camera_path.json"
    _write_path(cam, n=4)
    out = tmp_path / "tour.mp4"
    args = ["render", str(DEMO), "--camera-path", str(cam), "--out", str(out)]
    assert cli.main([*args, "--quality", quality]) == 0
    cap = cv2.VideoCapture(str(out))
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame)
    assert len(frames) == 4 and frames[0].shape == (32, 64, 3)
    assert "4 frames" in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["camera_path.json", "tour.mp4"]


@pytest.mark.gl
def test_perspective_path_to_png_frames(random_nets, tmp_path):
    cam = tmp_path / "p.json"
    _write_path(cam, "perspective", n=2, w=48, h=32)
    out = tmp_path / "frames"
    args = ["render", str(DEMO), "--camera-path", str(cam), "--out", str(out)]
    assert cli.main([*args, "--quality", "preview"]) == 0
    files = sorted(out.iterdir())
    assert [p.name for p in files] == ["frame_00000.png", "frame_00001.png"]
    assert read_rgb(files[0]).shape == (32, 48, 3)


@pytest.mark.gl
def test_a_path_behind_the_surfaces_is_warned_about(random_nets, tmp_path, capsys):
    """Frames whose camera sits behind the surface the sources see (here 30 m out, beyond the
    10 m depth range) are named, as are frames outside the covered region."""
    from panogrf.app.paths.camera_path import CameraPath, write_camera_path
    from panogrf.app.scene.folder import load_scene

    poses = np.array(load_scene(DEMO).c2w[:2], dtype=np.float64)
    far = poses[0].copy()
    far[:3, 3] += np.array([0.0, 0.0, -30.0])
    cam = tmp_path / "p.json"
    write_camera_path(
        cam, CameraPath(np.stack([poses[0], far, poses[1]]), "equirectangular", 32, 16, fps=10.0)
    )
    out = tmp_path / "frames"
    args = ["render", str(DEMO), "--camera-path", str(cam), "--out", str(out)]
    assert cli.main([*args, "--quality", "preview"]) == 0
    printed = capsys.readouterr().out
    assert "1 of 3 frames put the camera behind a surface" in printed and "frames 1" in printed
    assert "1 of 3 frames leave the region the sources cover" in printed


def test_camera_path_errors(random_nets, tmp_path, capsys):
    cam = tmp_path / "c.json"
    base = ["render", str(DEMO), "--camera-path", str(cam)]
    cam.write_text("{not json")
    assert cli.main([*base, "--out", str(tmp_path / "v.mp4")]) == 2
    assert "invalid JSON" in capsys.readouterr().err
    _write_path(cam)
    data = json.loads(cam.read_text())
    data["camera_path"] = []
    cam.write_text(json.dumps(data))
    assert cli.main([*base, "--out", str(tmp_path / "v.mp4")]) == 2
    assert "empty" in capsys.readouterr().err
    _write_path(cam, w=60, h=32)
    assert cli.main([*base, "--out", str(tmp_path / "v.mp4")]) == 2
    assert "render_width = 2" in capsys.readouterr().err
    _write_path(cam)
    assert cli.main([*base, "--out", str(tmp_path / "missing" / "v.mp4")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert cli.main([*base, "--out", str(tmp_path / "v.mp4"), "--height", "64"]) == 2
    assert "--height" in capsys.readouterr().err
    assert not (tmp_path / "v.mp4").exists()


def test_outputs_never_replace_the_scene_they_are_made_from(random_nets, tmp_path, capsys):
    scene = tmp_path / "scene"
    shutil.copytree(DEMO, scene)
    source = scene / "images" / "frame_000.png"
    poses = scene / "transforms.json"
    before = {p: p.read_bytes() for p in (source, poses)}
    path = tmp_path / "path.json"
    _write_path(path)
    cases = [
        ["render", str(scene), "--target-frame", "1", "--out", str(source)],
        ["render", str(scene), "--camera-path", str(path), "--out", str(scene / "images")],
        ["render", str(scene), "--camera-path", str(path), "--out", str(scene)],
        ["eval", str(scene), "--out", str(poses), "--methods", "nearest"],
    ]
    for args in cases:
        assert cli.main(args) == 2, args
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and ("refusing" in err or "name a new" in err), err
    assert all(p.read_bytes() == data for p, data in before.items())
    assert sorted(p.name for p in (scene / "images").iterdir()) == [
        "frame_000.png",
        "frame_001.png",
        "frame_002.png",
    ]


def test_a_pose_far_from_every_source_is_warned(random_nets, tmp_path, capsys):
    """Issue 57 S2: `--c2w` far from every source gave a grey panorama and exit 0, silently,
    while the same pose in a camera path warned."""
    c2w = "1 0 0 0.2 0 1 0 1.5 0 0 1 0.1 0 0 0 1"  # the demo's sources are about 8 m away
    out = tmp_path / "p.png"
    argv = ["render", str(DEMO), "--out", str(out), "--c2w", c2w, "--height", "16", "--json"]
    assert cli.main(argv) == 0
    captured = capsys.readouterr()
    json.loads(captured.out)  # stdout stays the JSON summary
    assert "warning: the --c2w pose is" in captured.err and "outside the region" in captured.err


def test_render_names_every_stage_after_the_preparation(random_nets, tmp_path):
    """Rendering, writing and scoring each show as a stage (an 8K render was silent for a
    minute after "preparing the scene")."""
    from panogrf.model import progress

    seen: list[tuple[str, str]] = []

    class Recorder:
        def started(self, stage):
            seen.append(("start", stage.name))

        def advanced(self, stage):
            pass

        def ended(self, stage):
            seen.append(("end", stage.name))

    out = tmp_path / "mid.png"
    args = ["render", str(DEMO), "--out", str(out), "--target-frame", "1", "--height", "32"]
    with progress.listening(Recorder()):
        assert cli.main([*args, "--quiet"]) == 0
    names = [name for kind, name in seen if kind == "start"]
    for name in ("rendering", "writing mid.png", "scoring"):
        assert name in names and ("end", name) in seen
    assert names.index("rendering") < names.index("writing mid.png") < names.index("scoring")


def test_a_render_too_small_to_score_says_why(random_nets, tmp_path, capsys):
    args = ["render", str(DEMO), "--out", str(tmp_path / "s.png"), "--target-frame", "1"]
    assert cli.main([*args, "--height", "8", "--quiet"]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert "LPIPS nan (n/a: too few rows for SSIM or LPIPS)" in line
