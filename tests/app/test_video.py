"""Video export: an MP4 that OpenCV opens with every frame, PNG folders, no half-written files."""

from __future__ import annotations

import os
import re
import subprocess
import time

import cv2
import numpy as np
import pytest
from helpers.disk import fill, tiny_tmpfs

from panogrf.app.errors import UserError
from panogrf.app.files.video import FrameSink


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


def _write_video(out, frames: int = 6, spherical: bool = False) -> None:
    with FrameSink(out, 24, 64, 32, spherical=spherical) as sink:
        for i in range(frames):
            sink.write(_frame(i))


def _top_boxes(path) -> list[bytes]:
    data, kinds, pos = path.read_bytes(), [], 0
    while pos < len(data):
        kinds.append(data[pos + 4 : pos + 8])
        pos += int.from_bytes(data[pos : pos + 4], "big")
    return kinds


def _ffmpeg_info(path) -> str:
    import imageio_ffmpeg

    done = subprocess.run(
        [imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(path)],
        capture_output=True,
        text=True,
    )
    return done.stderr


def test_mp4_is_shared_fast_start_and_spherical(tmp_path):
    old = os.umask(0o022)
    try:
        _write_video(tmp_path / "v.mp4", spherical=True)
        _write_video(tmp_path / "flat.mp4")
    finally:
        os.umask(old)
    out = tmp_path / "v.mp4"
    assert out.stat().st_mode & 0o777 == 0o644  # as the PNGs, not 0600
    kinds = _top_boxes(out)
    assert kinds.index(b"moov") < kinds.index(b"mdat")  # index first: plays while loading
    assert re.search(r"spherical[a-z ]*: equirectangular", _ffmpeg_info(out).lower())
    assert "spherical" not in _ffmpeg_info(tmp_path / "flat.mp4")
    cap = cv2.VideoCapture(str(out))  # chunk offsets moved with the larger index
    n = 0
    while cap.read()[0]:
        n += 1
    assert n == 6
    done = subprocess.run(
        [__import__("imageio_ffmpeg").get_ffmpeg_exe(), "-v", "error", "-i", str(out)]
        + ["-f", "null", "-"],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0 and done.stderr == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flat.mp4", "v.mp4"]


FAILING_FFMPEG = """#!/bin/sh
cat > /dev/null
echo "[out#0/mp4] Error writing trailer: No space left on device" >&2
exit 1
"""


def test_ffmpeg_failure_keeps_the_older_video(tmp_path, monkeypatch):
    import imageio_ffmpeg

    out = tmp_path / "v.mp4"
    _write_video(out)
    good = out.read_bytes()
    fake = tmp_path / "bin" / "ffmpeg"
    fake.parent.mkdir()
    fake.write_text(FAILING_FFMPEG)
    fake.chmod(0o755)
    monkeypatch.setattr(imageio_ffmpeg, "get_ffmpeg_exe", lambda: str(fake))
    for spherical in (False, True):
        with pytest.raises(UserError, match="ffmpeg failed writing .*No space left on device"):
            _write_video(out, spherical=spherical)
        assert out.read_bytes() == good
        assert sorted(p.name for p in tmp_path.iterdir()) == ["bin", "v.mp4"]


def test_really_full_disk_keeps_the_older_video(tmp_path):
    with tiny_tmpfs(tmp_path / "disk", "256k") as disk:
        out = disk / "v.mp4"
        _write_video(out, frames=2)
        good = out.read_bytes()
        fill(disk)
        rng = np.random.default_rng(0)
        with pytest.raises(UserError, match="No space left"):
            with FrameSink(out, 24, 64, 32) as sink:
                for _ in range(40):  # noise does not compress: more than the disk holds
                    sink.write(rng.integers(0, 256, (32, 64, 3), dtype=np.uint8))
        assert out.read_bytes() == good
        assert sorted(p.name for p in disk.iterdir()) == ["ballast", "v.mp4"]


def test_out_naming_a_folder_is_refused_before_the_work(tmp_path):
    (tmp_path / "v.mp4").mkdir()
    with pytest.raises(UserError, match="is a folder"):
        FrameSink(tmp_path / "v.mp4", 24, 64, 32)
    assert [p.name for p in tmp_path.iterdir()] == ["v.mp4"]


def test_frames_folder_holds_only_the_latest_render(tmp_path):
    out = tmp_path / "frames"
    with FrameSink(out, 30, 64, 32) as sink:
        for i in range(5):
            sink.write(_frame(i))
    with FrameSink(out, 30, 64, 32) as sink:
        for i in range(2):
            sink.write(_frame(i))
    assert sorted(p.name for p in out.iterdir()) == ["frame_00000.png", "frame_00001.png"]
    with pytest.raises(RuntimeError):
        with FrameSink(out, 30, 64, 32) as sink:
            sink.write(_frame(0))
            raise RuntimeError("interrupted")
    assert sorted(p.name for p in out.iterdir()) == ["frame_00000.png", "frame_00001.png"]
    assert [p.name for p in tmp_path.iterdir()] == ["frames"]
    (out / "notes.txt").write_text("mine")
    with pytest.raises(UserError, match="holds other files than frames"):
        FrameSink(out, 30, 64, 32)


_KILLED_EXPORT = """
import sys
import numpy as np
from pathlib import Path
from panogrf.app.files.video import FrameSink
with FrameSink(Path(sys.argv[1]), 24, 64, 32, spherical=True) as sink:
    for i in range(3):
        sink.write(np.zeros((32, 64, 3), np.uint8))
    print("ready", flush=True)
    sys.stdin.read()
"""


def test_kill_9_during_export_keeps_the_older_video_and_the_next_export_sweeps(tmp_path):
    import signal
    import sys

    out = tmp_path / "v.mp4"
    _write_video(out)
    good = out.read_bytes()
    proc = subprocess.Popen(
        [sys.executable, "-c", _KILLED_EXPORT, str(out)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout.readline() == "ready\n"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    time.sleep(0.5)  # ffmpeg sees its input close and exits
    assert out.read_bytes() == good
    assert len(list(tmp_path.iterdir())) > 1  # the killed export's temporaries
    _write_video(out, frames=2)
    assert [p.name for p in tmp_path.iterdir()] == ["v.mp4"]
