"""Hostile input, round 52: an OpenSfM shot whose rotation is too large to be one is named (it
was reported as NaN on the levelled output's first frame); a TUM quaternion of huge numbers is
refused without numpy's overflow warning; the synthetic homes' photo textures load without
libpng's warning about page.png's malformed colour profile, pixels unchanged."""

from __future__ import annotations

import errno
import io
import json
import os
import stat
import sys
import warnings

import cv2
import numpy as np
import pytest
from helpers.cli import run_cli

from panogrf.app import cli
from panogrf.app.errors import UserError
from panogrf.app.poses import importers as im
from panogrf.app.synth import textures
from panogrf.app.weights import networks
from panogrf.assets import path as asset_path


def _two_poses() -> np.ndarray:
    c2w = np.tile(np.eye(4), (2, 1, 1))
    c2w[1, 0, 3] = 1.0
    return c2w


def test_an_opensfm_rotation_too_large_to_be_one_names_its_shot(tmp_path):
    rec = tmp_path / "reconstruction.json"
    im.write_opensfm(rec, ["a.png", "b.png"], _two_poses(), 512, 256)
    data = json.loads(rec.read_text())
    data[0]["shots"]["b.png"]["rotation"] = [1e308, 1e308, 0.0]
    rec.write_text(json.dumps(data))
    with pytest.raises(
        UserError, match=r"shot .b.png.: rotation \[.*\] is too large to be an angle"
    ):
        im.read_poses("opensfm", rec)


def test_a_tum_quaternion_of_huge_numbers_is_refused_quietly(tmp_path):
    traj = tmp_path / "traj.txt"
    traj.write_text("0 0 0 0 0 0 0 1\n1 1 0 0 1e200 1e200 0 0\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy's overflow in the norm would raise here
        with pytest.raises(UserError, match=r"traj.txt:2: the quaternion is not unit length"):
            im.read_poses("tum", traj)


def test_a_png_loses_its_colour_profile_and_keeps_its_pixels(tmp_path):
    img = (np.random.default_rng(0).random((8, 12, 3)) * 255).astype(np.uint8)
    ok, png = cv2.imencode(".png", img)
    assert ok
    data = png.tobytes()
    # An iCCP chunk after IHDR (8 + 25 bytes): length, type, a profile's name and bytes, CRC.
    body = b"ICC Profile\x00\x00" + b"\x01" * 20
    chunk = len(body).to_bytes(4, "big") + b"iCCP" + body + b"\x00\x00\x00\x00"
    with_profile = data[:33] + chunk + data[33:]
    assert textures._without_profile(with_profile) == data
    assert textures._without_profile(b"\xff\xd8 a jpeg") == b"\xff\xd8 a jpeg"
    decoded = cv2.imdecode(np.frombuffer(textures._without_profile(with_profile), np.uint8), 1)
    np.testing.assert_array_equal(decoded, img)


def test_the_photo_textures_load_without_a_libpng_warning(capfd):
    for name in textures.photo_names("train"):
        textures._photo.__wrapped__(name, 16)
    assert "libpng" not in capfd.readouterr().err


# --- round 52's second battery -------------------------------------------------------------

DEMO = asset_path("demo")


def _error(capsys, argv: list[str]) -> str:
    code, line = run_cli(argv, capsys)
    assert code == 2 and line.startswith("panogrf"), line
    return line


def test_an_output_that_is_a_pipe_is_refused_and_left_alone(tmp_path, capsys):
    out = tmp_path / "view.png"
    os.mkfifo(out)
    argv = ["render", str(DEMO), "--out", str(out), "--target-frame", "1", "--height", "32",
            "--method", "nearest"]  # fmt: skip
    assert _error(capsys, argv).endswith("is not a regular file (a device, pipe or socket)")
    assert stat.S_ISFIFO(out.stat().st_mode)
    path_out = tmp_path / "path.json"
    os.mkfifo(path_out)
    line = _error(capsys, ["view", str(DEMO), "--window", "headless", "--path-out", str(path_out)])
    assert line.endswith(f"--path-out: {path_out} is not a regular file")


def _within(seconds: float, call) -> None:
    """``call()`` in a thread, which must end within ``seconds`` (a blocking open of a pipe
    would hang the test run instead of failing it)."""
    import threading

    failure: list[BaseException] = []

    def run() -> None:
        try:
            call()
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            failure.append(exc)

    worker = threading.Thread(target=run, daemon=True)
    worker.start()
    worker.join(seconds)
    assert not worker.is_alive(), "blocked"
    if failure:
        raise failure[0]


def test_a_cache_entry_or_weights_file_that_is_a_pipe_does_not_block(tmp_path, monkeypatch):
    from panogrf.app.scene.store import DiskStore, Unusable

    store = DiskStore(tmp_path)
    os.mkfifo(store.where("k"))
    with pytest.raises(Unusable, match="not a regular file"):
        _within(20, lambda: store.read("k"))
    weights = tmp_path / "w"
    weights.mkdir()
    os.mkfifo(weights / "x.safetensors")
    with pytest.raises(UserError, match=r"x.safetensors: not a regular file \(a pipe"):
        _within(20, lambda: networks.read_weights(weights / "x.safetensors"))


class _Full(io.StringIO):
    """Standard output on a full disk."""

    def write(self, text: str) -> int:
        raise OSError(errno.ENOSPC, "No space left on device")


def test_standard_output_on_a_full_disk_is_one_line(monkeypatch, capsys):
    frames = [str(DEMO / "images" / f"frame_00{i}.png") for i in (0, 1)]
    capsys.readouterr()
    monkeypatch.setattr(sys, "stdout", _Full())
    code = cli.main(["compare", *frames])
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err
    assert (
        err.strip()
        == "panogrf compare: error: cannot write to standard output (No space left on device)"
    )


def test_a_cache_folder_from_the_environment_is_named_so(monkeypatch, capsys, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker))
    line = _error(capsys, ["scene", "prepare", str(DEMO), "--sources", "0,2", "--no-refine-depth"])
    assert f"the cache folder {blocker}/panogrf (from $XDG_CACHE_HOME; --cache-dir" in line


