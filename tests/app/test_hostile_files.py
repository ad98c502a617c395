"""Hostile files found by a pass over today's paths: each gets one line naming the file or field,
a non-zero exit, and no work beyond reading its header."""

from __future__ import annotations

import io
import json
import shutil
import zlib

import numpy as np
import pytest
from PIL import Image

from panogrf.app import cli
from panogrf.app.files.atomic import parse_json
from panogrf.app.files.images import ImageReadError, read_rgb
from panogrf.app.scene.check import check_scene
from panogrf.assets import path as asset_path

DEMO = asset_path("demo")


def _scene(tmp_path, edit):
    root = tmp_path / "scene"
    shutil.copytree(DEMO, root)
    path = root / "transforms.json"
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))
    return root


def test_an_integer_of_thousands_of_digits_is_a_problem_not_a_traceback(tmp_path, capsys):
    assert parse_json("[" + "9" * 5000 + ", -" + "9" * 5000 + ", 12]") == [
        float("inf"),
        float("-inf"),
        12,
    ]
    root = tmp_path / "scene"
    shutil.copytree(DEMO, root)
    path = root / "transforms.json"
    path.write_text(path.read_text().replace('"w": 512', '"w": ' + "9" * 5000, 1))
    assert cli.main(["scene", "check", str(root)]) == 1
    assert "w must be a positive integer, got inf" in capsys.readouterr().out


def test_a_bad_nadir_cap_in_the_scene_is_found_by_scene_check(tmp_path):
    for value, reason in (("abc", "expected 'auto', 'off' or degrees"), (500, "[0, 90)")):
        root = _scene(tmp_path / str(value), lambda d, v=value: d.update(nadir_mask_deg=v))
        problems = check_scene(root)
        assert len(problems) == 1 and "nadir_mask_deg" in problems[0] and reason in problems[0]


def test_many_views_at_one_position_are_counted_not_all_listed(tmp_path):
    root = _scene(tmp_path, lambda d: d.update(frames=d["frames"] * 10))  # 30 views, 3 places
    problems = [p for p in check_scene(root) if "same position" in p]
    assert problems[0].startswith("135 pairs of frames are at the same position")
    assert len(problems) == 21


def test_two_frames_reading_one_panorama_are_a_problem(tmp_path):
    def edit(data):
        data["frames"][1]["file_path"] = "./" + data["frames"][0]["file_path"]

    problems = check_scene(_scene(tmp_path, edit))
    assert len(problems) == 1, problems
    assert problems[0].startswith("frames[0] and frames[1] both read ")
    copies = [
        p
        for p in check_scene(_scene(tmp_path / "b", lambda d: d.update(frames=d["frames"] * 10)))
        if "both read" in p or "read a panorama" in p
    ]
    assert copies[0] == "27 frames read a panorama another frame reads; the first follow"
    assert len(copies) == 21


def _png_declaring(width: int, height: int) -> bytes:
    """A valid PNG header and a few bytes of data for a grey image of that size."""
    good = io.BytesIO()
    Image.new("L", (1, 1)).save(good, "PNG")
    raw = good.getvalue()
    ihdr = width.to_bytes(4, "big") + height.to_bytes(4, "big") + raw[24:29]
    chunk = b"IHDR" + ihdr
    return raw[:8] + raw[8:12] + chunk + zlib.crc32(chunk).to_bytes(4, "big") + raw[33:]


def test_an_image_declaring_a_huge_size_is_refused_before_decoding(tmp_path):
    path = tmp_path / "bomb.png"
    path.write_bytes(_png_declaring(40000, 20000))
    with pytest.raises(ImageReadError, match=r"bomb\.png: too large"):
        read_rgb(path)
    ok = tmp_path / "ok.png"
    Image.fromarray(np.zeros((8, 16, 3), np.uint8)).save(ok)
    assert read_rgb(ok).shape == (8, 16, 3)


def test_a_truncated_png_is_one_named_problem_without_libpngs_own_line(tmp_path, capfd):
    path = tmp_path / "cut.png"
    Image.fromarray(np.random.default_rng(0).integers(0, 255, (64, 128, 3), np.uint8)).save(path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ImageReadError, match=r"cut\.png: corrupt or truncated PNG"):
        read_rgb(path)
    assert "libpng" not in capfd.readouterr().err


def test_a_file_outside_the_scene_folder_is_refused_like_an_absolute_path(tmp_path):
    def edit(data):
        data["frames"][0]["file_path"] = "../scene/" + data["frames"][0]["file_path"]

    problems = check_scene(_scene(tmp_path, edit))
    assert len(problems) == 1 and "must stay inside the scene folder" in problems[0], problems
    inside = _scene(
        tmp_path / "b",
        lambda d: d["frames"][0].update(file_path="images/../" + d["frames"][0]["file_path"]),
    )
    assert check_scene(inside) == []
