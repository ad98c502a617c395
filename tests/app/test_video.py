"""Video export: an MP4 that OpenCV opens with every frame, PNG folders, no half-written files."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from panogrf.app.errors import UserError
from panogrf.app.video import FrameSink


def _frame(i: int, w: int = 64, h: int = 32) -> np.ndarray:
    f = np.zeros((h, w, 3), np.uint8)
    f[:, : (i * 4) % w] = (200, 40, 90)
    return f


def test_mp4_opens_with_the_frame_count_and_size(tmp_path):
    out = tmp_path / "v.mp4"
    with FrameSink(out, 24, 64, 32) as sink:
        for i in range(12):
            sink.write(_frame(i))
    cap = cv2.VideoCapture(str(out))
    assert cap.isOpened()
    n = 0
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        assert frame.shape == (32, 64, 3)
        n += 1
    assert n == 12
    assert cap.get(cv2.CAP_PROP_FPS) == pytest.approx(24, abs=0.1)
    assert [p.name for p in tmp_path.iterdir()] == ["v.mp4"]


def test_interrupted_video_leaves_nothing_under_the_final_name(tmp_path):
    out = tmp_path / "v.mp4"
    with pytest.raises(KeyboardInterrupt):
        with FrameSink(out, 24, 64, 32) as sink:
            sink.write(_frame(0))
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_png_folder_and_errors(tmp_path):
    with FrameSink(tmp_path / "frames", 30, 64, 32) as sink:
        for i in range(3):
            sink.write(_frame(i))
    assert sorted(p.name for p in (tmp_path / "frames").iterdir()) == [
        "frame_00000.png",
        "frame_00001.png",
        "frame_00002.png",
    ]
    with pytest.raises(UserError, match="even"):
        FrameSink(tmp_path / "odd.mp4", 30, 63, 32)
    with pytest.raises(UserError, match="does not exist"):
        FrameSink(tmp_path / "no" / "v.mp4", 30, 64, 32)
    with pytest.raises(UserError, match=".mp4"):
        FrameSink(tmp_path / "v.avi", 30, 64, 32)
    with FrameSink(tmp_path / "w.mp4", 30, 64, 32) as sink, pytest.raises(ValueError):
        sink.write(np.zeros((10, 10, 3), np.uint8))
