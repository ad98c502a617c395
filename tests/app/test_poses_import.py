"""`panogrf scene import`: TUM, OpenSfM and COLMAP round trips, and bad pose files."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from panogrf.app import cli
from panogrf.app.errors import UserError
from panogrf.app.files.images import write_rgb
from panogrf.app.poses import errors as er
from panogrf.app.poses import importers as im
from panogrf.app.scene.folder import load_scene

H, W = 16, 32


@pytest.fixture(autouse=True)
def only_scene_command(monkeypatch):
    monkeypatch.setattr(cli, "_COMMANDS", ("scene", "eval"))


def _poses(tilted_world: bool = True) -> np.ndarray:
    """Three level cameras (c2w, OpenGL, y up), then seen in a tool's arbitrary world frame."""
    rng = np.random.default_rng(0)
    c2w = np.stack([np.eye(4)] * 3)
    for k in range(3):
        c2w[k, :3, :3] = Rotation.from_euler("y", rng.uniform(0, 360), degrees=True).as_matrix()
        c2w[k, :3, 3] = [0.8 * k, 1.5, 0.3 * k]
    if tilted_world:  # e.g. a SLAM world with y down, or OpenSfM's z up
        world = np.eye(4)
        world[:3, :3] = Rotation.from_rotvec([1.9, 0.4, -0.7]).as_matrix()
        world[:3, 3] = [3.0, -1.0, 2.0]
        c2w = world @ c2w
    return c2w


def _panoramas(folder, names):
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(1)
    paths = []
    for name in names:
        write_rgb(folder / f"{name}.png", rng.integers(0, 255, (H, W, 3), dtype=np.uint8))
        paths.append(folder / f"{name}.png")
    return paths


def _check(out, truth, distance=None):
    scene = load_scene(out)
    est = scene.c2w
    errors = er.pair_errors(est, truth)
    assert max(e["rotation_deg"] for e in errors) < 1e-4
    assert max(e["translation_deg"] for e in errors) < 1e-4
    np.testing.assert_allclose(est[:, :3, 1] @ [0, 1, 0], 1.0, atol=1e-9)  # levelled
    if distance is not None:
        assert abs(np.linalg.norm(est[0, :3, 3] - est[2, :3, 3]) - distance) < 1e-6


@pytest.mark.parametrize("fmt", ["tum", "opensfm", "colmap"])
def test_round_trip_through_each_format(tmp_path, fmt, capsys):
    c2w = _poses()
    names = ["a", "b", "c"]
    paths = _panoramas(tmp_path / "images", names)
    if fmt == "tum":
        pose_file = tmp_path / "keyframe_trajectory.txt"
        im.write_tum(pose_file, c2w)
        images = [str(p) for p in paths]
    elif fmt == "opensfm":
        pose_file = tmp_path / "reconstruction.json"
        im.write_opensfm(pose_file, [f"{n}.png" for n in names], c2w, W, H)
        images = []  # found in images/ beside the JSON
    else:
        pose_file = tmp_path / "images.txt"
        im.write_colmap(pose_file, names, c2w)
        images = [str(p) for p in paths[::-1]]  # matched by name, any order
    out = tmp_path / "scene"
    args = ["scene", "import", "--format", fmt, str(pose_file), "--out", str(out)]
    args += ["--images", *images] if images else []
    assert cli.main([*args, "--distance", "0,2=2.5"]) == 0
    assert "levelled" in capsys.readouterr().out
    truth = _poses(tilted_world=False)
    _check(out, truth[::-1] if fmt == "colmap" else truth, distance=2.5)  # --images order


