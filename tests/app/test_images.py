"""Image and depth files: conversions, refusals with clear messages, atomic writes."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from panogrf.app.errors import UserError
from panogrf.app.files.images import (
    ImageReadError,
    read_depth,
    read_rgb,
    read_rgb_with_notes,
    write_depth,
    write_json_atomic,
    write_rgb,
)


@pytest.fixture
def rng():
    return np.random.default_rng(0)


def test_rgb_round_trip_is_lossless_png(tmp_path, rng):
    img = rng.integers(0, 256, (16, 32, 3), dtype=np.uint8)
    write_rgb(tmp_path / "a.png", img)
    back, notes = read_rgb_with_notes(tmp_path / "a.png")
    assert back.dtype == np.uint8 and back.shape == (16, 32, 3)
    np.testing.assert_array_equal(back, img)
    assert notes == []


def test_rgb_channel_order_is_rgb(tmp_path):
    img = np.zeros((16, 32, 3), np.uint8)
    img[..., 0] = 200  # red
    write_rgb(tmp_path / "red.png", img)
    # OpenCV stores BGR: a red pixel is (0, 0, 200) in the file's decoded BGR order.
    assert tuple(cv2.imread(str(tmp_path / "red.png"))[0, 0]) == (0, 0, 200)
    assert tuple(read_rgb(tmp_path / "red.png")[0, 0]) == (200, 0, 0)


def test_write_rgb_float_is_rounded(tmp_path):
    img = np.full((16, 32, 3), 0.5, np.float32)
    img[0, 0] = (-1.0, 2.0, 1.0 / 255.0)
    write_rgb(tmp_path / "f.png", img)
    back = read_rgb(tmp_path / "f.png")
    assert back[1, 1, 0] == 128 and tuple(back[0, 0]) == (0, 255, 1)


def test_gray_is_converted_with_note(tmp_path, rng):
    gray = rng.integers(0, 256, (16, 32), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "g.png"), gray)
    img, notes = read_rgb_with_notes(tmp_path / "g.png")
    assert img.shape == (16, 32, 3)
    np.testing.assert_array_equal(img[..., 1], gray)
    assert notes == ["grayscale converted to RGB"]


def test_opaque_rgba_drops_alpha(tmp_path, rng):
    bgra = rng.integers(0, 256, (16, 32, 4), dtype=np.uint8)
    bgra[..., 3] = 255
    cv2.imwrite(str(tmp_path / "o.png"), bgra)
    img, notes = read_rgb_with_notes(tmp_path / "o.png")
    np.testing.assert_array_equal(img, bgra[..., 2::-1])
    assert notes == ["opaque alpha channel dropped"]


def test_transparent_rgba_is_refused(tmp_path):
    bgra = np.full((16, 32, 4), 255, np.uint8)
    bgra[:4, :, 3] = 0
    cv2.imwrite(str(tmp_path / "t.png"), bgra)
    with pytest.raises(ImageReadError, match=r"t\.png: alpha channel is not fully opaque \(25\.0%"):
        read_rgb(tmp_path / "t.png")


def test_16_bit_is_rounded_to_8_bit(tmp_path):
    bgr16 = np.zeros((16, 32, 3), np.uint16)
    bgr16[0, 0] = (65535, 257 * 100 + 128, 128)  # 255, 100.5 -> 100 or 101, 0.498 -> 0
    bgr16[0, 1] = (257 * 7, 0, 129)  # 7, 0, 0.502 -> 1
    cv2.imwrite(str(tmp_path / "h.png"), bgr16)
    img, notes = read_rgb_with_notes(tmp_path / "h.png")
    assert img.dtype == np.uint8
    assert tuple(img[0, 0]) in ((0, 100, 255), (0, 101, 255))
    assert tuple(img[0, 1]) == (1, 0, 7)
    assert notes == ["16-bit converted to 8-bit"]


def test_missing_and_unreadable_files_name_the_file(tmp_path):
    with pytest.raises(UserError, match=r"nope\.png: file not found"):
        read_rgb(tmp_path / "nope.png")
    (tmp_path / "junk.png").write_bytes(b"not an image at all")
    with pytest.raises(ImageReadError, match=r"junk\.png: not a readable image") as info:
        read_rgb(tmp_path / "junk.png")
    assert info.value.path == tmp_path / "junk.png"
    assert info.value.reason.startswith("not a readable image")


def test_writes_are_atomic_and_leave_no_temp_files(tmp_path, rng):
    path = tmp_path / "a.png"
    write_rgb(path, np.zeros((16, 32, 3), np.uint8))
    write_rgb(path, np.full((16, 32, 3), 9, np.uint8))  # overwrite in place
    write_depth(tmp_path / "d.png", np.ones((16, 32)))
    write_json_atomic(tmp_path / "x.json", {"m": [[1, 2], [3, 4]]})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "d.png", "x.json"]
    assert read_rgb(path)[0, 0, 0] == 9
    assert json.loads((tmp_path / "x.json").read_text()) == {"m": [[1, 2], [3, 4]]}


def test_failed_write_keeps_the_old_file(tmp_path, monkeypatch):
    path = tmp_path / "a.png"
    write_rgb(path, np.full((16, 32, 3), 3, np.uint8))

    def crash(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr("panogrf.app.files.images.os.replace", crash)
    with pytest.raises(OSError, match="disk full"):
        write_rgb(path, np.full((16, 32, 3), 7, np.uint8))
    monkeypatch.undo()
    assert read_rgb(path)[0, 0, 0] == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png"]  # temp file removed
    with pytest.raises(ValueError, match="not JSON compliant"):
        write_json_atomic(tmp_path / "a.json", {"x": float("nan")})
    with pytest.raises(ValueError, match=r"\[H, W, 3\]"):
        write_rgb(path, np.zeros((16, 32), np.uint8))


def test_depth_round_trip_in_millimetres(tmp_path, rng):
    depth = rng.uniform(0.1, 20.0, (16, 32))
    depth[0, :4] = (0.0, -1.0, np.nan, np.inf)  # unknown
    depth[1, 0] = 100.0  # beyond 65.535 m: clipped
    write_depth(tmp_path / "d.png", depth)
    raw = cv2.imread(str(tmp_path / "d.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw.ndim == 2
    back = read_depth(tmp_path / "d.png")
    assert back.dtype == np.float32 and back.shape == (16, 32)
    assert np.all(back[0, :4] == 0.0)
    assert back[1, 0] == pytest.approx(65.535)
    ok = np.isfinite(depth) & (depth > 0) & (depth < 65)
    np.testing.assert_allclose(back[ok], depth[ok], atol=0.0005 + 1e-6)


def test_depth_must_be_16_bit_single_channel(tmp_path):
    cv2.imwrite(str(tmp_path / "d8.png"), np.ones((16, 32), np.uint8))
    with pytest.raises(ImageReadError, match=r"d8\.png: expected a single-channel 16-bit PNG"):
        read_depth(tmp_path / "d8.png")
    cv2.imwrite(str(tmp_path / "d3.png"), np.ones((16, 32, 3), np.uint16))
    with pytest.raises(ImageReadError, match="got 3-channel uint16"):
        read_depth(tmp_path / "d3.png")
    with pytest.raises(ValueError, match=r"\.png"):
        write_depth(tmp_path / "d.jpg", np.ones((16, 32)))


def _jpeg(rng, params=()) -> bytes:
    img = rng.integers(0, 256, (32, 64, 3), dtype=np.uint8)
    ok, buf = cv2.imencode(".jpg", img, list(params))
    assert ok
    return buf.tobytes()


@pytest.mark.parametrize("params", [(), (cv2.IMWRITE_JPEG_PROGRESSIVE, 1)])
def test_truncated_jpeg_is_refused_with_the_file_named(tmp_path, rng, params):
    data = _jpeg(rng, params)
    (tmp_path / "whole.jpg").write_bytes(data + b"\0" * 16)  # trailing bytes are harmless
    assert read_rgb(tmp_path / "whole.jpg").shape == (32, 64, 3)
    for cut in (len(data) // 2, len(data) - 2):
        (tmp_path / "cut.jpg").write_bytes(data[:cut])
        with pytest.raises(ImageReadError, match=r"cut\.jpg: truncated JPEG"):
            read_rgb(tmp_path / "cut.jpg")
