"""The one atomic writer: the older file survives errors, full disks and kill -9; temporaries of
our own naming are swept by the next write into the same folder."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import time

import pytest
from helpers.disk import fill, tiny_tmpfs

from panogrf.app.errors import UserError
from panogrf.app.files import atomic
from panogrf.app.files.atomic import (
    atomic_output,
    check_output,
    nan_to_null,
    sweep_stale,
    temp_path,
    write_bytes_atomic,
    write_json_atomic,
)


def test_temporary_name_is_recognisable_and_keeps_the_suffix(tmp_path):
    tmp = temp_path(tmp_path / "v.mp4")
    assert tmp.parent == tmp_path and tmp.name.startswith(".v.mp4.") and tmp.suffix == ".mp4"
    assert atomic._OURS.match(tmp.name)


def test_error_keeps_the_older_file_and_leaves_no_temporary(tmp_path):
    out = tmp_path / "a.bin"
    write_bytes_atomic(out, b"old")
    with pytest.raises(RuntimeError):
        with atomic_output(out) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("boom")
    assert out.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["a.bin"]


def test_full_disk_keeps_the_older_file(tmp_path, monkeypatch):
    out = tmp_path / "a.json"
    write_json_atomic(out, {"v": 1})

    def full(fd):  # where a full disk shows on NFS and with delayed allocation
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OSError, match="No space"):
        write_json_atomic(out, {"v": 2})
    monkeypatch.undo()
    assert out.read_text() == '{\n  "v": 1\n}\n'
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]


def test_really_full_disk_keeps_the_older_file(tmp_path):
    with tiny_tmpfs(tmp_path / "disk") as disk:
        out = disk / "a.bin"
        write_bytes_atomic(out, b"old")
        fill(disk)
        with pytest.raises(OSError, match="No space"):
            write_bytes_atomic(out, b"x" * 100_000)
        assert out.read_bytes() == b"old"
        assert sorted(p.name for p in disk.iterdir()) == ["a.bin", "ballast"]


def test_files_follow_the_umask(tmp_path):
    old = os.umask(0o022)
    try:
        write_bytes_atomic(tmp_path / "a.bin", b"x")
    finally:
        os.umask(old)
    assert (tmp_path / "a.bin").stat().st_mode & 0o777 == 0o644


_KILLED_WRITER = """
import sys, time
from panogrf.app.files.atomic import atomic_output
with atomic_output(sys.argv[1], directory=sys.argv[2] == "dir") as tmp:
    if sys.argv[2] == "dir":
        (tmp / "frame_00000.png").write_bytes(b"new")
    else:
        tmp.write_bytes(b"half written")
    print("ready", flush=True)
    time.sleep(60)
