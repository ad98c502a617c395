"""Viewer logic without a window: recorded paths, failed saves, overlay text, layout, warnings."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest

from panogrf.app.paths.camera_path import read_camera_path
from panogrf.app.scene.coverage import behind_surface
from panogrf.app.viewer import recording, screen
from panogrf.app.viewer.camera import FlyCamera
from panogrf.app.viewer.recording import Keyframe


def _key(x: float, yaw: float, fov: float, transition: float = 2.0) -> Keyframe:
    return Keyframe(FlyCamera(np.array([x, 0.0, 0.0]), yaw=yaw).c2w, fov, transition)


KEYS = [_key(0.0, 0.0, 60.0, 1.0), _key(1.0, 0.5, 90.0, 3.0), _key(2.0, 1.0, 40.0)]


def test_recorded_path_keeps_each_keyframes_fov_time_and_one_aspect(tmp_path):
    path = recording.recorded_path(KEYS, perspective=True, pano_height=256, fps=10, aspect=2.0)
    assert path.seconds == pytest.approx(4.0) and len(path) == 40  # real time: seconds x fps
    assert path.fov[0] == pytest.approx(60.0) and path.fov[-1] == pytest.approx(40.0)
    assert 60.0 < path.fov[5] < 90.0  # between the first two keyframes' fovs
    assert [k["fov"] for k in path.keyframes] == [60.0, 90.0, 40.0]
    assert [k["override_transition_sec"] for k in path.keyframes] == [1.0, 3.0, 2.0]
    aspect = path.render_width / path.render_height
    assert aspect == pytest.approx(2.0)
    assert np.allclose(path.aspect, aspect) and all(k["aspect"] == aspect for k in path.keyframes)
    pano = recording.recorded_path(KEYS, perspective=False, pano_height=256, fps=10, aspect=1.7)
    assert (pano.render_width, pano.render_height) == (512, 256)
    assert np.allclose(pano.aspect, 2.0) and all(k["aspect"] == 2.0 for k in pano.keyframes)
    ok, message = recording.save_path_file(tmp_path / "p.json", path)
    assert ok and "saved 40 cameras" in message
    back = read_camera_path(tmp_path / "p.json")
    assert back.seconds == pytest.approx(len(back) / back.fps)
    assert np.allclose(back.fov, path.fov)


def test_a_saved_path_reads_back_as_its_keyframes_and_any_path_as_its_cameras(tmp_path):
    """What O saves comes back as the same keyframes (pose, fov, transition); a path without
    keyframes (written by hand, by another tool) gives at most MAX_LOADED_KEYFRAMES of its
    cameras, first and last kept, timed to the path's duration."""
    path = recording.recorded_path(KEYS, perspective=True, pano_height=256, fps=10, aspect=2.0)
    assert recording.save_path_file(tmp_path / "p.json", path)[0]
    back = recording.keyframes_from_path(read_camera_path(tmp_path / "p.json"))
    assert len(back) == len(KEYS)
    for a, b in zip(back, KEYS, strict=True):
        assert np.allclose(a.c2w, b.c2w) and a.fov == b.fov and a.transition == b.transition
    path = recording.recorded_path(KEYS, perspective=True, pano_height=256, fps=30, aspect=2.0)
    path = dataclasses.replace(path, keyframes=None)
    cams = recording.keyframes_from_path(path)
    assert len(cams) == recording.MAX_LOADED_KEYFRAMES < len(path)
    assert np.allclose(cams[0].c2w, path.poses[0]) and np.allclose(cams[-1].c2w, path.poses[-1])
    total = sum(k.transition for k in cams[:-1])
    assert total == pytest.approx(path.seconds)


@pytest.mark.parametrize(
    ("change", "says"),
    [
        ({"matrix": "abc"}, "keyframes[1].matrix: expected 16 numbers"),
        ({"matrix": [1.0] * 15}, "keyframes[1].matrix: expected 16 numbers"),
        ({"matrix": ["1"] * 16}, "keyframes[1].matrix: expected 16 numbers"),
        ({"far": 1e12}, "farther than 1e+09 m"),
        ({"far": 1e308}, "farther than 1e+09 m"),
        ({"scale": 2.0}, "not orthonormal"),
        ({"mirror": True}, "reflection"),
        ({"fov": -30}, "keyframes[1].fov"),
        ({"fov": 1e9}, "keyframes[1].fov"),
        ({"fov": "75"}, "keyframes[1].fov"),
        ({"override_transition_sec": 1e9}, "override_transition_sec"),
        ({"override_transition_sec": 0}, "override_transition_sec"),
        ({"override_transition_sec": float("nan")}, "override_transition_sec"),
    ],
)
def test_bad_keyframes_are_refused_naming_the_field(change, says):
    """A saved path's keyframe that the viewer cannot use (not 16 numbers, not a rigid pose,
    beyond 1e9 m, a field of view or transition out of range) is refused, naming it: never
    replaced by the path's cameras without a word, never a crash when the path is saved."""
    path = recording.recorded_path(KEYS, perspective=True, pano_height=256, fps=10, aspect=2.0)
    keys = [dict(k) for k in path.keyframes]
    m = np.asarray(keys[1]["matrix"], np.float64).reshape(4, 4).T
    if "far" in change:
        m[0, 3] = change.pop("far")
    if change.pop("scale", None):
        m[:3, :3] *= 2.0
    if change.pop("mirror", None):
        m[:3, 0] *= -1.0
    keys[1]["matrix"] = m.T.reshape(16).tolist()
    keys[1].update(change)
    with pytest.raises(ValueError, match=re.escape(says)):
        recording.keyframes_from_path(dataclasses.replace(path, keyframes=keys))
    with pytest.raises(ValueError, match="keyframes: expected a list"):
        recording.keyframes_from_path(dataclasses.replace(path, keyframes={"a": 1}))


