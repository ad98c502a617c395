"""`panogrf scene from-panoramas` on a real pair of 360° photographs (`tests/data/real_pair`,
CC0): a small studio with a bare white floor and its lights moved between the shots."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from panogrf.app import cli
from panogrf.app.scene.folder import load_scene

PAIR = Path(__file__).parents[1] / "data" / "real_pair"


@pytest.fixture(autouse=True)
def only_needed_commands(monkeypatch):
    monkeypatch.setattr(cli, "_COMMANDS", ("scene",))


def test_a_real_pair_poses_level_with_a_consistent_report(tmp_path, capsys):
    images = [str(PAIR / "studio_small_03.jpg"), str(PAIR / "studio_small_07.jpg")]
    out = tmp_path / "studio"
    assert cli.main(["scene", "from-panoramas", *images, "--out", str(out)]) == 0
    report = capsys.readouterr().out
    assert "nan" not in report.lower()
    saved = json.loads((out / "poses_report.json").read_text())
    (pair,) = saved["pairs"]
    assert pair["ok"] and 30 <= pair["inliers"] <= pair["matches"]
    assert math.isfinite(pair["median_residual_deg"]) and pair["median_residual_deg"] < 1.0
    assert all(v["registered"] for v in saved["views"])
    c2w = load_scene(out).c2w
    # Poly Haven levels its panoramas: both cameras stay level (their up axis is the world's),
    # though a floor plane fitted to the few points on the bare floor is tilted by degrees.
    tilt = np.degrees(np.arccos(np.clip(c2w[:, 1, 1], -1, 1)))
    assert tilt.max() < 1.0, (tilt, saved["scale"])
    # The lights moved, the camera a step: a small turn, a small horizontal move.
    rel = c2w[0, :3, :3].T @ c2w[1, :3, :3]
    turn = np.degrees(np.arccos(np.clip((np.trace(rel) - 1) / 2, -1, 1)))
    assert turn < 5.0
    move = c2w[1, :3, 3] - c2w[0, :3, 3]
    assert 0.0 < np.linalg.norm(move) < 1.0
    assert abs(move[1]) < 0.2 * np.linalg.norm(move)
    assert cli.main(["scene", "check", str(out)]) == 0
    # The photographs are kept as they were taken (copied, not re-encoded as PNG).
    for photo, frame in zip(images, load_scene(out).frames, strict=True):
        assert frame.image_path.suffix == ".jpg"
        assert frame.image_path.read_bytes() == Path(photo).read_bytes()


def _refused(capsys, args: list[str], *names: str) -> str:
    assert cli.main(args) == 2
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if not x.startswith("posing: ")]  # progress lines
    assert len(lines) == 1 and "Traceback" not in err, err
    assert all(name in lines[0] for name in names), lines[0]
    return lines[0]


def test_scales_that_make_no_scene_are_refused_naming_the_option(tmp_path, capsys):
    images = [str(PAIR / "studio_small_03.jpg"), str(PAIR / "studio_small_07.jpg")]
    for option, value, says in (
        ("--camera-height", "0.01", "same position"),  # the views 0.6 mm apart
        ("--distance", "0,1=1e30", "farther than"),
        ("--distance", "0,1=1e308", "NaN or infinite"),
    ):
        out = tmp_path / f"s{option}{value}"
        argv = ["scene", "from-panoramas", *images, "--out", str(out), option, value, "--quiet"]
        _refused(capsys, argv, option, value, says)
        assert not out.exists()


def test_an_empty_photo_and_a_folder_with_files_are_refused_in_one_line(tmp_path, capsys):
    empty = tmp_path / "empty.jpg"
    empty.write_bytes(b"")
    real = str(PAIR / "studio_small_03.jpg")
    out = ["--out", str(tmp_path / "s"), "--quiet"]
    _refused(capsys, ["scene", "from-panoramas", real, str(empty), *out], str(empty), "empty")
    kept = tmp_path / "mine" / "images" / "studio_small_03.png"
    kept.parent.mkdir(parents=True)
    kept.write_text("precious")
    argv = ["scene", "from-panoramas", real, str(PAIR / "studio_small_07.jpg"), "--out"]
    _refused(capsys, [*argv, str(tmp_path / "mine"), "--quiet"], "not empty")
    assert kept.read_text() == "precious"


def test_a_turned_copy_of_a_photo_is_diagnosed_as_no_parallax(tmp_path, capsys):
    import cv2

    photo = PAIR / "studio_small_03.jpg"
    turned = tmp_path / "turned.jpg"  # the same spot, the camera turned by 90 degrees
    cv2.imwrite(str(turned), np.roll(cv2.imread(str(photo)), 256, axis=1))
    argv = ["scene", "from-panoramas", str(photo), str(turned), "--out", str(tmp_path / "s")]
    line = _refused(capsys, [*argv, "--quiet"], str(turned), "no parallax", "apart")
    assert "a photo between the two" not in line


def test_photos_of_two_sizes_pose_at_the_smaller(tmp_path, capsys):
    """A photo from another camera (here: one of the pair at twice the size) no longer stops
    the scene: it is area-averaged to the smaller one's size, said in the report, and written
    as PNG; the other is kept as it is."""
    from PIL import Image

    large = tmp_path / "studio_07_large.jpg"
    Image.open(PAIR / "studio_small_07.jpg").resize((2048, 1024), Image.BICUBIC).save(large)
    small = PAIR / "studio_small_03.jpg"
    out = tmp_path / "studio"
    assert cli.main(["scene", "from-panoramas", str(small), str(large), "--out", str(out)]) == 0
    report = capsys.readouterr().out
    assert "resized to the smallest photo's 1024x512: studio_07_large.jpg" in report
    scene = load_scene(out)
    assert (scene.width, scene.height) == (1024, 512)
    kept, resized = (f.image_path for f in scene.frames)
    assert kept.read_bytes() == small.read_bytes()
    assert resized.suffix == ".png"
    assert cli.main(["scene", "check", str(out)]) == 0
