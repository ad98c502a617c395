"""Scene folders: write -> load round trip, and one test per kind of bad input.

Every problem message must name the file or field (and frame index) and say what is wrong.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from panogrf.app.errors import UserError
from panogrf.app.scene.folder import (
    SceneError,
    check_scene,
    inspect_scene,
    load_scene,
    write_scene,
)

H, W = 16, 32


def make_scene(root: Path, views: int = 3, depth: bool = True, seed: int = 0) -> Path:
    """A tiny valid scene: views 0.5 m apart along x, random pixels and depth."""
    rng = np.random.default_rng(seed)
    c2w = np.stack([np.eye(4)] * views)
    c2w[:, 0, 3] = 0.5 * np.arange(views)
    images = rng.random((views, 3, H, W), dtype=np.float32)
    depths = rng.uniform(0.5, 5.0, (views, 1, H, W)) if depth else None
    write_scene(root, c2w, images, depths, metadata={"seed": seed, "baseline": 0.5 * (views - 1)})
    return root


def edit_transforms(root: Path, edit) -> None:
    data = json.loads((root / "transforms.json").read_text())
    edit(data)
    (root / "transforms.json").write_text(json.dumps(data))


def set_matrix(i, value):
    def edit(data):
        data["frames"][i]["transform_matrix"] = value

    return edit


def only_problem(root: Path) -> str:
    problems = check_scene(root)
    assert len(problems) == 1, problems
    return problems[0]


@pytest.fixture
def scene_dir(tmp_path) -> Path:
    return make_scene(tmp_path / "scene")


# --- valid scenes ----------------------------------------------------------------------------


def test_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    c2w = np.stack([np.eye(4)] * 2)
    angle = 0.3  # a yaw, so the rotation is non-trivial
    c2w[1, :3, :3] = [
        [np.cos(angle), 0, np.sin(angle)],
        [0, 1, 0],
        [-np.sin(angle), 0, np.cos(angle)],
    ]
    c2w[1, :3, 3] = (0.2, -0.1, 1.0)
    images = torch.from_numpy(rng.random((2, 3, H, W), dtype=np.float32))
    depths = rng.uniform(0.5, 5.0, (2, 1, H, W))
    written = write_scene(tmp_path, c2w, images, depths, names=["a", "b"], metadata={"seed": 7})

    scene = load_scene(tmp_path, load_images=True)
    assert (scene.width, scene.height, scene.num_views) == (W, H, 2)
    assert [f.name for f in scene.frames] == ["a", "b"] == [f.name for f in written.frames]
    assert scene.frames[1].image_path == tmp_path / "images" / "b.png"
    assert scene.frames[1].depth_path == tmp_path / "depths" / "b.png"
    assert scene.metadata == {"seed": 7}
    np.testing.assert_array_equal(scene.c2w, c2w)  # JSON keeps float64 exactly
    loaded = scene.images
    assert loaded.images.shape == (2, 3, H, W) and loaded.images.dtype == torch.float32
    assert (loaded.images - images).abs().max() <= 0.5 / 255 + 1e-6
    assert loaded.c2w.shape == (2, 4, 4)
    assert loaded.depths.shape == (2, 1, H, W)
    np.testing.assert_allclose(loaded.depths.numpy(), depths, atol=5e-4 + 1e-6)
    # The lazy path reads the same pixels.
    again = load_scene(tmp_path).load_images()
    assert torch.equal(again.images, loaded.images) and torch.equal(again.depths, loaded.depths)
    assert load_scene(tmp_path).images is None


def test_scene_without_depth_and_with_partial_depth(tmp_path):
    root = make_scene(tmp_path / "s", depth=False)
    scene = load_scene(root, load_images=True)
    assert not scene.has_depth and scene.images.depths is None
    assert inspect_scene(root).depth_range_m is None

    root = make_scene(tmp_path / "p", depth=True)
    edit_transforms(root, lambda d: d["frames"][1].pop("depth_file_path"))
    scene = load_scene(root, load_images=True)
    assert scene.frames[1].depth_path is None
    assert torch.all(scene.images.depths[1] == 0)  # 0 = unknown
    assert torch.all(scene.images.depths[0] > 0)


def test_nerfstudio_extra_keys_are_accepted(scene_dir):
    def edit(data):
        data.update(fl_x=10.0, fl_y=10.0, cx=16.0, cy=8.0, k1=0.0, applied_transform=[[1, 0, 0, 0]])
        data["frames"][0].update(colmap_im_id=1, fl_x=10.0)

    edit_transforms(scene_dir, edit)
    report = inspect_scene(scene_dir)
    assert report.ok and report.notes == ()
    assert report.scene.metadata["fl_x"] == 10.0


def test_depth_range_reported(scene_dir):
    lo, hi = inspect_scene(scene_dir).depth_range_m
    assert 0.5 <= lo < hi <= 5.0


# --- folder and JSON -------------------------------------------------------------------------


def test_missing_folder(tmp_path):
    assert check_scene(tmp_path / "nowhere") == [f"scene folder not found: {tmp_path / 'nowhere'}"]
    (tmp_path / "file").write_text("x")
    assert "not a folder" in only_problem(tmp_path / "file")


def test_missing_transforms(tmp_path):
    assert only_problem(tmp_path) == f"transforms.json: file not found in {tmp_path}"


def test_invalid_json_names_the_line(scene_dir):
    (scene_dir / "transforms.json").write_text('{\n  "w": 32,\n  "h": 16\n  "frames": []\n}')
    assert only_problem(scene_dir).startswith("transforms.json: invalid JSON at line 4, column 3")


def test_unknown_camera_model(scene_dir):
    edit_transforms(scene_dir, lambda d: d.update(camera_model="OPENCV"))
    problem = only_problem(scene_dir)
    assert problem.startswith('transforms.json: camera_model is "OPENCV"')
    assert "EQUIRECTANGULAR" in problem
    edit_transforms(scene_dir, lambda d: d.pop("camera_model"))
    assert "camera_model is missing" in only_problem(scene_dir)


def test_zero_frames(scene_dir):
    edit_transforms(scene_dir, lambda d: d.update(frames=[]))
    assert (
        only_problem(scene_dir)
        == "transforms.json: frames is empty; a scene needs at least one view"
    )


def test_missing_w_and_h(scene_dir):
    edit_transforms(scene_dir, lambda d: [d.pop("w"), d.pop("h")])
    problems = check_scene(scene_dir)
    assert problems == [
        "transforms.json: w is missing (panorama width in pixels)",
        "transforms.json: h is missing (panorama height in pixels)",
    ]


def test_w_h_differ_from_images(scene_dir):
    edit_transforms(scene_dir, lambda d: d.update(w=64, h=32))
    assert only_problem(scene_dir) == (
        "transforms.json: w=64, h=32 but the images are 32x16 (width x height)"
    )
    edit_transforms(scene_dir, lambda d: d.update(w="wide"))
    assert 'w must be a positive integer, got "wide"' in check_scene(scene_dir)[0]
    for bad in (math.inf, -math.inf, math.nan):  # JSON's Infinity and NaN, which Python reads
        edit_transforms(scene_dir, lambda d, bad=bad: d.update(w=32, h=bad))
        assert "h must be a positive integer, got " in check_scene(scene_dir)[0]


def test_images_not_2_to_1(scene_dir):
    for i in range(3):
        cv2.imwrite(
            str(scene_dir / "images" / f"view_{i:03d}.png"), np.zeros((16, 40, 3), np.uint8)
        )
    edit_transforms(scene_dir, lambda d: d.update(w=40))
    for i in range(3):  # keep the depth maps out of it
        edit_transforms(scene_dir, lambda d, i=i: d["frames"][i].pop("depth_file_path"))
    assert only_problem(scene_dir) == (
        "frames[0].file_path (images/view_000.png): image is 40x16 (width x height), not 2:1; "
        "an equirectangular panorama has width = 2 x height"
    )


def test_views_of_different_sizes(scene_dir):
    cv2.imwrite(str(scene_dir / "images" / "view_002.png"), np.zeros((32, 64, 3), np.uint8))
    problems = check_scene(scene_dir)
    assert (
        "frames[2].file_path (images/view_002.png): image is 64x32 but frames[0] "
        "(images/view_000.png) is 32x16; all views must have the same size"
    ) in problems
    # Its depth map (32x16) no longer matches its image either: reported, not hidden.
    assert any(p.startswith("frames[2].depth_file_path") for p in problems)


# --- images ----------------------------------------------------------------------------------


def test_missing_image(scene_dir):
    (scene_dir / "images" / "view_001.png").unlink()
    assert only_problem(scene_dir) == "frames[1].file_path (images/view_001.png): file not found"
    edit_transforms(scene_dir, lambda d: d["frames"][1].pop("file_path"))
    assert only_problem(scene_dir) == "frames[1].file_path is missing"


def test_unreadable_image(scene_dir):
    (scene_dir / "images" / "view_001.png").write_bytes(b"\x89PNG garbage")
    assert only_problem(scene_dir).startswith(
        "frames[1].file_path (images/view_001.png): not a readable image"
    )


def test_absolute_image_path_is_refused(scene_dir):
    absolute = str((scene_dir / "images" / "view_000.png").resolve())
    edit_transforms(scene_dir, lambda d: d["frames"][0].update(file_path=absolute))
    assert only_problem(scene_dir).endswith("must be relative to the scene folder")


def test_gray_rgba_and_16_bit_images_are_converted_with_notes(scene_dir):
    rng = np.random.default_rng(3)
    cv2.imwrite(
        str(scene_dir / "images" / "view_000.png"), rng.integers(0, 256, (H, W), dtype=np.uint8)
    )
    bgra = rng.integers(0, 256, (H, W, 4), dtype=np.uint8)
    bgra[..., 3] = 255
    cv2.imwrite(str(scene_dir / "images" / "view_001.png"), bgra)
    cv2.imwrite(str(scene_dir / "images" / "view_002.png"), np.full((H, W, 3), 65535, np.uint16))
    report = inspect_scene(scene_dir)
    assert report.ok, report.problems
    assert report.notes == (
        "frames[0] (images/view_000.png): grayscale converted to RGB",
        "frames[1] (images/view_001.png): opaque alpha channel dropped",
        "frames[2] (images/view_002.png): 16-bit converted to 8-bit",
    )
    images = load_scene(scene_dir, load_images=True).images.images
    assert images.shape == (3, 3, H, W)
    assert torch.equal(images[0, 0], images[0, 2]) and torch.all(images[2] == 1.0)


def test_transparent_image_is_refused(scene_dir):
    bgra = np.full((H, W, 4), 255, np.uint8)
    bgra[0, :, 3] = 0
    cv2.imwrite(str(scene_dir / "images" / "view_001.png"), bgra)
    problem = only_problem(scene_dir)
    assert problem.startswith(
        "frames[1].file_path (images/view_001.png): alpha channel is not fully opaque"
    )


# --- transforms ------------------------------------------------------------------------------


def test_transform_not_4x4(scene_dir):
    edit_transforms(scene_dir, set_matrix(1, np.eye(4)[:3].tolist()))
    assert only_problem(scene_dir) == "frames[1].transform_matrix: expected a 4x4 matrix, got 3x4"
    edit_transforms(scene_dir, set_matrix(1, [[1, 0, 0, 0], [0, 1, 0]]))
    assert only_problem(scene_dir) == (
        "frames[1].transform_matrix: is not a rectangular list of numbers"
    )
    edit_transforms(scene_dir, lambda d: d["frames"][1].pop("transform_matrix"))
    assert only_problem(scene_dir).startswith("frames[1].transform_matrix is missing")


def test_transform_not_numbers(scene_dir):
    m = np.eye(4).tolist()
    m[0][1] = "zero"
    edit_transforms(scene_dir, set_matrix(2, m))
    assert only_problem(scene_dir) == 'frames[2].transform_matrix: contains a non-number ("zero")'


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_transform_nan_or_inf(scene_dir, bad):
    m = np.eye(4)
    m[1, 3] = bad
    edit_transforms(scene_dir, set_matrix(1, m.tolist()))  # json writes NaN / Infinity
    assert only_problem(scene_dir) == "frames[1].transform_matrix: contains NaN or infinite values"


def test_rotation_not_orthonormal(scene_dir):
    m = np.eye(4)
    m[0, 3] = 0.5
    m[0, 0] = 1.3
    edit_transforms(scene_dir, set_matrix(1, m.tolist()))
    assert only_problem(scene_dir) == (
        "frames[1].transform_matrix: rotation is not orthonormal (max |R^T R - I| = 0.69)"
    )


def test_rotation_within_tolerance_is_accepted(scene_dir):
    m = np.eye(4)
    m[0, 3] = 0.5
    m[0, 0] += 2e-5  # float32-style rounding in someone else's exporter
    edit_transforms(scene_dir, set_matrix(1, m.tolist()))
    assert check_scene(scene_dir) == []


def test_reflection_is_refused(scene_dir):
    m = np.diag([1.0, 1.0, -1.0, 1.0])
    m[0, 3] = 0.5
    edit_transforms(scene_dir, set_matrix(1, m.tolist()))
    assert only_problem(scene_dir) == (
        "frames[1].transform_matrix: rotation is a reflection (det = -1); expected det = +1"
    )


def test_last_row(scene_dir):
    m = np.eye(4)
    m[0, 3] = 0.5
    m[3, 2] = 1.0
    edit_transforms(scene_dir, set_matrix(1, m.tolist()))
    assert only_problem(scene_dir) == (
        "frames[1].transform_matrix: last row is [0, 0, 1, 1], expected [0, 0, 0, 1]"
    )


def test_views_at_the_same_position(scene_dir):
    m = np.eye(4)
    m[0, 3] = 0.5 + 3e-4  # 0.3 mm from frames[1]
    edit_transforms(scene_dir, set_matrix(2, m.tolist()))
    assert only_problem(scene_dir) == (
        "frames[1] and frames[2]: views at the same position (0.30 mm apart); "
        "views must be at least 1 mm apart"
    )


# --- depth -----------------------------------------------------------------------------------


def test_depth_size_differs_from_image(scene_dir):
    cv2.imwrite(str(scene_dir / "depths" / "view_000.png"), np.ones((8, 16), np.uint16))
    assert only_problem(scene_dir) == (
        "frames[0].depth_file_path (depths/view_000.png): depth map is 16x8 but its image is "
        "32x16 (width x height)"
    )


def test_depth_not_16_bit_single_channel(scene_dir):
    cv2.imwrite(str(scene_dir / "depths" / "view_001.png"), np.ones((H, W), np.uint8))
    assert only_problem(scene_dir) == (
        "frames[1].depth_file_path (depths/view_001.png): expected a single-channel 16-bit PNG "
        "(depth in millimetres), got 1-channel uint8"
    )
    cv2.imwrite(str(scene_dir / "depths" / "view_001.png"), np.ones((H, W, 3), np.uint16))
    assert "got 3-channel uint16" in only_problem(scene_dir)


def test_missing_depth_file(scene_dir):
    (scene_dir / "depths" / "view_002.png").unlink()
    assert (
        only_problem(scene_dir) == "frames[2].depth_file_path (depths/view_002.png): file not found"
    )


# --- reporting -------------------------------------------------------------------------------


def test_all_problems_are_reported_at_once_and_load_raises(scene_dir):
    (scene_dir / "images" / "view_000.png").unlink()
    (scene_dir / "depths" / "view_002.png").unlink()

    def edit(data):
        data["camera_model"] = "PINHOLE"
        data["frames"][1]["transform_matrix"][0][0] = 2.0

    edit_transforms(scene_dir, edit)
    problems = check_scene(scene_dir)
    assert len(problems) == 4, problems
    with pytest.raises(SceneError) as info:
        load_scene(scene_dir)
    assert isinstance(info.value, UserError)
    assert info.value.problems == tuple(problems)
    # One line for the command's error: the first problem and where to see every one.
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"invalid scene {scene_dir}: {problems[0]}")
    assert message.endswith(f"(and 3 more: panogrf scene check {scene_dir} lists them)")


# --- write_scene refuses bad arrays ----------------------------------------------------------


def test_write_scene_validates_its_inputs(tmp_path):
    c2w = np.stack([np.eye(4)] * 2)
    c2w[1, 0, 3] = 1.0
    ok = np.zeros((2, 3, H, W), np.uint8)
    with pytest.raises(ValueError, match="2:1"):
        write_scene(tmp_path, c2w, np.zeros((2, 3, H, H), np.uint8))
    with pytest.raises(ValueError, match=r"c2w must be \[2, 4, 4\]"):
        write_scene(tmp_path, c2w[:1], ok)
    bad = c2w.copy()
    bad[1, 0, 0] = 3.0
    with pytest.raises(ValueError, match=r"c2w\[1\]: rotation is not orthonormal"):
        write_scene(tmp_path, bad, ok)
    with pytest.raises(ValueError, match="distinct names"):
        write_scene(tmp_path, c2w, ok, names=["a", "a"])
    with pytest.raises(ValueError, match="metadata may not set"):
        write_scene(tmp_path, c2w, ok, metadata={"frames": []})
    with pytest.raises(ValueError, match=r"depths must be \[2, 1, 16, 32\]"):
        write_scene(tmp_path, c2w, ok, np.ones((2, H, W)))
    assert not (tmp_path / "transforms.json").exists()


def test_truncated_jpeg_is_a_problem(scene_dir):
    ok, buf = cv2.imencode(".jpg", np.full((H, W, 3), 90, np.uint8))
    (scene_dir / "images" / "view_001.png").write_bytes(buf.tobytes()[:-40])
    assert only_problem(scene_dir).startswith(
        "frames[1].file_path (images/view_001.png): truncated JPEG"
    )
    with pytest.raises(UserError, match="view_001.png"):
        load_scene(scene_dir, load_images=True)


def test_an_empty_image_file_is_one_problem(scene_dir):
    (scene_dir / "images" / "view_001.png").write_bytes(b"")
    expected = "frames[1].file_path (images/view_001.png): empty file (0 bytes)"
    assert only_problem(scene_dir) == expected


def test_a_scene_error_is_one_line_naming_the_folder_and_the_first_problem(scene_dir):
    from panogrf.app.scene.folder import SceneError

    (scene_dir / "images" / "view_001.png").write_bytes(b"")
    (scene_dir / "images" / "view_002.png").unlink()
    with pytest.raises(SceneError) as err:
        load_scene(scene_dir)
    message = str(err.value)
    assert "\n" not in message and message.startswith(f"invalid scene {scene_dir}: frames[1]")
    assert f"(and 1 more: panogrf scene check {scene_dir} lists them)" in message


def test_the_odd_sized_frame_is_the_one_named(scene_dir):
    cv2.imwrite(str(scene_dir / "images" / "view_000.png"), np.zeros((8, 16, 3), np.uint8))
    problems = check_scene(scene_dir)  # (its depth map no longer fits it either)
    named = [p for p in problems if "all views must have the same size" in p]
    assert named == [
        "frames[0].file_path (images/view_000.png): image is 16x8 but frames[1] "
        "(images/view_001.png) is 32x16; all views must have the same size"
    ]
