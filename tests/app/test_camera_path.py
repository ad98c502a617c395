"""nerfstudio camera_path.json: round trip, a literal nerfstudio file, and clear errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from panogrf.app.errors import UserError
from panogrf.app.paths.camera_path import (
    DEFAULT_FOV_DEG,
    CameraPath,
    duration_note,
    read_camera_path,
    write_camera_path,
)

# As nerfstudio's viewer writes it (render_panel.py `_write_json`), shortened to two cameras.
NERFSTUDIO_SNIPPET = """{
  "default_fov": 75.0,
  "default_transition_sec": 2.0,
  "keyframes": [
    {"matrix": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1], "fov": 75.0, "aspect": 2.0,
     "override_transition_enabled": false, "override_transition_sec": null},
    {"matrix": [0, 0, 1, 1, 0, 1, 0, 0, -1, 0, 0, 0, 0, 0, 0, 1], "fov": 75.0, "aspect": 2.0,
     "override_transition_enabled": false, "override_transition_sec": null}
  ],
  "camera_type": "equirectangular",
  "render_height": 512.0,
  "render_width": 1024.0,
  "fps": 30.0,
  "seconds": 2.0,
  "is_cycle": false,
  "smoothness_value": 0.5,
  "camera_path": [
    {"camera_to_world": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1], "fov": 75.0,
     "aspect": 2.0},
    {"camera_to_world": [0, 0, 1, 1, 0, 1, 0, 0, -1, 0, 0, 0, 0, 0, 0, 1], "fov": 75.0,
     "aspect": 2.0}
  ]
}"""


def _yaw(angle: float, position) -> np.ndarray:
    m = np.eye(4)
    c, s = np.cos(angle), np.sin(angle)
    m[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    m[:3, 3] = position
    return m


def test_reads_a_nerfstudio_file(tmp_path):
    (tmp_path / "camera_path.json").write_text(NERFSTUDIO_SNIPPET)
    path = read_camera_path(tmp_path / "camera_path.json")
    assert len(path) == 2 and path.poses.shape == (2, 4, 4) and path.poses.dtype == np.float64
    np.testing.assert_array_equal(path.poses[1], _yaw(np.pi / 2, (1, 0, 0)).round(12))
    assert (path.camera_type, path.render_width, path.render_height) == (
        "equirectangular",
        1024,
        512,
    )
    assert isinstance(path.render_width, int)
    assert (path.fps, path.seconds, path.is_cycle, path.smoothness_value) == (30.0, 2.0, False, 0.5)
    np.testing.assert_array_equal(path.fov, [75.0, 75.0])
    np.testing.assert_array_equal(path.aspect, [2.0, 2.0])
    assert path.times is None and path.crop is None
    assert path.keyframes == json.loads(NERFSTUDIO_SNIPPET)["keyframes"]
    assert path.extra == {"default_fov": 75.0, "default_transition_sec": 2.0}


def test_nerfstudio_file_round_trips(tmp_path):
    (tmp_path / "in.json").write_text(NERFSTUDIO_SNIPPET)
    write_camera_path(tmp_path / "out.json", read_camera_path(tmp_path / "in.json"))
    original = json.loads(NERFSTUDIO_SNIPPET)
    written = json.loads((tmp_path / "out.json").read_text())
    # Equal as JSON (1024.0 and 1024 compare equal), keyframes untouched.
    assert written == original
    assert written["keyframes"] == original["keyframes"]


def test_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    angles, positions = rng.uniform(-3, 3, 5), rng.normal(size=(5, 3))
    poses = np.stack([_yaw(a, p) for a, p in zip(angles, positions, strict=True)])
    keyframes = [{"matrix": "[1,0,0,0]", "properties": '[["FOV",50],["NAME","Camera 0"]]'}]
    crop = {"crop_center": [0, 0, 0], "crop_scale": [1, 1, 1], "crop_rot": [0, 0, 0]}
    path = CameraPath(
        poses=poses,
        camera_type="perspective",
        render_width=64,
        render_height=48,
        fps=24.0,
        fov=rng.uniform(30, 90, 5),
        times=np.linspace(0, 1, 5),
        keyframes=keyframes,
        smoothness_value=0.25,
        is_cycle=True,
        crop=crop,
        extra={"default_fov": 50.0},
    )
    assert path.seconds == pytest.approx(5 / 24)
    np.testing.assert_array_equal(path.aspect, np.full(5, 64 / 48))
    write_camera_path(tmp_path / "p.json", path)
    back = read_camera_path(tmp_path / "p.json")
    np.testing.assert_array_equal(back.poses, path.poses)
    for name in ("fov", "aspect", "times"):
        np.testing.assert_array_equal(getattr(back, name), getattr(path, name))
    for name in ("camera_type", "render_width", "render_height", "fps", "seconds", "keyframes"):
        assert getattr(back, name) == getattr(path, name), name
    assert (back.smoothness_value, back.is_cycle, back.crop, back.extra) == (
        0.25,
        True,
        crop,
        path.extra,
    )
    # Flattened row-major, one camera per line.
    camera = json.loads((tmp_path / "p.json").read_text())["camera_path"][0]
    assert camera["camera_to_world"] == poses[0].reshape(16).tolist()


def test_equirectangular_cameras_need_no_fov(tmp_path):
    data = json.loads(NERFSTUDIO_SNIPPET)
    for camera in data["camera_path"]:
        del camera["fov"], camera["aspect"]
    (tmp_path / "p.json").write_text(json.dumps(data))
    path = read_camera_path(tmp_path / "p.json")
    np.testing.assert_array_equal(path.fov, [DEFAULT_FOV_DEG] * 2)
    np.testing.assert_array_equal(path.aspect, [2.0, 2.0])


def _problems_for(tmp_path, edit) -> str:
    data = json.loads(NERFSTUDIO_SNIPPET)
    edit(data)
    (tmp_path / "camera_path.json").write_text(json.dumps(data))
    with pytest.raises(UserError) as info:
        read_camera_path(tmp_path / "camera_path.json")
    message = str(info.value)
    assert str(tmp_path / "camera_path.json") in message
    return message


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (lambda d: d.update(camera_path=[]), "camera_path.json: camera_path is empty: no cameras"),
        (lambda d: d.pop("camera_path"), "camera_path is missing"),
        (
            lambda d: d.update(camera_type="fisheye"),
            'camera_path.json: camera_type: expected "equirectangular" or "perspective", '
            'got "fisheye"',
        ),
        (lambda d: d.update(render_width=0), "render_width: expected a positive integer, got 0"),
        (
            lambda d: d.update(render_height=-5),
            "render_height: expected a positive integer, got -5",
        ),
        (
            lambda d: d.update(render_width=10.5),
            "render_width: expected a positive integer, got 10.5",
        ),
        (lambda d: d.pop("render_height"), "render_height is missing"),
        (lambda d: d.update(fps=0), "fps: expected a number in [0.0166667, 1000], got 0"),
        (lambda d: d.update(fps=1e300), "fps: expected a number in [0.0166667, 1000], got 1e+300"),
        (lambda d: d.update(seconds="2"), 'seconds: expected a number in [0.001, 86400], got "2"'),
        (
            lambda d: d["camera_path"][1].update(camera_to_world=[1.0] * 12),
            "camera_path[1].camera_to_world: expected 16 numbers (a row-major 4x4 matrix), "
            "got shape [12]",
        ),
        (
            lambda d: d["camera_path"][0]["camera_to_world"].__setitem__(5, None),
            "camera_path[0].camera_to_world: contains a non-number (null)",
        ),
        (
            lambda d: d["camera_path"][0]["camera_to_world"].__setitem__(3, float("nan")),
            "camera_path[0].camera_to_world: contains NaN or infinite values",
        ),
        (
            lambda d: d["camera_path"][1]["camera_to_world"].__setitem__(0, 0.5),
            "camera_path[1].camera_to_world: rotation is not orthonormal",
        ),
        (
            lambda d: d["camera_path"][1]["camera_to_world"].__setitem__(15, 2.0),
            "camera_path[1].camera_to_world: last row is [0, 0, 0, 2], expected [0, 0, 0, 1]",
        ),
        (
            lambda d: d["camera_path"][0].update(fov=0),
            "camera_path[0].fov: expected degrees in (0, 180), got 0",
        ),
        (
            lambda d: d.update(camera_type="perspective") or d["camera_path"][0].pop("fov"),
            "camera_path[0].fov is missing",
        ),
    ],
)
def test_bad_camera_paths_name_the_field(tmp_path, edit, expected):
    assert expected in _problems_for(tmp_path, edit)


def test_every_problem_is_listed(tmp_path):
    def edit(data):
        data.update(fps=-1, camera_type="orthographic")
        data["camera_path"][1]["camera_to_world"] = "identity"

    message = _problems_for(tmp_path, edit)
    assert "\n" not in message and "(and 2 more: " in message  # one line, every problem
    assert "fps" in message and "camera_type" in message and "camera_path[1]" in message


def test_file_errors(tmp_path):
    with pytest.raises(UserError, match="camera path file not found"):
        read_camera_path(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text('{"fps": 30,\n}')
    with pytest.raises(UserError, match=r"bad\.json: invalid JSON at line 2, column 1"):
        read_camera_path(tmp_path / "bad.json")


def test_constructor_refuses_bad_poses():
    with pytest.raises(ValueError, match=r"\[N, 4, 4\] with N >= 1"):
        CameraPath(poses=np.zeros((0, 4, 4)))
    with pytest.raises(ValueError, match=r"poses\[0\]: rotation is not orthonormal"):
        CameraPath(poses=np.zeros((1, 4, 4)) + np.diag([1, 1, 0, 1]))
    with pytest.raises(ValueError, match="camera_type"):
        CameraPath(poses=np.eye(4)[None], camera_type="fisheye")


def test_seconds_that_disagree_with_the_cameras_are_reported(tmp_path):
    # nerfstudio's snippet: 2 cameras at 30 fps but "seconds": 2.0. A video has one frame per
    # camera, so it lasts 0.07 s: said, not silently ignored.
    file = tmp_path / "camera_path.json"
    file.write_text(NERFSTUDIO_SNIPPET)
    note = duration_note(read_camera_path(file))
    assert note is not None and "seconds 2" in note and "2 cameras" in note and "0.07 s" in note
    poses = np.stack([_yaw(0.1 * i, [0, 0, 0]) for i in range(60)])
    assert duration_note(CameraPath(poses, fps=30.0, seconds=2.0)) is None
    assert duration_note(CameraPath(poses, fps=30.0)) is None  # seconds from the cameras