"""


@pytest.mark.parametrize("kind", ["file", "dir"])
def test_kill_9_keeps_the_older_output_and_the_next_write_sweeps(tmp_path, kind):
    out = tmp_path / ("frames" if kind == "dir" else "a.bin")
    if kind == "dir":
        out.mkdir()
        (out / "frame_00000.png").write_bytes(b"old")
    else:
        out.write_bytes(b"old")
    proc = subprocess.Popen(
        [sys.executable, "-c", _KILLED_WRITER, str(out), kind], stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout.readline() == "ready\n"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    names = sorted(p.name for p in tmp_path.iterdir())
    assert len(names) == 2 and atomic._OURS.match(names[0])  # the killed one's temporary
    if kind == "dir":
        assert (out / "frame_00000.png").read_bytes() == b"old"
        with atomic_output(out, directory=True) as tmp:
            (tmp / "frame_00000.png").write_bytes(b"next")
        assert [p.name for p in out.iterdir()] == ["frame_00000.png"]
        assert (out / "frame_00000.png").read_bytes() == b"next"
    else:
        assert out.read_bytes() == b"old"
        write_bytes_atomic(out, b"next")
        assert out.read_bytes() == b"next"
    assert [p.name for p in tmp_path.iterdir()] == [out.name]


def test_sweep_spares_live_processes_and_other_files(tmp_path):
    mine = temp_path(tmp_path / "a.png")  # this process is alive
    mine.write_bytes(b"x")
    (tmp_path / ".hidden").write_bytes(b"x")
    legacy = tmp_path / ".v.abcd1234.partial.mp4"
    legacy.write_bytes(b"x")
    os.utime(legacy, (time.time() - 7200, time.time() - 7200))
    assert sweep_stale(tmp_path) == [legacy]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([mine.name, ".hidden"])


def test_folder_replaces_the_older_one_whole(tmp_path):
    out = tmp_path / "frames"
    with atomic_output(out, directory=True) as tmp:
        for i in range(3):
            (tmp / f"frame_{i:05d}.png").write_bytes(b"a")
    with atomic_output(out, directory=True) as tmp:
        (tmp / "frame_00000.png").write_bytes(b"b")
    assert [p.name for p in out.iterdir()] == ["frame_00000.png"]
    assert [p.name for p in tmp_path.iterdir()] == ["frames"]


def test_nan_to_null():
    data = {"a": [1.0, float("nan")], "b": float("inf"), "c": "x", "d": (2,)}
    assert nan_to_null(data) == {"a": [1.0, None], "b": None, "c": "x", "d": [2]}


def test_check_output_refuses_before_the_work(tmp_path):
    with pytest.raises(UserError, match="does not exist"):
        check_output(tmp_path / "no" / "r.json")
    with pytest.raises(UserError, match="is a folder"):
        check_output(tmp_path)
    (tmp_path / "f").write_text("")
    with pytest.raises(UserError, match="is a file"):
        check_output(tmp_path / "f", folder=True)
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        if os.access(ro, os.W_OK):
            pytest.skip("running as root: permissions are not enforced")
        with pytest.raises(UserError, match="not writable"):
            check_output(ro / "r.json")
    finally:
        ro.chmod(0o700)
    assert check_output(tmp_path / "r.json") == tmp_path / "r.json"


def _writers():
    """(name, write(path)) for every kind of file panogrf writes but video (tests/app/test_video)
    and the scene cache (tests/app/test_scene_cache)."""
    import numpy as np
    import torch

    from panogrf.app.files.images import write_depth, write_rgb
    from panogrf.app.paths.camera_path import CameraPath, write_camera_path
    from panogrf.app.poses.importers import write_tum
    from panogrf.app.train.loop import save_weights

    rng = np.random.default_rng(0)
    noise = rng.integers(0, 256, (128, 256, 3), dtype=np.uint8)  # does not compress
    poses = np.stack([np.eye(4)] * 2)
    return {
        "png": ("a.png", lambda p: write_rgb(p, noise)),
        "depth png": ("d.png", lambda p: write_depth(p, rng.uniform(1, 60, (128, 256)))),
        "json": ("a.json", lambda p: write_json_atomic(p, {"x": list(range(30000))})),
        "camera path": (
            "path.json",
            lambda p: write_camera_path(
                p, CameraPath(poses=np.stack([np.eye(4)] * 3000), fov=np.full(3000, 90.0))
            ),
        ),
        "weights": ("w.safetensors", lambda p: save_weights(torch.nn.Linear(200, 200), p, {})),
        "poses": ("poses.txt", lambda p: write_tum(p, np.concatenate([poses] * 1000))),
    }


@pytest.mark.parametrize("kind", list(_writers()))
def test_every_writer_keeps_the_older_file_on_a_full_disk(tmp_path, kind):
    name, write = _writers()[kind]
    with tiny_tmpfs(tmp_path / "disk", "512k") as disk:
        out = disk / name
        out.write_bytes(b"older")
        fill(disk)
        with pytest.raises(OSError):
            write(out)
        assert out.read_bytes() == b"older"
        assert sorted(p.name for p in disk.iterdir()) == sorted([name, "ballast"])


def test_safetensors_errors_become_oserror(tmp_path, monkeypatch):
    import safetensors.torch
    import torch
    from safetensors import SafetensorError

    def full(tensors, filename, metadata=None):
        raise SafetensorError("I/O error: No space left on device (os error 28)")

    monkeypatch.setattr(safetensors.torch, "save_file", full)
    with pytest.raises(OSError, match="No space left"):
        atomic.save_tensors_atomic(tmp_path / "w.safetensors", {"a": torch.zeros(2)})
    assert list(tmp_path.iterdir()) == []