def test_readers_agree_with_the_conventions():
    c2w = _poses(tilted_world=False)
    # TUM stores camera-to-world in the OpenCV camera frame: y down, looking down +z.
    m = c2w[0]
    q = Rotation.from_matrix(m[:3, :3] @ np.diag([1, -1, -1])).as_quat()
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "t.txt"
        path.write_text("0 " + " ".join(map(str, (*m[:3, 3], *q))) + "\n")
        np.testing.assert_allclose(im.read_tum(path).c2w[0], m, atol=1e-12)
        # OpenSfM: world-to-camera axis-angle and translation
        rot_w2c = (m[:3, :3] @ np.diag([1, -1, -1])).T
        shot = {
            "camera": "c",
            "rotation": Rotation.from_matrix(rot_w2c).as_rotvec().tolist(),
            "translation": (-rot_w2c @ m[:3, 3]).tolist(),
        }
        rec = [{"cameras": {"c": {"projection_type": "equirectangular"}}, "shots": {"x.jpg": shot}}]
        path = Path(d) / "r.json"
        path.write_text(json.dumps(rec))
        np.testing.assert_allclose(im.read_opensfm(path).c2w[0], m, atol=1e-12)


@pytest.mark.parametrize(
    ("fmt", "text", "message"),
    [
        ("tum", "0 1 2 3\n", "expected 'timestamp"),
        ("tum", "0 0 0 0 0 0 0 2\n", "not unit length"),
        ("opensfm", "{oops", "not JSON"),
        (
            "opensfm",
            '[{"cameras": {"c": {"projection_type": "perspective"}}, "shots": '
            '{"a.jpg": {"camera": "c", "rotation": [0,0,0], "translation": [0,0,0]}}}]',
            "spherical",
        ),
        ("colmap", "1 1 0 0 0 0 0 0 1 photo.jpg\n\n", "no image named"),
        # issue 57, T8-T9: each was a traceback
        ("colmap", "1 0 0 0 0 0 0 0 1 a/front.png\n\n", "not unit length"),
        ("colmap", "1 nan 0 0 0 0 0 0 1 a/front.png\n\n", "finite"),
        ("colmap", "1 1 0 0 0 0 0 inf 1 a/front.png\n\n", "finite"),
        (
            "opensfm",
            '[{"cameras": {"pano": "spherical"}, "shots": '
            '{"a.jpg": {"camera": "pano", "rotation": [0,0,0], "translation": [0,0,0]}}}]',
            "is not an object",
        ),
        ("opensfm", '[{"cameras": {}, "shots": [["a.jpg"]]}]', "objects keyed by name"),
    ],
)
def test_bad_pose_files_are_one_line_errors_naming_the_file(tmp_path, capsys, fmt, text, message):
    pose_file = tmp_path / "poses.txt"
    pose_file.write_text(text)
    paths = _panoramas(tmp_path, ["a", "b"])
    args = ["scene", "import", "--format", fmt, str(pose_file), "--out", str(tmp_path / "s")]
    assert cli.main([*args, "--images", *map(str, paths)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(pose_file) in err and message in err


def test_import_count_mismatch(tmp_path, capsys):
    pose_file = tmp_path / "t.txt"
    im.write_tum(pose_file, _poses())
    paths = _panoramas(tmp_path, ["a", "b"])
    args = ["scene", "import", "--format", "tum", str(pose_file), "--out", str(tmp_path / "s")]
    assert cli.main([*args, "--images", *map(str, paths)]) == 2
    assert "3 poses but 2 --images" in capsys.readouterr().err
    with pytest.raises(UserError):
        im.read_poses("bogus", pose_file)


@pytest.mark.parametrize("how", ["duplicate", "tiny scale"])
def test_import_never_writes_a_scene_its_check_rejects(tmp_path, capsys, how):
    """Issue 57 S3: duplicate poses, or a --scale that puts every view within a millimetre,
    were written as a scene that `scene check` then refused."""
    c2w = _poses()
    extra = []
    if how == "duplicate":
        c2w[2] = c2w[1]
    else:
        extra = ["--scale", "1e-6"]
    pose_file = tmp_path / "t.txt"
    im.write_tum(pose_file, c2w)
    paths = _panoramas(tmp_path / "images", ["a", "b", "c"])
    out = tmp_path / "s"
    args = ["scene", "import", "--format", "tum", str(pose_file), "--out", str(out)]
    assert cli.main([*args, "--images", *map(str, paths), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "views at the same position" in err[0], err
    assert not (out / "transforms.json").exists()
