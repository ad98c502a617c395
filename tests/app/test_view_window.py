"""`panogrf view` for real: a window under Xvfb driven by xdotool, and a headless EGL session.

The window test types the way a person would (XTEST key events to the focused window): a
screenshot, W held for a while, another screenshot, Esc. The camera must have moved forward
along its heading and the two screenshots must differ.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from panogrf.app.files.images import read_rgb
from panogrf.assets import path as asset_path

DEMO = asset_path("demo")
PANOGRF = str(Path(sys.executable).with_name("panogrf"))
SHOT = re.compile(
    r"screenshot (\S+) at ([-+\d.]+) ([-+\d.]+) ([-+\d.]+) yaw ([-+\d.]+) pitch ([-+\d.]+)"
)

pytestmark = [pytest.mark.gl, pytest.mark.slow]


def _free_display() -> str:
    for n in range(90, 140):
        if not Path(f"/tmp/.X11-unix/X{n}").exists() and not Path(f"/tmp/.X{n}-lock").exists():
            return f":{n}"
    raise RuntimeError("no free X display number")


def _until(predicate, timeout: float, what: str):
    end = time.time() + timeout
    while time.time() < end:
        value = predicate()
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.fixture
def xvfb():
    display = _free_display()
    proc = subprocess.Popen(
        ["Xvfb", display, "-screen", "0", "1280x720x24", "-nolisten", "tcp"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    n = display[1:]
    _until(lambda: Path(f"/tmp/.X11-unix/X{n}").exists(), 20, "Xvfb")
    yield display
    proc.terminate()
    proc.wait(10)


@pytest.mark.slow
def test_window_moves_on_key_presses(xvfb, tmp_path):
    env = {**os.environ, "DISPLAY": xvfb}
    log = tmp_path / "viewer.log"
    cmd = [
        PANOGRF,
        "view",
        str(DEMO),
        "--window",
        "pyglet",
        "--size",
        "512x256",
        "--no-refine",
        "--no-refine-depth",
        "--screenshot-dir",
        str(tmp_path),
        "--cache-dir",
        str(tmp_path / "cache"),
    ]
    with log.open("w") as out:
        viewer = subprocess.Popen(cmd, env=env, stdout=out, stderr=subprocess.STDOUT)
    try:

        def xdo(*args: str) -> str:
            return subprocess.run(
                ["xdotool", *args], env=env, capture_output=True, text=True, timeout=30
            ).stdout.strip()

        wid = _until(lambda: xdo("search", "--name", "panogrf").split(), 120, "the window")[0]
        xdo("windowfocus", "--sync", wid)
        time.sleep(1.0)

        def shots():
            return SHOT.findall(log.read_text())

        xdo("key", "x")
        _until(lambda: len(shots()) >= 1, 30, "the first screenshot")
        xdo("keydown", "w")
        time.sleep(1.5)
        xdo("keyup", "w")
        time.sleep(0.5)
        xdo("key", "x")
        _until(lambda: len(shots()) >= 2, 30, "the second screenshot")
        xdo("key", "Escape")
        assert viewer.wait(30) == 0, log.read_text()
    finally:
        if viewer.poll() is None:
            viewer.kill()
    (a, *pa), (b, *pb) = shots()[:2]
    pa, pb = np.array(pa, float), np.array(pb, float)
    yaw = math.radians(pa[3])
    forward = np.array([-math.sin(yaw), 0.0, -math.cos(yaw)])
    step = pb[:3] - pa[:3]
    # The demo's sources are 0.5 m apart: the first speed is 0.25 m/s (`walk_speed`), about
    # 0.37 m for the 1.5 s W was held.
    assert step @ forward > 0.15, (pa, pb)
    assert np.linalg.norm(step - (step @ forward) * forward) < 0.05  # straight ahead
    img_a, img_b = read_rgb(a), read_rgb(b)
    assert img_a.shape == img_b.shape == (256, 512, 3)
    below = slice(120, None)  # under the overlay
    diff = np.abs(img_a[below].astype(int) - img_b[below].astype(int)).mean()
    assert diff > 5.0, diff


@pytest.mark.slow
def test_headless_session_writes_screenshots_and_a_camera_path(tmp_path):
    out_path = tmp_path / "path.json"
    cmd = [
        PANOGRF,
        "view",
        str(DEMO),
        "--window",
        "headless",
        "--size",
        "256x128",
        "--no-refine",
        "--no-refine-depth",
        "--screenshot-dir",
        str(tmp_path),
        "--cache-dir",
        str(tmp_path / "c"),
        "--frames",
        "40",
        "--fixed-step",
        "0.05",
        "--path-out",
        str(out_path),
        "--script",
        "k,w*10,left*5,k,d*5,k,o,x,3,x",
    ]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "saved" in run.stdout and len(SHOT.findall(run.stdout)) == 2
    from panogrf.app.paths.camera_path import read_camera_path

    path = read_camera_path(out_path)
    assert len(path) > 3 and path.camera_type == "equirectangular"
    assert len(path.keyframes) == 3
    # Read back: the session starts with the three keyframes, plays them and saves them again.
    again = tmp_path / "again.json"
    cmd[cmd.index("--script") + 1] = "p,wait*5,o"
    cmd[cmd.index("--path-out") + 1] = str(again)
    cmd[cmd.index("--frames") + 1] = "10"
    run = subprocess.run(
        [*cmd, "--camera-path", str(out_path)], capture_output=True, text=True, timeout=300
    )
    assert run.returncode == 0, run.stderr
    assert f"3 keyframes from {out_path}" in run.stdout and "playing 3 keyframes" in run.stdout
    assert read_camera_path(again).keyframes == path.keyframes
    run = subprocess.run(
        [*cmd, "--camera-path", str(tmp_path / "none.json")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 2 and "none.json: camera path file not found" in run.stderr
    # O never writes over the scene's own files: refused before the scene is prepared.
    victim = tmp_path / "victim"
    shutil.copytree(DEMO, victim)
    before = (victim / "transforms.json").read_bytes()
    at = cmd.index(str(DEMO)) if str(DEMO) in cmd else 2
    bad = [*cmd[:at], str(victim), *cmd[at + 1 :]]
    bad[bad.index("--path-out") + 1] = str(victim / "transforms.json")
    run = subprocess.run(bad, capture_output=True, text=True, timeout=300)
    assert run.returncode == 2 and "--path-out" in run.stderr and "refusing" in run.stderr
    assert (victim / "transforms.json").read_bytes() == before


def test_view_errors(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    run = subprocess.run([PANOGRF, "view", str(DEMO)], env=env, capture_output=True, text=True)
    assert run.returncode == 2 and "headless" in run.stderr
    run = subprocess.run(
        [PANOGRF, "view", str(tmp_path / "nope"), "--window", "headless"],
        capture_output=True,
        text=True,
    )
    assert run.returncode == 2 and "Traceback" not in run.stderr
    run = subprocess.run(
        [PANOGRF, "view", str(DEMO), "--window", "headless", "--moving-rows", "8"],
        capture_output=True,
        text=True,
    )
    assert run.returncode == 2 and "--moving-rows" in run.stderr


@pytest.mark.slow
def test_headless_session_survives_a_failed_save_and_plays_in_real_time(tmp_path):
    """O into a missing folder is reported and the session goes on; P plays the 2 s transition
    in real time (20 steps of 0.05 s: half way); F writes a clean 2:1 panorama; the wide
    window letterboxes the panorama; looking up in panorama mode leaves it level; the source
    view turns with the heading."""
    cmd = [
        PANOGRF,
        "view",
        str(DEMO),
        "--window",
        "headless",
        "--size",
        "300x100",
        "--no-refine",
        "--no-refine-depth",
        "--screenshot-dir",
        str(tmp_path),
        "--cache-dir",
        str(tmp_path / "c"),
        "--frames",
        "150",
        "--fixed-step",
        "0.05",
        "--path-out",
        str(tmp_path / "missing" / "path.json"),
        "--script",
        "x,k,d*20,k,o,f,p,wait*20,x,p,h,x,up*10,x,4,x,left*10,x,esc",
    ]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    # The session went on after the failed save, and its status says a write failed.
    assert run.returncode == 1 and "1 write failed" in run.stderr, run.stderr
    assert "cannot save the camera path" in run.stdout and "does not exist" in run.stdout
    shots = SHOT.findall(run.stdout)
    assert len(shots) == 6, run.stdout
    start, mid = (np.array(s[1:4], float) for s in shots[:2])
    # d*20: 1 s at the demo's first speed of 0.25 m/s between the keyframes; 1.05 s of 2 s.
    assert np.linalg.norm(mid - start) == pytest.approx(0.25 * 1.05 / 2, abs=0.0125)
    pano = list(tmp_path.glob("panogrf_pano_*.png"))
    assert len(pano) == 1 and read_rgb(pano[0]).shape == (512, 1024, 3)
    img = [read_rgb(s[0]).astype(int) for s in shots]
    assert img[2].shape == (100, 300, 3)
    assert img[2][:, :48].max() == 0 and img[2][:, -48:].max() == 0  # the bars
    assert img[2][:, 60:240].mean() > 10
    assert np.array_equal(img[2], img[3])  # looking up: the panorama stays level
    assert np.abs(img[4] - img[5]).mean() > 3  # the source view turned with the camera


def test_a_dead_render_worker_is_reported_and_exits_non_zero(tmp_path, monkeypatch, capsys):
    """The session goes on with the preview, says why refinement stopped, and exits 1."""
    from panogrf.app import cli
    from panogrf.app.viewer import worker as worker_mod

    def broken(self):
        raise RuntimeError("renderer weights do not match the cache")

    monkeypatch.setattr(worker_mod.RenderWorker, "_serve", broken)
    code = cli.main(
        ["view", str(DEMO), "--window", "headless", "--size", "128x64", "--frames", "20",
         "--fixed-step", "0.05", "--cache-dir", str(tmp_path / "c"), "--threads", "1"]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert code == 1
    assert "refinement stopped: RuntimeError: renderer weights do not match the cache" in err
    assert "Traceback" not in err


def test_every_refinement_level_reaches_the_screen(tmp_path, capsys):
    """Both levels are 512 rows (the network at 128 rows): the second must replace
    the first on screen although it has the same size."""
    from panogrf.app import cli

    code = cli.main(
        ["view", str(DEMO), "--window", "headless", "--size", "128x64", "--frames", "3000",
         "--fixed-step", "0.05", "--cache-dir", str(tmp_path / "c"), "--script",
         "w*3,refined,escape"]
    )  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0
    assert "refined level 1/2" in out and "refined level 2/2" in out, out


def test_live_the_neural_view_follows_the_moving_camera(tmp_path):
    """A live worker (the default on a GPU): frames that move show the neural view of a pose
    at most one render behind (turned to the camera's direction), and the still camera's own
    frame at the end. Small renders, so that a CPU keeps up with a moving camera."""
    from panogrf.app.scene.session import default_models, prepare_scene
    from panogrf.app.viewer.window import ViewerSetup, parse_script, run_viewer
    from panogrf.app.viewer.worker import RenderWorker

    prepared = prepare_scene(DEMO, tmp_path / "c", log=lambda *a: None)
    views, models = prepared.views, default_models()
    cache = views.cache_for("panogrf", models)
    net = models.renderer("panogrf")
    worker = RenderWorker(net, cache, levels=((32, "fast", None, 32),), live=True).start()
    setup = ViewerSetup.from_views(
        views,
        worker=worker,
        script=parse_script("w*200,d*100,refined,escape"),
        frames=5000,
        fixed_step=0.01,
        log=lambda *a: None,
    )
    try:
        config = run_viewer(setup, "headless", (128, 64))
    finally:
        worker.stop()
    assert worker.error is None
    assert config.neural_moving_frames >= 1
    assert config.refinement.state == "refined"
    assert np.allclose(config.refinement.frame()[0].c2w, config.refinement.pose)


def test_live_is_wired_to_the_command(tmp_path, capsys):
    from panogrf.app import cli

    code = cli.main(
        ["view", str(DEMO), "--window", "headless", "--size", "128x64", "--frames", "3000",
         "--fixed-step", "0.05", "--cache-dir", str(tmp_path / "c"), "--live", "on",
         "--no-refine-depth", "--script", "w*3,refined,escape"]
    )  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0
    assert re.search(r"while moving [\d.]+ ms, the neural view on \d+ of them", out), out
    assert "refined level 1/1" in out, out


def test_live_on_needs_the_refinement(tmp_path, capsys):
    from panogrf.app import cli

    code = cli.main(["view", str(DEMO), "--window", "headless", "--live", "on", "--no-refine"])
    err = capsys.readouterr().err
    assert code != 0 and "--live on" in err and "Traceback" not in err


@pytest.mark.slow
@pytest.mark.parametrize(
    ("script", "frames", "sharp", "rows"),
    [
        ("w*30", 8, False, 64),
        ("w*3,wait*30", 10, False, 128),
        ("w*30", 8, True, 64),
        ("w*3,wait*30", 10, True, 64),
    ],
)
def test_the_preview_has_fewer_rows_while_moving(tmp_path, script, frames, sharp, rows):
    """While the camera moves the preview's geometry is drawn at ``moving_height`` rows. Sharp
    (the default) reads the colours at ``preview_height`` rows as it shows them and keeps that
    geometry when the camera stops; otherwise the preview is shown upsampled and the first
    still frame draws it at ``preview_height``."""
    from panogrf.app.scene.session import prepare_scene
    from panogrf.app.viewer.window import ViewerSetup, parse_script, run_viewer

    views = prepare_scene(DEMO, tmp_path / "c", log=lambda *a: None).views
    setup = ViewerSetup.from_views(
        views,
        worker=None,
        script=parse_script(script),
        frames=frames,
        fixed_step=0.05,
        preview_height=128,
        moving_height=64,
        sharp=sharp,
        log=lambda *a: None,
    )
    config = run_viewer(setup, "headless", (256, 128))
    assert (config.preview_out.sharp is not None) == sharp
    assert config.preview_out.blend.size == (2 * rows, rows)


def test_the_refined_depth_replaces_the_plain_one_in_a_running_session(tmp_path):
    """`panogrf view` opens on the plain scene while the refinement runs in the background:
    when it is done, the next frame rebuilds the GL preview from the refined depth, hands the
    refined cache to the render worker and refines the still view again from it."""
    from panogrf.app.scene.session import prepare_scene
    from panogrf.app.viewer.scene_refiner import SceneRefiner
    from panogrf.app.viewer.window import ViewerSetup, parse_script, run_viewer
    from panogrf.app.viewer.worker import RenderWorker
    from panogrf.model import refine

    quiet = lambda *a: None  # noqa: E731
    prepared = prepare_scene(
        DEMO, tmp_path / "c", log=quiet, refine=refine.PREPARE_REFINE, defer_refine=True
    )
    plain = prepared.views.depth["full"][:, 0].numpy().copy()
    refiner = SceneRefiner(prepared, log=quiet).start()
    refiner.join(120)  # done before the window opens: the swap happens at the first frame
    cache = prepared.views.cache_for("panogrf", prepared.models)
    worker = RenderWorker(prepared.models.renderer("panogrf"), cache, threads=1).start()
    messages = []
    setup = ViewerSetup.from_views(
        prepared.views,
        worker=worker,
        script=parse_script("refined,escape"),
        frames=3000,
        fixed_step=0.05,
        scene_refiner=refiner,
        log=messages.append,
    )
    try:
        config = run_viewer(setup, "headless", (128, 64))
    finally:
        worker.stop()
    assert not np.array_equal(setup.depth, plain)
    assert worker.cache is not cache and worker.cache.depth.shape[0] == plain.shape[0]
    assert any(m.startswith("depth refined") for m in messages), messages
    assert config.refinement.done() and config.shown_level is not None
    # What benchmarks/viewer.py reads: the swap happened at the first frame, and no frame
    # counted as one while the refinement ran.
    assert config.scene_swapped
    assert config.refining_frame_times == []
    assert refiner.seconds is not None and refiner.seconds > 0


def test_the_main_thread_only_draws(tmp_path, monkeypatch):
    """The scene is prepared in another thread on the session's torch threads, the window runs
    with the main thread's torch serial (so that it never holds an OpenMP pool of its own:
    `panogrf.app.viewer.torch_threads`), and the caller's count is back afterwards."""
    import threading

    import torch

    from panogrf.app import cli
    from panogrf.app.scene import session
    from panogrf.app.viewer import window

    seen = {}
    prepare, run = session.prepare_scene, window.run_viewer

    def spy_prepare(*args, **kwargs):
        seen["prepare"] = (threading.current_thread() is threading.main_thread(),
                           torch.get_num_threads())  # fmt: skip
        return prepare(*args, **kwargs)

    def spy_run(*args, **kwargs):
        seen["window"] = (threading.current_thread() is threading.main_thread(),
                          torch.get_num_threads())  # fmt: skip
        return run(*args, **kwargs)

    monkeypatch.setattr(session, "prepare_scene", spy_prepare)
    monkeypatch.setattr(window, "run_viewer", spy_run)
    before = torch.get_num_threads()
    code = cli.main(
        ["view", str(DEMO), "--window", "headless", "--size", "128x64", "--frames", "5",
         "--no-refine", "--no-refine-depth", "--cache-dir", str(tmp_path / "c"),
         "--threads", "2"]
    )  # fmt: skip
    assert code == 0
    assert seen["prepare"] == (False, 2)
    assert seen["window"] == (True, 1)
    assert torch.get_num_threads() == before
