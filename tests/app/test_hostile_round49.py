"""Hostile input, round 49: a pair whose matches fit no camera motion, names too long for the
file system, malformed pose files (deep nesting, shots that are a number, a COLMAP images.txt
without its POINTS2D lines or with a face listed twice, positions near the float limit). Each
one line and a non-zero exit, nothing written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers.cli import run_cli as _run

from panogrf.app.poses import colmap
from panogrf.app.poses.importers import read_colmap, read_opensfm, write_colmap
from panogrf.assets import path as asset_path

DEMO = asset_path("demo")
PHOTOS = [str(DEMO / "images" / f"frame_00{k}.png") for k in range(2)]


class _Geometry:
    """A verified pair as COLMAP's database returns it, with no camera motion."""

    inlier_matches = np.zeros((500, 2), np.uint32)
    cam2_from_cam1 = None

    def __init__(self) -> None:
        self.config = colmap.load_pycolmap().TwoViewGeometryConfiguration.CALIBRATED


class _Database:
    def exists_two_view_geometry(self, a: int, b: int) -> bool:
        return True

    def read_two_view_geometry(self, a: int, b: int) -> _Geometry:
        return _Geometry()


def test_a_verified_pair_without_a_camera_motion_seeds_nothing():
    """An upside-down or mirrored photo: COLMAP verifies the matches (a homography or a
    fundamental matrix) but gives no pose; the pair is verified, seeds no guided matching."""
    essential, verified = colmap._seed(_Database(), 1, 2, colmap.ColmapConfig())
    assert essential is None and verified


def test_names_too_long_for_the_file_system_are_one_line(tmp_path, capsys):
    long = tmp_path / ("x" * 300)
    code, line = _run(["scene", "from-panoramas", *PHOTOS, "--out", str(long)], capsys)
    assert code == 2 and "too long" in line.lower() and line.startswith("panogrf")
    args = ["render", str(DEMO), "--target-frame", "1", "--method", "nearest", "--height", "16"]
    code, line = _run([*args, "--out", f"{long}.png"], capsys)
    assert code == 2 and "too long" in line.lower()
    assert list(tmp_path.iterdir()) == []


def test_an_opensfm_file_nested_too_deeply_or_with_shots_that_are_a_number(tmp_path, capsys):
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100000 + "]" * 100000)
    number = tmp_path / "number.json"
    number.write_text(json.dumps([{"cameras": {}, "shots": 5}]))
    for path, words in ((deep, "nested too deeply"), (number, "must be objects keyed by name")):
        out = tmp_path / "out"
        argv = ["scene", "import", "--format", "opensfm", str(path), "--out", str(out)]
        code, line = _run([*argv, "--images", *PHOTOS], capsys)
        assert code == 2 and words in line and str(path) in line and not out.exists()
    with pytest.raises(Exception, match="nested too deeply"):
        read_opensfm(deep)


def test_a_colmap_file_without_points_lines_or_with_a_face_twice(tmp_path, capsys):
    c2w = np.tile(np.eye(4), (2, 1, 1))
    c2w[1, 0, 3] = 1.0
    full = tmp_path / "images.txt"
    write_colmap(full, ["a", "b"], c2w)
    assert read_colmap(full).names == ["a", "b"]  # as written: two lines per image
    lines = full.read_text().splitlines()
    stripped = tmp_path / "no_points.txt"
    stripped.write_text("\n".join(x for x in lines if x.strip()) + "\n")
    twice = tmp_path / "twice.txt"
    image = next(x for x in lines if x and not x.startswith("#"))
    twice.write_text(full.read_text() + "99 " + image.split(" ", 1)[1] + "\n\n")
    for path, words in ((stripped, "POINTS2D"), (twice, "a/front.png is listed twice")):
        out = tmp_path / "out"
        argv = ["scene", "import", "--format", "colmap", str(path), "--out", str(out)]
        code, line = _run([*argv, "--images", *PHOTOS], capsys)
        assert code == 2 and words in line and str(path) in line and not out.exists()


