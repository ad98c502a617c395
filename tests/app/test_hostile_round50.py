"""Hostile input, round 50: a command stopped by SIGTERM or SIGHUP, or interrupted while it
writes a scene, leaves nothing behind; the cache's entries are readable as the umask says and
a killed write's temporary goes; ``~`` in ``--opt=~/x``; a dangling cache link; camera
heights in centimetres; a panorama turned by its EXIF tag; a hand-typed ``--c2w``."""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from panogrf.app.errors import UserError
from panogrf.app.options import user_path
from panogrf.app.runtime import folder_path
from panogrf.app.scene import folder as scene_folder
from panogrf.app.scene import store as st
from panogrf.assets import path as asset_path

DEMO = asset_path("demo")
PHOTOS = [str(DEMO / "images" / f"frame_00{k}.png") for k in range(2)]

#: A posing that hangs once COLMAP's work folder exists (the marker file says so).
_HANGING_POSING = """
import signal, sys, time
signal.signal(signal.SIGHUP, signal.SIG_DFL)  # as in a terminal, whatever ran the tests (nohup)
from pathlib import Path
from panogrf.app import cli
from panogrf.app.poses import colmap

def hang(images, cfg, say, work):
    (Path(work) / "database.db").write_bytes(b"x" * 1000)
    Path(sys.argv[1]).write_text("posing")
    time.sleep(120)

colmap._run = hang
cli.main(["scene", "from-panoramas", *sys.argv[3:], "--out", sys.argv[2]])
"""


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_a_posing_stopped_by_a_signal_leaves_no_temporary_folder(tmp_path, sig):
    """`timeout`, a service manager or a closed terminal: COLMAP's work folder is removed and
    the process ends by the signal, quietly."""
    temp = tmp_path / "tmp"
    temp.mkdir()
    marker, out = tmp_path / "posing", tmp_path / "scene"
    env = {**os.environ, "TMPDIR": str(temp)}
    args = [sys.executable, "-c", _HANGING_POSING, str(marker), str(out), *PHOTOS]
    proc = subprocess.Popen(args, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while not marker.exists() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert marker.exists(), proc.communicate()
    assert any(temp.iterdir())  # the work folder is there while it runs
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == -sig
    assert "Traceback" not in err.decode()
    assert list(temp.iterdir()) == [] and not out.exists()


def test_a_scene_write_interrupted_leaves_no_half_scene(tmp_path, monkeypatch):
    """Ctrl-C while the photos are copied: the same command can run again."""

    def interrupted(out, *args, **kwargs):
        (Path(out) / "images").mkdir(parents=True)
        (Path(out) / "images" / "a.jpg").write_bytes(b"half")
        raise KeyboardInterrupt

    monkeypatch.setattr(scene_folder, "write_scene", interrupted)
    for out in (tmp_path / "new", tmp_path / "empty"):
        if out.name == "empty":
            out.mkdir()
        with pytest.raises(KeyboardInterrupt):
            scene_folder.write_new_scene(out, np.eye(4)[None])
        assert not out.exists() or list(out.iterdir()) == []


def _entry() -> st.Entry:
    return st.Entry({"depth": torch.arange(6, dtype=torch.float32).reshape(2, 3)}, {"a": "b"})


def test_cache_entries_follow_the_umask_and_a_killed_writes_temporary_goes(tmp_path):
    store = st.DiskStore(tmp_path)
    old = tmp_path / ".tmpAb12Cd"  # safetensors' own temporary, left by a killed process
    fresh = tmp_path / ".tmpZz99Yy"  # another process writing now
    for path in (old, fresh):
        path.write_bytes(b"partial")
    os.utime(old, (time.time() - 2 * 3600,) * 2)
    mask = os.umask(0o022)
    try:
        store.write("k", _entry())
    finally:
        os.umask(mask)
    assert (store.where("k").stat().st_mode & 0o777) == 0o644
    assert not old.exists() and fresh.exists()
    loaded = store.read("k")
    assert loaded is not None and torch.equal(loaded.tensors["depth"], _entry().tensors["depth"])


def test_an_entry_without_read_permission_is_said_so(tmp_path, monkeypatch):
    """safetensors reports a file it may not read as a missing one."""
    store = st.DiskStore(tmp_path)
    store.write("k", _entry())
    monkeypatch.setattr(st.os, "access", lambda path, mode: False)
    with pytest.raises(st.Unusable, match="no permission"):
        store.read("k")


def test_a_tilde_after_an_equals_sign_is_the_home_folder(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))
    assert user_path("~/scene") == tmp_path / "scene"
    assert user_path("a~b") == Path("a~b")
    assert folder_path("~/cache") == tmp_path / "cache"
    dangling = tmp_path / "cache_link"
    dangling.symlink_to(tmp_path / "unmounted" / "cache")
    with pytest.raises(argparse.ArgumentTypeError, match="which does not exist"):
        folder_path(str(dangling))


def test_camera_heights_in_centimetres_are_warned_about(capsys):
    from panogrf.app.poses.scale import parse_heights

    assert parse_heights("1.6", 2).tolist() == [1.6, 1.6]
    assert capsys.readouterr().err == ""
    parse_heights("160,158", 2)
    err = capsys.readouterr().err
    assert err.startswith("warning: --camera-height 160,158") and "1.6 for 160 cm" in err


def test_a_panorama_turned_by_its_exif_tag_says_so(tmp_path):
    from PIL import Image

    from panogrf.app.commands.scene_poses import read_panoramas

    turned = tmp_path / "turned.jpg"
    exif = Image.Exif()
    exif[0x0112] = 6
    Image.new("RGB", (64, 128), (90, 120, 150)).save(turned, exif=exif)
    with pytest.raises(UserError, match="64x128 is not a 2:1 panorama .*EXIF orientation"):
        read_panoramas([turned])
    plain = tmp_path / "plain.jpg"
    Image.new("RGB", (64, 128), (90, 120, 150)).save(plain)
    with pytest.raises(UserError) as exc:
        read_panoramas([plain])
    assert "EXIF" not in str(exc.value)


def test_a_hand_typed_c2w(capsys):
    from panogrf.app.commands.render import parse_c2w

    nested = "[[1, 0, 0, 0.5], [0, 1, 0, 1.5], [0, 0, 1, 2], [0, 0, 0, 1]]"
    assert parse_c2w(nested)[:3, 3].tolist() == [0.5, 1.5, 2.0]
    rounded = "0.707 0 0.707 0 0 1 0 1.5 -0.707 0 0.707 0 0 0 0 1"
    with pytest.raises(UserError, match=r"not a rotation \(max \|R\^T R - I\| = 0.0003"):
        parse_c2w(rounded)
    with pytest.raises(UserError, match="det -1"):
        parse_c2w("-1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1")