def test_playback_pose_at_a_time_follows_the_transitions():
    pose, fov = recording.pose_at(KEYS, 1.0)  # the second keyframe, reached after 1 s
    assert np.allclose(pose, KEYS[1].c2w, atol=1e-9) and fov == pytest.approx(90.0)
    pose, fov = recording.pose_at(KEYS, 2.5)  # half way through the 3 s transition
    assert 1.0 < pose[0, 3] < 2.0 and fov == pytest.approx(65.0)


@pytest.mark.parametrize("where", ["missing", "folder", "file_parent"])
def test_failed_saves_say_why_and_do_not_raise(tmp_path, where):
    (tmp_path / "a_file").write_text("x")
    (tmp_path / "a_folder").mkdir()
    out = {
        "missing": tmp_path / "nope" / "path.json",
        "folder": tmp_path / "a_folder",
        "file_parent": tmp_path / "a_file" / "path.json",
    }[where]
    path = recording.recorded_path(KEYS, False, 64, 10, 2.0)
    ok, message = recording.save_path_file(out, path)
    assert not ok and str(out) in message and "keyframes kept" in message
    assert {"missing": "does not exist", "folder": "is a folder", "file_parent": "not a folder"}[
        where
    ] in message
    ok, problem = recording.save_image_file(
        out.with_suffix(".png") if where != "folder" else out, np.zeros((4, 8, 3), np.uint8)
    )
    assert not ok and problem


def test_letterbox_keeps_two_to_one():
    assert screen.letterbox(1024, 512) == (0, 0, 1024, 512)
    assert screen.letterbox(1000, 800) == (0, 150, 1000, 500)  # bars above and below
    assert screen.letterbox(1600, 400) == (400, 0, 800, 400)  # bars left and right


def test_overlay_lines_wrap_inside_the_box():
    long = "cannot save the camera path /a/very/long/folder/" + "x" * 120 + " : no such folder"
    lines = screen.wrap_to_width(long)
    assert len(lines) > 2 and " ".join(lines).replace(" ", "") == long.replace(" ", "")
    box = screen.OVERLAY_WIDTH - 2 * screen.MARGIN
    assert all(screen.text_width(line) <= box for line in lines)
    img = screen.overlay_image(["pos +0.00 +0.00 +0.00 m", long])
    assert img.shape[0] == screen.ROW * (1 + len(lines)) + 8
    assert screen.wrap_to_width("") == [""]


def test_overlay_messages_are_whole_recent_and_said_once():
    """Old messages expire, a long one is never cut to its tail, a repeated one shows once."""
    m = screen.Messages()
    m.add("playing 3 keyframes, 6.0 s", now=0.0)
    long = "a message long enough to need three lines on the overlay " * 3
    m.add(long, now=1.0)
    m.add("keyframe 2 added (fov 75 deg)", now=2.0)
    shown = m.lines(now=2.5)
    wrapped = screen.wrap_to_width(long)
    assert len(wrapped) == 3 and shown == [*wrapped, "keyframe 2 added (fov 75 deg)"]
    assert "playing" not in " ".join(shown)  # it would have fitted only as a fragment
    m.add("keyframe 2 added (fov 75 deg)", now=3.0)
    assert m.lines(now=3.0).count("keyframe 2 added (fov 75 deg)") == 1
    assert m.lines(now=1.0 + screen.MESSAGE_SECONDS + 0.1) == ["keyframe 2 added (fov 75 deg)"]
    assert m.lines(now=100.0) == []


