"""Synthetic scenes: layout rules, determinism, disjoint splits, GL depth vs ray casting."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch
import trimesh

from panogrf.app.synth.layout import LayoutConfig, generate_layout
from panogrf.app.synth.make import (
    MakeConfig,
    build_scene,
    build_textures,
    make_dataset,
    scene_seed,
)
from panogrf.app.synth.textures import photo_names, texture_bank


def _horizontal_distance_to_segment(p, a, b):
    ab = b - a
    t = np.clip(np.dot(p - a, ab) / np.dot(ab, ab), 0, 1)
    return np.linalg.norm(p - (a + t * ab))


@pytest.mark.parametrize("seed", range(12))
def test_layout_rules(seed):
    cfg = LayoutConfig()
    scene = generate_layout(seed, "train", n_layers=10, config=cfg)
    cams = scene.cameras
    pos = cams[:, :3, 3]
    # Three cameras on a line, middle at the midpoint, baseline in range, heights in range.
    assert np.allclose(pos[1], 0.5 * (pos[0] + pos[2]))
    assert cfg.baseline[0] - 1e-9 <= np.linalg.norm(pos[2] - pos[0]) <= cfg.baseline[1] + 1e-9
    assert np.all((pos[:, 1] >= 1.2) & (pos[:, 1] <= 1.7))
    # Rigid, upright poses; headings differ from camera to camera.
    for c2w in cams:
        r = c2w[:3, :3]
        assert np.allclose(r.T @ r, np.eye(3), atol=1e-9) and np.isclose(np.linalg.det(r), 1.0)
        assert np.allclose(r[:, 1], [0, 1, 0])
    yaws = np.arctan2(cams[:, 0, 2], cams[:, 2, 2])
    assert len(np.unique(np.round(yaws, 6))) == 3
    # Cameras inside room A and never inside or against an object: every object's vertices stay
    # horizontally clear of the camera line.
    lx, _, lz = scene.meta["room_a"]
    assert np.all((pos[:, 0] > 0) & (pos[:, 0] < lx) & (pos[:, 2] > 0) & (pos[:, 2] < lz))
    a, b = pos[0, [0, 2]], pos[2, [0, 2]]
    for obj in scene.objects:
        if obj.name[:2] not in ("A_", "B_"):
            continue
        d = min(_horizontal_distance_to_segment(v[[0, 2]], a, b) for v in obj.mesh.vertices)
        assert d > cfg.camera_clearance - 0.15, obj.name  # footprint circles are conservative
    assert scene.merged_mesh().faces.shape[0] < 50_000


def test_fixed_baseline_and_determinism():
    s1 = generate_layout(5, "test", n_layers=8, baseline=2.0)
    s2 = generate_layout(5, "test", n_layers=8, baseline=2.0)
    assert np.isclose(np.linalg.norm(s1.cameras[2, :3, 3] - s1.cameras[0, :3, 3]), 2.0)
    assert np.array_equal(s1.cameras, s2.cameras)
    assert np.array_equal(s1.merged_mesh().vertices, s2.merged_mesh().vertices)
    s3 = generate_layout(6, "test", n_layers=8, baseline=2.0)
    assert not np.array_equal(s1.cameras, s3.cameras)


def test_splits_are_disjoint():
    train = {scene_seed("train", s, i) for s in range(3) for i in range(200)}
    test = {scene_seed("test", s, i) for s in range(3) for i in range(200)}
    assert not train & test
    assert not set(photo_names("train")) & set(photo_names("test"))
    rng = np.random.default_rng(0)
    a = texture_bank("train", rng, 8)
    b = texture_bank("test", rng, 8)
    assert a.dtype == np.float32 and a.min() >= 0 and a.max() <= 1
    # No texture layer of one split appears in the other.
    for layer in b:
        assert np.min(np.abs(a - layer[None]).mean(axis=(1, 2, 3))) > 0.01


def _planes(mesh: trimesh.Trimesh, c2w, height, width) -> np.ndarray:
    """Plane (n, n.x) of the first surface hit by each pixel ray [H, W, 4] (NaN: no hit)."""
    from panogrf.app.synth.raycast import first_hits

    tri = first_hits(mesh, c2w, height, width)
    safe = np.maximum(tri, 0)
    normals = mesh.face_normals[safe]
    offsets = np.einsum("ij,ij->i", normals, mesh.vertices[mesh.faces[safe, 0]])
    plane = np.concatenate([normals, offsets[:, None]], 1)
    plane[tri < 0] = np.nan
    return plane.reshape(height, width, 4)


def _interior_mask(mesh: trimesh.Trimesh, c2w, height, width, factor=3) -> np.ndarray:
    """Pixels whose whole 3x3-pixel neighbourhood, ray cast 3x finer, sees the pixel's plane.

    There the depth is a smooth function of direction and must be exact; elsewhere (edges,
    creases, objects thinner than a pixel) GL and ray casting sample different surfaces.
    """
    lo = _planes(mesh, c2w, height, width)
    hi = _planes(mesh, c2w, height * factor, width * factor)
    r = factor + factor // 2  # fine samples from the centre to the edge of the 3x3 window
    padded = np.pad(hi, ((r, r), (0, 0), (0, 0)), mode="edge")
    padded = np.concatenate([padded[:, -r:], padded, padded[:, :r]], 1)  # wrap in longitude
    ok = np.isfinite(lo).all(-1)
    c = factor // 2  # fine sample at the centre of a coarse pixel
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            sub = padded[r + c + dy :: factor, r + c + dx :: factor][:height, :width]
            ok &= np.all(np.abs(sub - lo) < 1e-6, axis=-1)
    return ok


@pytest.mark.gl
@pytest.mark.slow
@pytest.mark.parametrize("split,seed", [("train", 3), ("test", 7)])
def test_gl_depth_matches_ray_casting(split, seed):
    from panogrf.app.synth.gl_render import PanoramaRenderer
    from panogrf.app.synth.raycast import raycast_depth

    textures, _ = build_textures(split, 0, procedural=4)
    scene = build_scene(split, seed, baseline=1.5, n_layers=len(textures))
    mesh = scene.merged_mesh()
    height, width = 48, 96
    with PanoramaRenderer() as renderer:
        renderer.set_textures(textures)
        renderer.set_scene(scene)
        for c2w in scene.cameras[[0, 2]]:
            rgb, depth = renderer.render(c2w, height, width)
            ref = raycast_depth(mesh, c2w, height, width)
            assert rgb.shape == (height, width, 3) and rgb.dtype == np.uint8
            assert np.all(ref > 0), "rooms are closed: every ray hits something"
            assert np.all(depth > 0) and np.all(np.isfinite(depth))
            interior = _interior_mask(mesh, c2w, height, width)
            assert interior.mean() > 0.6
            err = np.abs(depth - ref)
            assert err[interior].max() < 0.01, "GL depth must agree with ray casting within 1 cm"
            assert np.median(err) < 1e-3
            assert (err < 0.01).mean() > 0.9  # edges and creases included


@pytest.mark.gl
def test_make_dataset_writes_scene_folders(tmp_path):
    from panogrf.app.files.images import read_depth, read_rgb

    summary = make_dataset(
        MakeConfig(out=tmp_path, split="test", count=2, height=16, baselines=(1.0, 2.0)),
        progress=False,
    )
    assert summary["panoramas"] == 6
    index = json.loads((tmp_path / "dataset.json").read_text())
    assert [e["folder"] for e in index["scenes"]] == ["test_00000", "test_00001"]
    for entry, baseline in zip(index["scenes"], (1.0, 2.0), strict=True):
        meta = json.loads((tmp_path / entry["folder"] / "transforms.json").read_text())
        assert meta["camera_model"] == "EQUIRECTANGULAR" and (meta["w"], meta["h"]) == (32, 16)
        pos = np.array([f["transform_matrix"] for f in meta["frames"]])[:, :3, 3]
        assert np.isclose(np.linalg.norm(pos[2] - pos[0]), baseline)
        for frame in meta["frames"]:
            rgb = read_rgb(tmp_path / entry["folder"] / frame["file_path"])
            depth = read_depth(tmp_path / entry["folder"] / frame["depth_file_path"])
            assert rgb.shape == (16, 32, 3) and depth.shape == (16, 32)
            assert depth.min() > 0.05 and depth.max() < 30
    # Same seed, same bytes.
    again = tmp_path / "again"
    make_dataset(MakeConfig(out=again, split="test", count=1, height=16, baselines=(1.0,)), False)
    a = (tmp_path / "test_00000" / "images" / "frame_001.png").read_bytes()
    assert a == (again / "test_00000" / "images" / "frame_001.png").read_bytes()


@pytest.mark.gl
def test_no_cracks_where_clipped_triangles_meet():
    """Regression: near-plane clipping of the huge floor triangles left a one-texel crack right
    below this camera (depth 0, a black dot). Every ray in a closed room must hit something."""
    from panogrf.app.synth.gl_render import PanoramaRenderer

    textures, _ = build_textures("test", 99, 32)
    scene = build_scene("test", scene_seed("test", 99, 0), 1.0, len(textures))
    with PanoramaRenderer() as renderer:
        renderer.set_textures(textures)
        renderer.set_scene(scene)
        for c2w in scene.cameras:
            rgb, depth = renderer.render(c2w, 256, 512)
            assert np.all(depth > 0)
            assert rgb.reshape(-1, 3).max(axis=1).min() > 0  # no black holes in colour either


@pytest.mark.gl
def test_merge_datasets_links_every_scene(tmp_path):
    from panogrf.app.errors import UserError
    from panogrf.app.synth.merge import merge_datasets
    from panogrf.app.train.data import load_triplets

    make_dataset(MakeConfig(out=tmp_path / "a", count=2, height=16), progress=False)
    make_dataset(MakeConfig(out=tmp_path / "b", count=1, height=16, start=5), progress=False)
    summary = merge_datasets(tmp_path / "ab", [tmp_path / "a", tmp_path / "b"])
    assert summary == {"scenes": 3, "sources": 2}
    merged = load_triplets(tmp_path / "ab", 16)
    assert merged.names == ["train_00000", "train_00001", "train_00005"]
    alone = load_triplets(tmp_path / "b", 16)
    assert torch.equal(merged.images[2], alone.images[0])
    assert (tmp_path / "ab" / "train_00005").resolve() == (tmp_path / "b" / "train_00005").resolve()
    merge_datasets(tmp_path / "ab", [tmp_path / "a", tmp_path / "b"])  # again: no change
    # One source twice, the same scene names in two sources, or a source that is no
    # dataset: refused.
    with pytest.raises(UserError, match="listed twice"):
        merge_datasets(tmp_path / "aa", [tmp_path / "a", tmp_path / "a"])
    shutil.copytree(tmp_path / "a", tmp_path / "a2")
    with pytest.raises(UserError, match="in both"):
        merge_datasets(tmp_path / "aa", [tmp_path / "a", tmp_path / "a2"])
    with pytest.raises(UserError, match="no dataset.json"):
        merge_datasets(tmp_path / "ax", [tmp_path / "a", tmp_path / "missing"])
    assert not (tmp_path / "ax").exists()  # nothing written on a refusal


def test_dataset_options_check_themselves_and_give_the_make_config(tmp_path):
    from panogrf.app.commands.dataset import MakeOptions, MergeOptions, PackOptions
    from panogrf.app.errors import UserError

    with pytest.raises(UserError, match="^--coves needs --world home$"):
        MakeOptions(out=tmp_path, coves=0.5)
    with pytest.raises(UserError, match="^--workers must be at least 1, got 0$"):
        MakeOptions(out=tmp_path, workers=0)
    options = MakeOptions(out=tmp_path, world="home", sheers=0.5, seed=3, progress=False)
    assert options.config() == MakeConfig(out=tmp_path, world="home", sheers=0.5, seed=3)
    with pytest.raises(UserError, match="^--height must be a multiple of 32, got 100$"):
        PackOptions(out=tmp_path / "p" / "x.safetensors", height=100, sources=[])
    assert (tmp_path / "p").is_dir()  # the pack's folder is made as before
    assert MergeOptions(out=tmp_path, sources=[tmp_path]).sources == [tmp_path]
