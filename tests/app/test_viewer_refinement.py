"""The refinement state machine: moving cancels, still for the debounce requests, and only the
current request's levels reach the window, each logged once."""

from __future__ import annotations

import time

import numpy as np
from helpers.nets import random_cache

from panogrf.app.viewer.refinement import Refinement
from panogrf.app.viewer.worker import RenderWorker


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def _worker() -> RenderWorker:
    net, cache = random_cache()
    return RenderWorker(net, cache, levels=((8, "draft", 2, 8), (16, "fast", None, 16)))


def _until_refined(machine: Refinement, clock: Clock) -> list:
    frames = []
    end = time.time() + 60
    while machine.state != "refined" and time.time() < end:
        machine.worker.wait_for_result(0.05)
        clock.now += 0.01
        machine.observe(machine.pose)
        done, new = machine.frame()
        if new:
            frames.append(done)
    done, new = machine.frame()
    if new:
        frames.append(done)
    return frames


def test_still_camera_is_refined_level_by_level_and_moving_cancels():
    clock = Clock()
    worker = _worker().start()
    machine = Refinement(worker, still_delay=0.1, clock=clock)
    try:
        here, there = np.eye(4), np.eye(4)
        there[0, 3] = 0.5
        assert machine.observe(here) and machine.state == "moving"
        assert not machine.observe(here) and machine.state == "settling"  # debounce
        assert machine.frame() == (None, False)
        clock.now = 0.1
        machine.observe(here)
        assert machine.state in ("refining", "refined") and machine.requested
        frames = _until_refined(machine, clock)
        assert machine.state == "refined" and machine.done()
        assert [f.level for f in frames] == [0, 1]  # each level handed out once, in order
        assert frames[1].rgb.shape == (16, 32, 3)
        assert np.allclose(frames[1].c2w, here)
        assert [lv for lv, _ in machine.log] == [0, 1]
        assert machine.frame()[1] is False  # the same level is not new twice
        assert "done" in machine.status_text()

        # Moving: the finished frame of the old pose is no longer the window's to show.
        assert machine.observe(there) and machine.state == "moving"
        assert machine.frame() == (None, False)
        assert "moving" in machine.status_text()
        clock.now += 0.1
        machine.observe(there)
        frames = _until_refined(machine, clock)
        assert [f.level for f in frames] == [0, 1]
        assert np.allclose(frames[-1].c2w, there)
    finally:
        machine.stop()


def test_without_a_worker_the_preview_is_all_there_is():
    machine = Refinement(None)
    assert machine.observe(np.eye(4))
    machine.observe(np.eye(4))
    assert machine.state == "off" and machine.done()
    assert machine.frame() == (None, False)
    assert machine.status_text() == "refinement off"
    machine.idle(time.perf_counter() - 1.0, 30.0)  # a frame already late: returns at once
    machine.stop()


def test_live_every_move_is_requested_and_the_newest_finished_frame_shown():
    """Live (a GPU): moving requests the pose at once and cancels nothing; a render finishes
    although the camera moved on, and the window gets the newest finished frame, never an
    older one after it."""
    net, cache = random_cache()
    worker = RenderWorker(net, cache, levels=((8, "fast", None, 8),), live=True).start()
    machine = Refinement(worker, clock=Clock())
    try:
        poses = [np.eye(4) for _ in range(40)]
        for i, pose in enumerate(poses):
            pose[0, 3] = 0.01 * i
        shown = []
        end = time.time() + 60
        i = 0
        while time.time() < end and (len(shown) < 3 or i < len(poses)):
            assert machine.observe(poses[min(i, len(poses) - 1)]) == (i < len(poses))
            assert machine.requested  # at once, no debounce
            done, new = machine.frame()
            if new:
                shown.append(done.generation)
            worker.wait_for_result(0.01)
            i += 1
        assert len(shown) >= 3 and shown == sorted(shown)
        assert len(set(shown)) == len(shown)
        # A frame of a pose the camera has left reached the window (it was not dropped).
        assert any(g < machine.generation for g in shown)
        while machine.state != "refined" and time.time() < end:  # still at the last pose
            worker.wait_for_result(0.01)
            assert not machine.observe(poses[-1])
        assert machine.state == "refined"
        assert np.allclose(machine.frame()[0].c2w, poses[-1])
    finally:
        machine.stop()


def test_live_a_new_pose_does_not_drop_the_render_in_flight_but_a_cancel_does():
    net, cache = random_cache()
    worker = RenderWorker(net, cache, levels=((8, "fast", None, 8),), live=True)
    assert not worker._superseded(worker._generation)
    gen = worker.request(np.eye(4))
    worker.request(np.eye(4))  # a newer pose waits for the render of ``gen``
    assert not worker._superseded(gen)
    worker.cancel()
    assert worker._superseded(gen)
    plain = RenderWorker(net, cache, levels=((8, "fast", None, 8),))
    gen = plain.request(np.eye(4))
    plain.request(np.eye(4))
    assert plain._superseded(gen)
