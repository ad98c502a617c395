"""The GL preview on headless EGL: the bundled scene's middle view warped from the outer two.

Checked against a golden image (tolerance for GL rasterisation differences; set
PANOGRF_DUMP_GOLDEN=1 to write the actual image beside the golden when the test fails) and,
independently, against the real middle panorama.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from panogrf.app.files.images import read_rgb, write_rgb
from panogrf.app.scene.folder import load_scene
from panogrf.assets import path as asset_path
from panogrf.model.metrics import ws_psnr

GOLDEN = Path(__file__).parent.parent / "golden" / "preview_demo_mid.png"

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def demo():
    data = load_scene(asset_path("demo"), load_images=True).images
    images = (data.images.permute(0, 2, 3, 1).numpy() * 255 + 0.5).astype(np.uint8)
    depth = F.interpolate(data.depths, size=(128, 256), mode="nearest")[:, 0].numpy()
    return data, images, depth


@pytest.fixture(scope="module")
def gl():
    from panogrf.renderer.gl_preview import create_headless_context

    ctx = create_headless_context()
    yield ctx
    ctx.release()


def test_preview_matches_the_golden_image_and_the_real_view(gl, demo):
    from panogrf.renderer.gl_preview import PreviewRenderer

    data, images, depth = demo
    with PreviewRenderer(gl, images[[0, 2]], depth[[0, 2]], data.c2w[[0, 2]].numpy()) as pr:
        rgb, dist = pr.render(data.c2w[1].numpy(), 256)
    assert rgb.shape == (256, 512, 3) and dist.shape == (256, 512)
    assert np.isfinite(dist).all() and (dist > 0).mean() > 0.97  # 0: filled holes
    x = torch.from_numpy(rgb).permute(2, 0, 1)[None].float() / 255
    assert float(ws_psnr(x, data.images[1:2])) > 27.0
    gt = data.depths[1, 0].numpy()
    ok = gt > 0
    assert np.median(np.abs(dist[ok] - gt[ok]) / gt[ok]) < 0.01
    golden = read_rgb(GOLDEN)
    diff = np.abs(rgb.astype(np.int16) - golden.astype(np.int16))
    close = (diff.max(-1) <= 8).mean()
    if close < 0.98 and os.environ.get("PANOGRF_DUMP_GOLDEN"):
        write_rgb(GOLDEN.with_name(GOLDEN.stem + "_actual.png"), rgb)
    assert close >= 0.98, f"{close:.3f} of the pixels within 8 levels of the golden image"


def test_preview_at_a_source_pose_is_that_source(gl, demo):
    from panogrf.renderer.gl_preview import PreviewRenderer

    data, images, depth = demo
    with PreviewRenderer(gl, images, depth, data.c2w.numpy()) as pr:
        rgb, _ = pr.render(data.c2w[0].numpy(), 256)
        # Seam: the first and last columns are neighbours like any other two.
        seam = np.abs(rgb[:, 0].astype(float) - rgb[:, -1].astype(float)).mean()
        inner = np.abs(np.diff(rgb.astype(float), axis=1)).mean()
    x = torch.from_numpy(rgb).permute(2, 0, 1)[None].float() / 255
    assert float(ws_psnr(x, data.images[0:1])) > 30.0
    assert seam < 3 * inner + 2.0


def test_bad_input(gl, demo):
    from panogrf.renderer.gl_preview import PreviewRenderer

    _, images, depth = demo
    with pytest.raises(ValueError, match="disagree"):
        PreviewRenderer(gl, images, depth[:2], np.tile(np.eye(4), (3, 1, 1)))


@pytest.mark.parametrize("rows", [4, 17, 64])
def test_sphere_mesh_tiles_the_bands_between_its_rows(rows):
    from panogrf.renderer.gl_preview import sphere_mesh

    uv, tris = sphere_mesh(rows)
    p = uv[tris].astype(np.float64)
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    area = 0.5 * (e1[:, 0] * e2[:, 1] - e2[:, 0] * e1[:, 1])
    # One winding for all (no folds) and no gaps or overlaps: the areas add up to the band.
    assert (area < 0).all() or (area > 0).all()
    assert np.abs(area).sum() == pytest.approx((rows - 1) / rows, rel=1e-5)
    # Fewer vertices near the poles than at the equator, and fewer triangles than a grid.
    per_row = np.unique(uv[:, 1], return_counts=True)[1]
    assert per_row[0] < per_row[rows // 2] and per_row[rows // 2] >= 2 * rows
    if rows >= 16:
        assert len(tris) < 0.7 * 2 * (rows - 1) * 2 * rows


def test_holes_are_filled_from_their_surroundings(gl, demo):
    """Push-pull: a source that sees nothing behind a wall leaves a hole; the fill takes the
    colours around it, not black, and the distance there stays 0 (unknown)."""
    from panogrf.renderer.gl_preview import PreviewRenderer

    data, images, depth = demo
    d = depth[[0]].copy()
    d[0, 40:60, 100:140] = 0.0  # no depth: the mesh has a hole there
    with PreviewRenderer(gl, images[[0]], d, data.c2w[[0]].numpy()) as pr:
        rgb, dist = pr.render(data.c2w[0].numpy(), 128)
    hole = (slice(40, 60), slice(100, 140))
    assert (dist[hole] == 0).mean() > 0.9
    around = images[0, 76:124, 196:284].reshape(-1, 3).mean(0)  # the source at 256 rows
    filled = rgb[hole].reshape(-1, 3).astype(float)
    assert filled.mean() > 20
    assert np.abs(filled.mean(0) - around).max() < 60


def test_shader_defines():
    from panogrf.shaders import load

    text = load("display.frag", {"PERSPECTIVE": 1, "DEPTH": 0, "FILL": 1})
    lines = text.splitlines()
    assert lines[0].startswith("#version") and lines[1:4] == [
        "#define PERSPECTIVE 1",
        "#define DEPTH 0",
        "#define FILL 1",
    ]


def test_the_viewers_cheaper_blend_matches_the_exact_one(gl, demo):
    """distance=False compares surfaces on the layers' 8-bit log distances instead of the
    depth buffer: the same colours but for a few pixels where two surfaces nearly tie."""
    from panogrf.renderer.gl_preview import PreviewRenderer

    data, images, depth = demo
    with PreviewRenderer(gl, images, depth, data.c2w.numpy()) as pr:
        pose = data.c2w[1].numpy().copy()
        pose[:3, 3] += [0.3, 0.1, -0.4]  # between the sources, none at the camera
        blends = []
        for distance in (True, False):
            out = pr.render_to_framebuffer(pose, 128, distance=distance)
            assert (out.dist is None) != distance
            blends.append(np.frombuffer(out.blend.read(), np.uint8).reshape(128, 256, 4))
    exact, cheap = (b.astype(np.int16) for b in blends)
    assert (exact[..., 3] == cheap[..., 3]).mean() > 0.999  # the same pixels covered
    assert (np.abs(exact - cheap)[..., :3].max(-1) <= 4).mean() > 0.995


def test_more_sources_than_layers_draws_the_nearest(gl, demo):
    from panogrf.renderer.gl_preview import MAX_VIEWS, PreviewRenderer

    data, images, depth = demo
    reps = MAX_VIEWS // 3 + 2  # more sources than MAX_VIEWS
    many = PreviewRenderer(
        gl,
        np.tile(images, (reps, 1, 1, 1)),
        np.tile(depth, (reps, 1, 1)),
        np.tile(data.c2w.numpy(), (reps, 1, 1)),
    )
    with many as pr:
        assert pr.views == 3 * reps > MAX_VIEWS and pr.max_views == MAX_VIEWS
        rgb, _ = pr.render(data.c2w[1].numpy(), 32)
    x = torch.from_numpy(rgb).permute(2, 0, 1)[None].float() / 255
    small = F.interpolate(data.images[1:2], size=(32, 64), mode="area")
    assert float(ws_psnr(x, small)) > 25.0


def _box_room_depth(rows: int, half: tuple[float, float, float]) -> np.ndarray:
    """Spherical distance [rows, 2 rows] from the centre of an axis-aligned box room."""
    from panogrf.model.erp import erp_directions

    d = erp_directions(rows, 2 * rows, dtype=torch.float64).numpy()
    with np.errstate(divide="ignore"):
        t = np.min(np.asarray(half) / np.abs(d), axis=-1)
    return t.astype(np.float32)


@pytest.mark.parametrize("mesh_rows", [32, 64])
def test_oblique_walls_are_kept_and_depth_steps_dropped(gl, mesh_rows):
    """Floors and walls far from the camera are seen obliquely: neighbouring mesh vertices
    differ in depth by more than 15 % at coarse mesh rows, yet they are one surface (kept, no
    holes). A box in front of the wall makes a step in depth: the triangles across it are
    dropped (they would smear a skin between the box and the wall)."""
    from panogrf.renderer.gl_preview import PreviewRenderer, sphere_mesh

    depth = _box_room_depth(128, (4.0, 1.5, 4.0))
    step = depth.copy()
    step[60:68, 100:130] = 1.0  # a box 1 m away in front of a wall about 4 m away
    images = np.full((2, 128, 256, 3), 128, np.uint8)
    c2w = np.tile(np.eye(4), (2, 1, 1))
    _, grid = sphere_mesh(mesh_rows)
    with PreviewRenderer(gl, images[:1], depth[None], c2w[:1], mesh_rows) as pr:
        (room,) = pr.triangles
        _, dist = pr.render(np.eye(4), 64)
    with PreviewRenderer(gl, images[:1], step[None], c2w[:1], mesh_rows) as pr:
        (with_box,) = pr.triangles
    # A fixed ratio of 1.15 dropped 28 % of this room's triangles at 32 rows, 1.3 % at 64.
    assert len(room) == len(grid)
    assert (dist[6:-6] > 0).all()  # holes only in the polar caps (no vertices there)
    # Both sides of the box's outline lose triangles in every mesh row it crosses.
    assert len(room) - len(with_box) >= 2 * 8 * mesh_rows // 128


def _score(rgb: np.ndarray, reference: torch.Tensor) -> float:
    x = torch.from_numpy(rgb).permute(2, 0, 1)[None].float() / 255
    if x.shape[-2] != reference.shape[-2]:
        x = F.interpolate(x, size=reference.shape[-2:], mode="bilinear", align_corners=False)
    return float(ws_psnr(x, reference))


def test_the_sharp_preview_reads_the_sources_at_full_resolution(gl, demo):
    """Geometry drawn at a quarter of the rows, colours read at all of them: as good as
    drawing everything at full resolution, clearly better than upsampling the small draw."""
    from panogrf.renderer.gl_preview import PreviewRenderer

    data, images, depth = demo
    pose = data.c2w[1].numpy()
    with PreviewRenderer(gl, images[[0, 2]], depth[[0, 2]], data.c2w[[0, 2]].numpy()) as pr:
        sharp, dist = pr.render(pose, 256, geometry_height=64)
        full, _ = pr.render(pose, 256)
        small, _ = pr.render(pose, 64)
        with pytest.raises(ValueError, match="below the geometry"):
            pr.render_to_framebuffer(pose, 128, sharp_height=64)
    assert sharp.shape == (256, 512, 3) and dist.shape == (256, 512)
    real = data.images[1:2]
    s, f, u = _score(sharp, real), _score(full, real), _score(small, real)
    assert s > f - 0.3 and s > u + 1.0, (s, f, u)
    gt = data.depths[1, 0].numpy()
    ok = (gt > 0) & (dist > 0)
    assert ok.mean() > 0.95 and np.median(np.abs(dist[ok] - gt[ok]) / gt[ok]) < 0.02


def test_the_sharp_preview_at_a_source_pose_is_that_source(gl, demo):
    """Seams and poles: the directions the layers hold wrap round the source's seam and its
    poles without a line where u jumps from 1 to 0."""
    from panogrf.renderer.gl_preview import PreviewRenderer

    data, images, depth = demo
    with PreviewRenderer(gl, images, depth, data.c2w.numpy()) as pr:
        # Turned half round: the source's seam runs down the middle of the picture.
        pose = data.c2w[0].numpy().copy()
        turn = np.array([[-1.0, 0, 0], [0, 1, 0], [0, 0, -1]])
        pose[:3, :3] = pose[:3, :3] @ turn
        rgb, _ = pr.render(pose, 256, geometry_height=64)
        drawn, _ = pr.render(pose, 256)
    expected = np.roll(images[0], 256, axis=1)  # the same panorama, turned half round
    y = torch.from_numpy(expected).permute(2, 0, 1)[None].float() / 255
    assert _score(rgb, y) > 28.0 and _score(rgb, y) > _score(drawn, y) - 1.0
    middle = np.abs(rgb[:, 255].astype(float) - rgb[:, 256].astype(float)).mean()
    inner = np.abs(np.diff(rgb.astype(float), axis=1)).mean()
    assert middle < 3 * inner + 2.0
    poles = np.abs(rgb[:8].astype(float) - expected[:8]).mean()
    assert poles < 12.0


def test_the_viewers_display_computes_the_same_sharp_colours(gl, demo):
    """display.frag with SHARP = 1 (the viewer's one pass) and the sharp pass of its own
    (what `render` reads back) share preview_sharp.glsl and agree pixel for pixel."""
    import moderngl

    from panogrf.renderer.gl_preview import PreviewRenderer
    from panogrf.shaders import load

    data, images, depth = demo
    with PreviewRenderer(gl, images, depth, data.c2w.numpy(), max_views=2) as pr:
        pose = data.c2w[1].numpy().copy()
        pose[:3, 3] += [0.2, 0.0, -0.3]
        out = pr.render_to_framebuffer(pose, 64, distance=False, sharp_height=256)
        own = np.frombuffer(out.color.read(), np.uint8).reshape(256, 512, 4)[..., :3]
        defines = {"PERSPECTIVE": 0, "DEPTH": 0, "FILL": 0, "ROTATE": 0, "SHARP": 1, "VIEWS": 2}
        prog = gl.program(
            vertex_shader=load("fullscreen.vert"),
            fragment_shader=load("display.frag", defines),
        )
        vao = gl.vertex_array(prog, [])
        tex = gl.texture((512, 256), 4)
        fbo = gl.framebuffer([tex])
        pr.bind_sharp(prog, out.sharp, 2)
        prog["u_origin"].value = (0.0, 0.0)
        prog["u_size"].value = (512.0, 256.0)
        fbo.use()
        fbo.viewport = (0, 0, 512, 256)
        vao.render(moderngl.TRIANGLES, vertices=3)
        shown = np.frombuffer(tex.read(), np.uint8).reshape(256, 512, 4)[..., :3]
        shown = shown[::-1]  # the display's row 0 is the window's bottom
        for obj in (fbo, tex, vao, prog):
            obj.release()
    diff = np.abs(own.astype(int) - shown.astype(int)).max(-1)
    assert (diff <= 1).mean() > 0.999, np.percentile(diff, [50, 99.9, 100])


def test_simplified_meshes_keep_the_preview(gl, demo):
    """Quadric simplification to a quarter of the triangles: flat walls lose triangles, the
    preview hardly changes; a triangle across the source's seam reads the texture across it
    (its vertices' u less than half a turn apart)."""
    from panogrf.renderer.gl_preview import PreviewRenderer, decimate

    data, images, depth = demo
    c2w = data.c2w[[0, 2]].numpy()
    pose = data.c2w[1].numpy()
    with PreviewRenderer(gl, images[[0, 2]], depth[[0, 2]], c2w) as pr:
        whole = pr.triangles[0].shape[0]
        ref, _ = pr.render(pose, 256, geometry_height=128)
    target = whole // 4
    with PreviewRenderer(gl, images[[0, 2]], depth[[0, 2]], c2w, mesh_triangles=target) as pr:
        assert all(len(t) <= target for t in pr.triangles)
        rgb, _ = pr.render(pose, 256, geometry_height=128)
        drawn, _ = pr.render(pose, 256)
    real = data.images[1:2]
    assert _score(rgb, real) > _score(ref, real) - 0.5
    assert _score(drawn, real) > _score(ref, real) - 0.5  # the texture coordinates hold too

    from panogrf.renderer.preview_mesh import _uv_world_points, sphere_mesh

    uv, grid = sphere_mesh(64)
    pts, _ = _uv_world_points(uv, depth[0], c2w[0])
    p2, uv2, t2 = decimate(pts, grid, 2000, c2w[0])
    assert len(t2) <= 2000 and len(p2) == len(uv2)
    u = uv2[t2, 0]
    assert (u.max(1) - u.min(1) < 0.5).mean() > 0.99
    # Every vertex still where the source saw a surface, in the direction its uv says.
    lon = 2 * np.pi * (uv2[:, 0] - 0.5)
    lat = np.pi * (0.5 - uv2[:, 1])
    dirs = np.stack((np.cos(lat) * np.sin(lon), np.sin(lat), -np.cos(lat) * np.cos(lon)), -1)
    cam = (p2 - c2w[0, :3, 3]) @ c2w[0, :3, :3]
    cos = (cam * dirs).sum(-1) / np.linalg.norm(cam, axis=-1)
    assert cos.min() > 0.9999


def test_shader_includes():
    from panogrf.shaders import load

    text = load("preview_sharp.frag", {"VIEWS": 2})
    assert "vec3 sharp_preview(vec2 uv)" in text and "#include" not in text
    assert text.splitlines()[1] == "#define VIEWS 2"