def test_positions_near_the_float_limit_are_one_line_without_warnings(tmp_path, capsys):
    poses = tmp_path / "huge.txt"
    poses.write_text("0 0 0 0 0 0 0 1\n1 1e308 -1e308 1e308 0 0 0 1\n")
    out = tmp_path / "out"
    argv = ["scene", "import", "--format", "tum", str(poses), "--out", str(out)]
    try:
        from panogrf.app.cli import main

        code = main([*argv, "--images", *PHOTOS])
    except SystemExit as exc:
        code = int(exc.code or 0)
    err = capsys.readouterr().err
    assert code == 2 and not out.exists()
    assert "Warning" not in err and len(err.strip().splitlines()) == 1, err


def test_a_folder_as_a_camera_path_and_an_output_under_a_file_say_so(tmp_path, capsys):
    args = ["render", str(DEMO), "--method", "nearest"]
    code, line = _run([*args, "--camera-path", str(tmp_path), "--out", str(tmp_path / "v.mp4")],
                      capsys)  # fmt: skip
    assert code == 2 and line.endswith(f"{tmp_path}: a folder, not a camera path file")
    keep = tmp_path / "keep.mp4"
    keep.write_bytes(b"an older video")
    args += ["--height", "16", "--target-frame", "1"]
    code, line = _run([*args, "--out", str(keep / "x.png")], capsys)
    assert code == 2 and line.endswith(f"folder {keep} is a file, not a folder")
    assert keep.read_bytes() == b"an older video"


def test_a_process_that_loaded_colmap_ends_quietly_on_sigterm():
    """`timeout` or a service manager stopping a posing: no page of C++ stack trace from
    COLMAP's logging library, the signal's default end."""
    import subprocess
    import sys

    code = (
        "from panogrf.app.poses.colmap import load_pycolmap; load_pycolmap(); "
        "import os, signal; os.kill(os.getpid(), signal.SIGTERM)"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == -15 and run.stderr == ""


def test_a_photo_saved_again_with_fewer_colours_is_taken_from_one_spot(tmp_path, capsys):
    """A re-encoded copy moves its keypoints by a fifth of a degree at 512 columns: still one
    spot (the turn that fits the matches best, within half a pixel), not a pose 3 cm away or
    points behind a camera."""
    from PIL import Image

    photo = Image.open(PHOTOS[0]).convert("RGB")
    photo.save(tmp_path / "a.png")
    photo.convert("P").convert("RGB").save(tmp_path / "a_copy.png")
    out = tmp_path / "out"
    argv = ["scene", "from-panoramas", str(tmp_path / "a.png"), str(tmp_path / "a_copy.png")]
    code, line = _run([*argv, "--out", str(out)], capsys)
    assert code == 2 and "taken from one spot" in line and not out.exists()


def test_a_camera_path_or_a_scene_saved_with_a_byte_order_mark_is_read(tmp_path, capsys):
    """Windows editors save UTF-8 with a byte order mark: JSON files the user hands over are
    read with or without one."""
    import shutil

    from panogrf.app.paths.camera_path import read_camera_path
    from panogrf.app.scene.folder import load_scene

    scene = Path(shutil.copytree(DEMO, tmp_path / "scene"))
    text = (scene / "transforms.json").read_text(encoding="utf-8")
    (scene / "transforms.json").write_text("\ufeff" + text, encoding="utf-8")
    assert load_scene(scene).num_views == 3
    c2w = load_scene(scene).c2w[0].reshape(-1).tolist()
    path = {"camera_type": "equirectangular", "render_height": 16, "render_width": 32, "fps": 1,
            "seconds": 1, "camera_path": [{"camera_to_world": c2w}]}  # fmt: skip
    bom = tmp_path / "path.json"
    bom.write_text("\ufeff" + json.dumps(path), encoding="utf-8")
    assert len(read_camera_path(bom).poses) == 1


def test_a_panorama_of_a_few_pixels_is_too_small_to_pose(tmp_path, capsys):
    from panogrf.app.files.images import write_rgb

    tiny = tmp_path / "tiny.png"
    write_rgb(tiny, np.zeros((1, 2, 3), np.uint8))
    out = tmp_path / "out"
    code, line = _run(["scene", "from-panoramas", PHOTOS[0], str(tiny), "--out", str(out)], capsys)
    assert code == 2 and line.endswith(f"{tiny}: 2x1 is too small to pose (at least 64x32)")