def test_overlay_says_refined_only_when_shown_with_overall_progress():
    levels = [(256, "draft", 2), (512, "fast", None)]
    assert screen.shown_label("refined", None, 2, 0).startswith("GL preview")
    # --no-refine: nothing to wait for, so no "not ready" beside "refinement off" (issue 55)
    assert screen.shown_label("refined", None, 0, 0, refining=False) == "GL preview"
    assert screen.shown_label("preview", None, 2, 0) == "GL preview"
    assert screen.shown_label("refined", 0, 2, 0) == "refined level 1/2"
    assert screen.shown_label("sources", None, 2, 3) == "source view 3"
    # Level 1 done, half of level 2: the overall share counts level 2's four times the pixels.
    status = screen.refine_status(True, True, 1, 0.5, levels)
    assert "refining level 2/2 (50%)" in status and "60% overall" in status
    assert screen.overall_progress(0, 0.5, screen.level_weights(levels)) == pytest.approx(0.1)
    assert "refined" not in screen.refine_status(True, False, 0, 0.0, levels)


def test_distance_legend_and_exit_summary_in_level_order():
    plain = screen.overlay_image(["a", "b"])
    legend = screen.overlay_image(["a", "b"], legend=True)
    assert legend.shape[0] == plain.shape[0] + screen.ROW
    bar = legend[2 * screen.ROW + 10, 40:240, :3].astype(int)
    assert bar[0, 2] > bar[0, 0] and bar[-1, 0] > bar[-1, 2]  # blue (near) to red (far)
    log = [(1, 1.5), (0, 0.4), (0, 0.6), (1, 1.7)]
    lines = screen.refine_summary(log, 2)
    assert lines[0].startswith("refined level 1/2 0.50 s") and lines[1].startswith("level 2/2", 8)


def test_level_pose_drops_the_pitch():
    cam = FlyCamera(np.array([1.0, 2.0, 3.0]), yaw=0.4, pitch=0.7)
    level = FlyCamera.from_c2w(cam.level_c2w)
    assert level.yaw == pytest.approx(0.4) and level.pitch == pytest.approx(0.0)
    assert np.allclose(cam.level_c2w[:3, 3], cam.position)


def test_behind_surface_finds_a_camera_inside_an_object():
    sources = np.tile(np.eye(4), (2, 1, 1))
    sources[1, 0, 3] = 5.0
    depth = np.full((2, 8, 16), 3.0)  # every source sees a surface 3 m away all round
    assert behind_surface(np.array([1.0, 0.0, 0.0]), sources, depth) is None
    found = behind_surface(np.array([0.0, 0.0, -4.0]), sources, depth)
    assert found is not None and found[0] == 0 and found[1] == pytest.approx(4.0)
    assert found[2] == pytest.approx(3.0)
    depth[0] = 0.0  # unknown depth: no claim
    assert behind_surface(np.array([0.0, 0.0, -4.0]), sources, depth) is None
    assert math.isfinite(found[1])


def test_keyframes_can_be_gone_to_deleted_and_retimed():
    session = recording.KeyframeSession()
    assert "no keyframes" in session.edit("G", np.eye(4), 75.0)[0]
    for k in KEYS:
        session.edit("K", k.c2w, k.fov)
    assert session.selected == 2
    message, go = session.edit("G", np.eye(4), 75.0)  # from the last added: wraps to the first
    assert go is session.keys[0] and "1/3" in message
    message, go = session.edit("G", np.eye(4), 75.0)
    assert go is session.keys[1] and go.fov == 90.0
    message, _ = session.edit("PERIOD", np.eye(4), 75.0)
    assert session.keys[1].transition == 2.5 and "path 4.5 s" in message
    for _ in range(10):
        session.edit("COMMA", np.eye(4), 75.0)
    assert session.keys[1].transition == recording.RETIME_STEP_S  # never below one step
    message, _ = session.edit("BACKSPACE", np.eye(4), 75.0)
    assert (
        len(session.keys) == 2 and session.keys[1].fov == 40.0 and "keyframe 2 deleted" in message
    )
    assert session.selected == 1


def test_playback_runs_on_the_clock_and_stops_where_it_is():
    session = recording.KeyframeSession()
    session.edit("K", KEYS[0].c2w, 60.0)
    assert "at least two" in session.toggle_playback()
    session.edit("K", KEYS[1].c2w, 90.0)  # a 2 s transition
    assert "2.0 s" in session.toggle_playback()
    pose, fov, done = session.advance(0.5)
    assert np.allclose(pose, KEYS[0].c2w) and not done
    pose, fov, done = session.advance(0.5)  # 0.5 s in: a quarter of the way, by the clock
    assert fov == pytest.approx(67.5) and not done
    session.advance(10.0)
    pose, fov, done = session.advance(0.1)
    assert done and np.allclose(pose, KEYS[1].c2w, atol=1e-9) and session.playback is None
    session.toggle_playback()
    session.advance(0.3)
    assert session.toggle_playback() == "playback stopped" and session.play_pose is None