def _png_with_idat(raw_of) -> bytes:
    """The demo's frame 1 as a PNG whose image data is ``raw_of(its raw data)``, chunks valid."""
    import struct
    import zlib

    data = (DEMO / "images" / "frame_001.png").read_bytes()
    chunks, at = [], 8
    while at < len(data):
        (n,) = struct.unpack(">I", data[at : at + 4])
        chunks.append((data[at + 4 : at + 8], data[at + 8 : at + 8 + n]))
        at += 12 + n

    def chunk(kind: bytes, body: bytes) -> bytes:
        return (
            struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
        )

    raw = zlib.decompress(b"".join(body for kind, body in chunks if kind == b"IDAT"))
    idat = zlib.compress(raw_of(raw))
    return data[:8] + chunk(b"IHDR", chunks[0][1]) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def test_png_data_cut_short_is_named_without_libpng_lines(tmp_path, capfd):
    from panogrf.app.files.images import ImageReadError, read_pixels

    half = tmp_path / "half.png"
    half.write_bytes(_png_with_idat(lambda raw: raw[: len(raw) // 2]))
    with pytest.raises(ImageReadError, match=r"half.png: corrupt PNG \(Not enough image data\)"):
        read_pixels(half)
    extra = tmp_path / "extra.png"
    extra.write_bytes(_png_with_idat(lambda raw: raw + raw))
    assert read_pixels(extra).shape == (256, 512, 3)  # the extra data is harmless
    assert "libpng" not in capfd.readouterr().err


def test_a_damaged_jpeg_that_is_all_there_is_called_corrupt(tmp_path):
    from panogrf.app.files.images import ImageReadError, read_pixels

    img = cv2.imread(str(DEMO / "images" / "frame_001.png"))
    ok, jpeg = cv2.imencode(".jpg", img)
    data = bytearray(jpeg.tobytes())
    for i in range(len(data) // 2, len(data) // 2 + 40, 3):
        data[i] = 0xFF
    bad = tmp_path / "bad.jpg"
    bad.write_bytes(bytes(data))
    with pytest.raises(ImageReadError, match=r"bad.jpg: corrupt JPEG \(its data is damaged\)"):
        read_pixels(bad)


def test_faces_of_a_tiny_panorama_name_it_not_the_size_option(tmp_path, capsys):
    tiny = tmp_path / "tiny.png"
    cv2.imwrite(str(tiny), np.zeros((15, 30, 3), np.uint8))
    line = _error(capsys, ["scene", "faces", str(tiny), "--out", str(tmp_path / "f")])
    assert line.endswith(f"{tiny}: 30x15 is too small for cube faces (a quarter of the width, "
                         "at least 8 px); give --size, or larger panoramas")  # fmt: skip


def test_a_depth_map_with_no_known_pixel_is_left_out_and_said(tmp_path, capsys):
    import shutil

    scene = tmp_path / "s"
    shutil.copytree(DEMO, scene)
    meta = json.loads((scene / "transforms.json").read_text())
    depth = scene / meta["frames"][1]["depth_file_path"]
    cv2.imwrite(str(depth), np.zeros((256, 512), np.uint16))
    assert cli.main(["scene", "check", str(scene)]) == 0
    out = capsys.readouterr().out
    assert "no known depth (every pixel is 0, unknown): left out" in out
    assert "depth: 2 of 3 views" in out
    line = _error(capsys, ["scene", "reproject", str(scene), "--target", "1"])
    assert line.endswith("--target 1 (frame_001) has no depth map: choose a view that has")
    assert cli.main(["scene", "reproject", str(scene), "--target", "0"]) == 0
    assert "frame_001    no depth map to warp with" in capsys.readouterr().out


def test_a_scene_written_meanwhile_by_another_run_is_kept(tmp_path, monkeypatch):
    from panogrf.app.scene import folder

    out = tmp_path / "scene"
    real = folder.write_scene

    def slow_write(root, *args, **kwargs):  # another run finishes while this one writes
        real(root, *args, **kwargs)
        out.mkdir()
        (out / "transforms.json").write_text("{}")

    monkeypatch.setattr(folder, "write_scene", slow_write)
    images = np.zeros((2, 3, 16, 32), np.uint8)
    c2w = np.tile(np.eye(4), (2, 1, 1))
    c2w[1, 0, 3] = 1.0
    with pytest.raises(UserError, match="another run wrote a scene there meanwhile"):
        folder.write_new_scene(out, c2w, images)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene"]  # no temporary left
    assert (out / "transforms.json").read_text() == "{}"


def test_an_exif_orientation_that_is_not_applied_is_said(tmp_path):
    from PIL import Image

    from panogrf.app.files.images import read_rgb_with_notes

    photo = Image.open(DEMO / "images" / "frame_001.png").convert("RGB")
    exif = Image.Exif()
    exif[0x0112] = 3
    photo.save(tmp_path / "turned.jpg", exif=exif)
    photo.save(tmp_path / "plain.jpg")
    pixels, notes = read_rgb_with_notes(tmp_path / "turned.jpg")
    assert notes == ["its EXIF orientation (viewers show it turned 180 degrees) is not applied"]
    plain, plain_notes = read_rgb_with_notes(tmp_path / "plain.jpg")
    assert plain_notes == [] and np.array_equal(pixels, plain)  # used as stored


def test_file_names_that_are_not_text_never_reach_json_as_lone_surrogates():
    from pathlib import Path

    from panogrf.app.commands.scene_poses import _view_names
    from panogrf.app.files.atomic import json_text

    odd = Path(os.fsdecode(b"bad\xff.png"))  # a Latin-1 name on a UTF-8 system
    assert _view_names([odd, Path("b.png")]) == ["view_000", "view_001"]
    assert _view_names([Path("a.png"), Path("b.jpg")]) == ["a", "b"]
    text = json_text({"from": [str(odd), "café.jpg"]})
    assert json.loads(text) == {"from": ["bad\\xff.png", "café.jpg"]}
    text.encode("utf-8")  # no lone surrogate left


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
def test_standard_output_on_dev_full_is_one_line_for_a_command_and_its_help(tmp_path):
    import subprocess

    frames = [str(DEMO / "images" / f"frame_00{i}.png") for i in (0, 1)]
    run = "import sys; from panogrf.app.cli import main; sys.exit(main())"
    for argv, name in ((["compare", *frames], "panogrf compare"), (["--help"], "panogrf")):
        with open("/dev/full", "w") as full:
            done = subprocess.run(
                [sys.executable, "-c", run, *argv], stdout=full, stderr=subprocess.PIPE,
                text=True, timeout=300,
            )  # fmt: skip
        assert done.returncode == 1, done.stderr
        assert done.stderr.strip() == (
            f"{name}: error: cannot write to standard output (No space left on device)"
        )


def test_an_empty_folder_given_as_out_is_written_into_not_replaced(tmp_path):
    from panogrf.app.scene import folder

    target = tmp_path / "disk"
    target.mkdir()
    link = tmp_path / "link"
    link.symlink_to(target)  # a mount or a link the user made: it stays where it is
    images = np.zeros((2, 3, 16, 32), np.uint8)
    c2w = np.tile(np.eye(4), (2, 1, 1))
    c2w[1, 0, 3] = 1.0
    folder.write_new_scene(link, c2w, images)
    assert link.is_symlink() and (target / "transforms.json").is_file()
