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


def test_a_photo_named_like_a_hidden_file_and_a_copy_at_another_size(tmp_path, capsys):
    """A photo named ``.jpg`` gives its view a plain name instead of a traceback; one photo
    twice (a copy at another size) is named, file by file, as posed at one spot."""
    from PIL import Image

    hidden = tmp_path / "v" / ".jpg"
    hidden.parent.mkdir()
    hidden.write_bytes((PAIR / "studio_small_07.jpg").read_bytes())
    out = tmp_path / "a"
    assert cli.main(["scene", "from-panoramas", str(PAIR / "studio_small_03.jpg"), str(hidden),
                     "--out", str(out), "--quiet"]) == 0  # fmt: skip
    assert [f.name for f in load_scene(out).frames] == ["view_000", "view_001"]
    copy = tmp_path / "studio_03_large.jpg"
    Image.open(PAIR / "studio_small_03.jpg").resize((2048, 1024), Image.BICUBIC).save(copy)
    photos = [str(PAIR / "studio_small_03.jpg"), str(copy), str(PAIR / "studio_small_07.jpg")]
    capsys.readouterr()
    assert cli.main(["scene", "from-panoramas", *photos, "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "studio_small_03.jpg" in err and "studio_03_large.jpg" in err
    assert "posed at one spot" in err and "frames[" not in err


def test_a_left_out_photo_does_not_set_the_scenes_size():
    from panogrf.app.commands.scene_poses import _at_smallest

    rng = np.random.default_rng(0)
    big = [rng.integers(0, 256, (64, 128, 3), dtype=np.uint8) for _ in range(2)]
    thumb = rng.integers(0, 256, (8, 16, 3), dtype=np.uint8)
    read = _at_smallest([big[0], thumb, big[1]])
    assert read.images.shape == (3, 3, 8, 16) and read.resized == [True, False, True]
    kept = read.kept(np.array([0, 2]))
    assert kept.images.shape == (2, 3, 64, 128) and kept.resized == [False, False]
    assert np.array_equal(kept.images[1], big[1].transpose(2, 0, 1))


def test_a_failed_write_leaves_nothing_behind(tmp_path, monkeypatch):
    """A scene that cannot be written whole (a full disk) is removed again: the same command
    can run again (it refuses a folder that is not empty)."""
    import errno

    from panogrf.app.errors import UserError
    from panogrf.app.scene import folder

    def half(root, *args, **kwargs):
        (root / "images").mkdir(parents=True)
        (root / "images" / "a.jpg").write_bytes(b"x")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(folder, "write_scene", half)
    for out in (tmp_path / "new", tmp_path / "empty"):
        if out.name == "empty":
            out.mkdir()
        with pytest.raises(UserError, match="No space left on device"):
            folder.write_new_scene(out, None, None)
        assert not out.exists() or not any(out.iterdir())
    assert (tmp_path / "empty").is_dir()  # the user's own (empty) folder stays
