"""Viewer pieces without a window: fly camera, render worker, scripted keys."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
import torch
from helpers.nets import random_cache

from panogrf.app.viewer.camera import FlyCamera
from panogrf.app.viewer.window import parse_script
from panogrf.app.viewer.worker import RenderWorker


def test_camera_pose_round_trip_and_moves():
    cam = FlyCamera(position=np.array([1.0, 1.5, -2.0]), yaw=0.7, pitch=-0.3)
    m = cam.c2w
    assert np.allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3))
    back = FlyCamera.from_c2w(m)
    assert back.yaw == pytest.approx(0.7) and back.pitch == pytest.approx(-0.3)
    assert np.allclose(back.position, cam.position)
    level = FlyCamera(yaw=0.0, speed=2.0)
    level.move(1.0, 0.0, 0.0, 0.5)  # forward is -z at yaw 0
    assert np.allclose(level.position, [0, 0, -1.0])
    level.move(0.0, 1.0, 1.0, 0.5)
    assert np.allclose(level.position, [1.0, 1.0, -1.0])
    turned = FlyCamera(yaw=math.pi / 2)
    turned.move(1.0, 0.0, 0.0, 1.0)  # a quarter turn left: forward is -x
    assert np.allclose(turned.position, [-1.0, 0, 0], atol=1e-12)
    turned.look(0.0, 5.0)
    assert turned.pitch == pytest.approx(1.5)  # never over the top


def test_parse_script():
    assert parse_script("w*3, x ,wait*2,[,1") == [
        ("W", 3),
        ("X", 0),
        ("WAIT", 2),
        ("LEFT_BRACKET", 0),
        ("NUMBER_1", 0),
    ]


def _wait(worker, gen, level, timeout=60.0):
    end = time.time() + timeout
    while time.time() < end:
        done = worker.latest()
        if done is not None and done.generation == gen and done.level >= level:
            return done
        time.sleep(0.01)
    raise AssertionError("the worker did not finish in time")


def test_worker_refines_level_by_level_and_newer_requests_win():
    net, cache = random_cache()
    worker = RenderWorker(net, cache, levels=((8, "fast"), (16, "fast"))).start()
    try:
        gen = worker.request(np.eye(4))
        done = _wait(worker, gen, 1)
        assert done.rgb.shape == (16, 32, 3) and done.rgb.dtype == np.uint8
        assert worker.status[0] == 2
        pose = np.eye(4)
        pose[0, 3] = 0.3
        worker.cancel()
        gen2 = worker.request(pose)
        assert gen2 > gen
        done2 = _wait(worker, gen2, 1)
        assert np.allclose(done2.c2w, pose)
    finally:
        worker.stop()


def test_cancel_stops_a_render_in_flight():
    net, cache = random_cache()
    worker = RenderWorker(net, cache, levels=((64, "paper"),)).start()
    poses = [np.eye(4) for _ in range(3)]
    for k, p in enumerate(poses):
        p[0, 3] = 0.2 * k
    try:
        t0 = time.perf_counter()
        first = _wait(worker, worker.request(poses[0]), 0)
        whole = time.perf_counter() - t0  # what one render takes here
        gen = worker.request(poses[1])
        end = time.time() + 60
        while worker.status[1] == 0.0 and time.time() < end:
            time.sleep(0.005)
        assert worker.status[1] > 0.0  # the render is under way
        worker.cancel()
        time.sleep(1.5 * whole)  # long enough for it to finish, had it not stopped
        assert worker.latest() is first  # the cancelled render was never published
        assert worker.status == (0, 0.0)
        # The worker goes on: the next request is rendered to the end.
        done = _wait(worker, worker.request(poses[2]), 0)
        assert done.generation > gen and np.allclose(done.c2w, poses[2])
    finally:
        worker.stop()


def test_worker_levels_can_use_the_nearest_sources():
    net, cache = random_cache()  # sources at x = 0 and x = 1
    worker = RenderWorker(net, cache, levels=((8, "fast", 1), (8, "fast", None)))
    near_second = np.eye(4)
    near_second[0, 3] = 0.9
    one = worker._nearest(near_second, 1)
    assert one.num_views == 1 and torch.equal(one.c2w[0], cache.c2w[1])
    assert worker._nearest(near_second, 1) is one  # memoised
    assert worker._nearest(np.eye(4), None) is cache
    worker.start()
    try:
        done = _wait(worker, worker.request(near_second), 1)
        assert done.rgb.shape == (8, 16, 3)
    finally:
        worker.stop()


def test_waiting_for_a_result_wakes_when_a_level_is_done():
    net, cache = random_cache()
    worker = RenderWorker(net, cache, levels=((8, "fast"),)).start()
    try:
        time.sleep(0.5)  # the warm-up render is done
        gen = worker.request(np.eye(4))
        t0 = time.perf_counter()
        worker.wait_for_result(30.0)  # the render takes far longer than getting here
        assert time.perf_counter() - t0 < 5.0  # woken by the result, not the timeout
        assert worker.latest().generation == gen
    finally:
        worker.stop()


def test_brackets_drag_and_wheel_act_as_in_360_viewers():
    """`[` and `]` change the speed in a real (pyglet) window, whose key table names the braces
    as the brackets; dragging moves the image with the cursor; the wheel zooms."""
    from types import SimpleNamespace

    from panogrf.app.viewer.camera import FlyCamera
    from panogrf.app.viewer.window import PanoViewer

    pyglet_keys = SimpleNamespace(LEFT_BRACKET=ord("{"), RIGHT_BRACKET=ord("}"), W=ord("w"))
    keymap = PanoViewer._make_keymap(SimpleNamespace(wnd=SimpleNamespace(keys=pyglet_keys)))
    assert keymap[ord("[")] == "LEFT_BRACKET" and keymap[ord("]")] == "RIGHT_BRACKET"
    setup = SimpleNamespace(drag_looks=False)
    viewer = SimpleNamespace(camera=FlyCamera.from_c2w(np.eye(4)), perspective=True, setup=setup)
    yaw, pitch = viewer.camera.yaw, viewer.camera.pitch
    PanoViewer.on_mouse_drag_event(viewer, 0, 0, 10, 10)  # right and down
    assert viewer.camera.yaw > yaw  # turned left: the image moved right, with the cursor
    assert viewer.camera.pitch > pitch  # looked up: the image moved down
    setup.drag_looks = True  # --drag-looks: the camera turns with the mouse instead
    PanoViewer.on_mouse_drag_event(viewer, 0, 0, 10, 10)
    assert viewer.camera.yaw == pytest.approx(yaw) and viewer.camera.pitch == pytest.approx(pitch)
    PanoViewer.on_mouse_drag_event(viewer, 0, 0, 10, 10)
    assert viewer.camera.yaw < yaw and viewer.camera.pitch < pitch
    fov = viewer.camera.fov
    PanoViewer.on_mouse_scroll_event(viewer, 0, 1)
    assert viewer.camera.fov == fov - 5


def test_the_first_walking_speed_follows_the_sources_spacing():
    from panogrf.app.viewer.camera import walk_speed

    def line(*xs):
        c2w = np.repeat(np.eye(4)[None], len(xs), 0)
        c2w[:, 0, 3] = xs
        return c2w

    assert walk_speed(line(0.0, 1.0)) == 0.5  # two seconds from one source to the next
    assert walk_speed(line(0.0, 0.3, 0.6)) == pytest.approx(0.15)
    assert walk_speed(line(0.0, 40.0)) == 1.0 and walk_speed(line(0.0, 0.01)) == 0.1
    assert walk_speed(line(0.0)) == 0.5


def test_the_preview_reads_sources_at_most_twice_its_rows():
    import cv2

    from panogrf.app.viewer.setup import preview_sources

    rng = np.random.default_rng(0)
    images = rng.integers(0, 256, (2, 64, 128, 3), dtype=np.uint8)
    assert preview_sources(images, 32) is images  # 64 rows = 2 x 32: as they are
    small = preview_sources(images, 16)
    assert small.shape == (2, 32, 64, 3) and small.dtype == np.uint8
    want = cv2.resize(images[1], (64, 32), interpolation=cv2.INTER_AREA)
    assert np.array_equal(small[1], want)
    # Area averaging, not picking: a 2x2 block's mean.
    assert abs(int(small[0, 5, 7, 0]) - images[0, 10:12, 14:16, 0].mean()) <= 0.5
