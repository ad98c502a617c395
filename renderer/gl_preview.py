"""The instant preview: the sources' depth meshes warped into the target view on the GPU (GL).

Each source panorama becomes a mesh over its (estimated) depth map, rows at pixel latitudes and
as many vertices per row as the row's circumference needs (`preview_mesh.sphere_mesh`), lifted
to the world once, textured with the full-resolution panorama; triangles spanning a depth
discontinuity (the "stretched" triangles of a depth mesh) are dropped once, there, and the mesh
may be simplified (`preview_mesh.decimate`: flat walls need few triangles). Per frame every
mesh is projected straight into the target's equirectangular image by the vertex shader, into
its own layer (8-bit colour, or for the sharp preview the direction in which the source saw the
point; the distance in the depth buffer). Triangles that cross the target's seam (longitude
+-180 deg) are found on the CPU and drawn apart, twice, one full turn apart, so each side gets
its part; triangles around the target's poles (longitude undefined) are dropped. A blend pass
keeps the nearest surface and mixes the sources that agree on it by closeness; push-pull passes
fill what no source saw from ever coarser averages of what they did. The same path renders the
viewer's preview and `--quality preview` videos.

The sharp preview draws all that at a coarse resolution (the viewer: 128 rows) and reads the
colours from the sources at the output's (shaders/preview_sharp.glsl, in the viewer's display
pass): geometry is smooth and cheap to draw coarsely, texture detail is not. On 12 validation
scenes at 512 rows it scores 25.12 dB WS-PSNR, against 24.98 for drawing everything at 512
rows and 24.31 for drawing at 256 and upsampling, at 1.1 to 1.3 times the latter's frame
cost (`benchmarks/preview_quality.py`).

(A geometry shader could split seam triangles on the GPU, but on Mesa's CPU rasteriser it
cost about 0.7 us per triangle, six times the whole frame budget; the CPU pass costs about
1 ms per source.)

GL objects are created and released explicitly; the context comes from the caller (the viewer's
window) or is a standalone EGL context made here (`create_headless_context`).

The meshes' CPU side (building, simplifying, the seam split) is `panogrf.renderer.preview_mesh`;
the render targets, the push-pull fill and the sharp colours pass, with the constants the
shaders share, are `panogrf.renderer.preview_passes`.
"""

from __future__ import annotations

from typing import Any, NamedTuple, Protocol

import moderngl
import numpy as np

from panogrf.renderer.preview_mesh import (
    MAX_OBLIQUE_TAN,
    _uv_masked,
    _uv_world_points,
    decimate,
    sphere_mesh,
    split_seam,
)
from panogrf.renderer.preview_passes import (
    BLEND_TOLERANCE,
    FAR,
    LOG_NEAR,
    LOG_TOLERANCE,
    MAX_VIEWS,
    PreviewPasses,
    SharpInputs,
    _uniform,
)
from panogrf.shaders import load as load_shader

#: Each drawn source's weight among those that see a surface: 1 / (its distance from the
#: camera + 1 cm) to this power, as the refined view's detail weighs them. The square against
#: the plain inverse (`lab/preview_closeness.py`, the preview as the viewer draws it while
#: moving, WS-PSNR / LPIPS): 6 views a fifth of the way from a photo 21.40 / 0.1399 -> 21.39 /
#: 0.1365; 6 views halfway between two photos the same.
CLOSENESS_POWER = 2.0


class _GLObject(Protocol):
    """A moderngl object this renderer makes and releases."""

    def release(self) -> None: ...


class PreviewTextures(NamedTuple):
    """One drawn preview, on the GPU (H x 2H textures at the geometry's rows, row 0 = the top;
    ``color`` at the sharp preview's rows when it has them)."""

    color: moderngl.Texture | None  # the filled RGB preview (None: left to the caller's pass)
    blend: moderngl.Texture  # the blend: rgb premultiplied by coverage, coverage in alpha
    coarse: moderngl.Texture  # push-pull level 1, filled: blend + (1 - a) * coarse = color
    dist: moderngl.Texture | None  # distance of the visible surface (metres; 0: none)
    dist_fbo: moderngl.Framebuffer  # holds dist as attachment 1 (for read-back)
    sharp: SharpInputs | None = None  # the sharp preview's inputs (None: not sharp)


def create_headless_context() -> moderngl.Context:
    """A standalone OpenGL 3.3+ context on EGL (no display needed)."""
    return moderngl.create_context(
        standalone=True,
        backend="egl",  # type: ignore[arg-type]  # moderngl's stub: **settings as dict values
        require=330,
    )


class PreviewRenderer(PreviewPasses):
    """Depth-mesh warping of V posed panoramas into any ERP view, on a moderngl context."""

    def __init__(
        self,
        ctx: moderngl.Context,
        images: np.ndarray,  # [V, H, W, 3] uint8
        depth: np.ndarray,  # [V, h, w] float32 metres
        c2w: np.ndarray,  # [V, 4, 4]
        mesh_height: int | None = None,
        max_views: int | None = None,
        mesh_triangles: int | None = None,
        masks: np.ndarray | None = None,  # [V, H', W'] bool
    ) -> None:
        """``mesh_height``: rows of the depth meshes (default: the depth's own; fewer rows,
        fewer triangles). ``max_views``: draw only this many sources per frame, the nearest to
        the camera (default: all of them, at most `MAX_VIEWS`). ``mesh_triangles``: simplify
        each source's mesh to at most this many triangles (`preview_mesh.decimate`; default: keep
        all). ``masks``: each source's rig at the nadir (`panogrf.renderer.nadir`; True: masked):
        its triangles there are not drawn, so its texels there get no weight and the other
        sources (or the push-pull fill) give the floor."""
        v = images.shape[0]
        if v < 1:
            raise ValueError("the preview needs at least one view")
        if masks is not None and (masks.ndim != 3 or masks.shape[0] != v):
            raise ValueError(f"masks {masks.shape} must be [{v}, H, W]")
        if depth.shape[0] != v or c2w.shape != (v, 4, 4):
            raise ValueError(
                f"images {images.shape}, depth {depth.shape} and c2w {c2w.shape} disagree"
            )
        self.ctx = ctx
        self.views = v
        self.max_views = min(v, max_views or v, MAX_VIEWS)
        self.c2w = np.asarray(c2w, np.float64)
        # The mesh pass writing colours (GEO = 0) or, for the sharp preview, where each source
        # saw the surface (GEO = 1).
        self.mesh_progs = {
            geo: ctx.program(
                vertex_shader=load_shader("preview_mesh.vert", {"LOG_NEAR": f"{LOG_NEAR:.6f}"}),
                fragment_shader=load_shader("preview_mesh.frag", {"GEO": int(geo)}),
            )
            for geo in (False, True)
        }
        # The blend with exact distances (written out), without (the viewer's colour view), and
        # on the sharp preview's layers (its colours read from the sources). Keyed (dist, geo).
        self.blend_progs = {
            (dist, geo): ctx.program(
                vertex_shader=load_shader("fullscreen.vert"),
                fragment_shader=load_shader(
                    "preview_blend.frag",
                    {"VIEWS": self.max_views, "DIST": int(dist), "GEO": int(geo)},
                ),
            )
            for dist in (True, False)
            for geo in (False, True)
        }
        self.sharp_prog = ctx.program(
            vertex_shader=load_shader("fullscreen.vert"),
            fragment_shader=load_shader("preview_sharp.frag", {"VIEWS": self.max_views}),
        )
        self.sharp_vao = ctx.vertex_array(self.sharp_prog, [])
        self.fill_prog = ctx.program(
            vertex_shader=load_shader("fullscreen.vert"),
            fragment_shader=load_shader("preview_fill.frag"),
        )
        self.blend_vaos = {k: ctx.vertex_array(p, []) for k, p in self.blend_progs.items()}
        self.fill_vao = ctx.vertex_array(self.fill_prog, [])
        self._objects: list[_GLObject] = [
            *self.mesh_progs.values(),
            *self.blend_progs.values(),
            self.sharp_prog,
            self.fill_prog,
            *self.blend_vaos.values(),
            self.fill_vao,
            self.sharp_vao,
        ]
        rows = min(mesh_height or depth.shape[1], depth.shape[1])
        uv, grid = sphere_mesh(rows)
        max_stretch = 1.0 + (np.pi / rows) * MAX_OBLIQUE_TAN
        self.points, self.triangles, self.corners, self.buffers = [], [], [], []
        for k in range(v):
            pts, dd = _uv_world_points(uv, np.asarray(depth[k], np.float32), self.c2w[k])
            tri_d = dd[grid]
            keep = (tri_d.min(1) > 0) & (tri_d.max(1) <= max_stretch * tri_d.min(1))
            if masks is not None and masks[k].any():
                keep &= ~_uv_masked(uv, masks[k])[grid].any(1)
            tris, vuv = np.ascontiguousarray(grid[keep]), uv
            if mesh_triangles and len(tris) > mesh_triangles:
                pts, vuv, tris = decimate(pts, tris, mesh_triangles, self.c2w[k])
            # Per vertex: world position, source texture coordinates (the colour layers), the
            # direction in which the source sees it (the sharp preview's layers), made once.
            cam = (pts - self.c2w[k, :3, 3]) @ self.c2w[k, :3, :3]
            dirs = cam / np.maximum(np.linalg.norm(cam, axis=-1, keepdims=True), 1e-9)
            data = np.concatenate((pts.astype(np.float32), vuv, dirs.astype(np.float32)), -1)
            vbo = ctx.buffer(np.ascontiguousarray(data, np.float32).tobytes())
            main_ibo = ctx.buffer(reserve=max(tris.nbytes, 4), dynamic=True)
            seam_ibo = ctx.buffer(reserve=max(tris.nbytes, 4), dynamic=True)
            # Each program reads what its fragment shader uses; the rest of a vertex is skipped.
            layouts = {
                False: ("3f 2f 12x", "in_pos", "in_uv"),
                True: ("3f 8x 3f", "in_pos", "in_dir"),
            }
            vaos = {
                geo: [
                    ctx.vertex_array(prog, [(vbo, *layouts[geo])], ibo)
                    for ibo in (main_ibo, seam_ibo)
                ]
                for geo, prog in self.mesh_progs.items()
            }
            self.points.append(pts.astype(np.float32))
            self.triangles.append(tris)
            self.corners.append(np.ascontiguousarray(tris.T))
            self.buffers.append((main_ibo, seam_ibo, vaos))
            self._objects += [vbo, main_ibo, seam_ibo, *vaos[False], *vaos[True]]
        # The source panoramas, one layer each, RGBA (GL has no 3-byte alignment to spare).
        rgba = np.concatenate((images, np.full(images.shape[:3] + (1,), 255, np.uint8)), -1)
        self.images = ctx.texture_array(
            (images.shape[2], images.shape[1], v), 4, np.ascontiguousarray(rgba)
        )
        self.images.repeat_x, self.images.repeat_y = True, False
        self.images.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self._objects.append(self.images)
        self._targets: dict[tuple[int, int], dict[str, Any]] = {}
        self._sharp: dict[int, tuple[moderngl.Texture, moderngl.Framebuffer]] = {}

    def render_to_framebuffer(
        self,
        c2w: np.ndarray,
        height: int,
        fill_top: bool = True,
        distance: bool = True,
        sharp_height: int | None = None,
        sharp_pass: bool = True,
    ) -> PreviewTextures:
        """Draw the preview of camera ``c2w`` [4, 4], left on the GPU: a `PreviewTextures`.

        ``fill_top=False`` skips the last, full-resolution push-pull step: whoever draws the
        preview next (the viewer's display pass) does it as it samples, one pass fewer.
        ``distance=False`` leaves ``dist`` unwritten and blends on 8-bit log distances (the
        viewer's colour view: half the blend's cost on llvmpipe).

        ``sharp_height`` (at least ``height``): the sharp preview. The geometry is drawn at
        ``height`` rows and the colours are read from the sources at ``sharp_height`` rows
        (shaders/preview_sharp.glsl), into ``color``; with ``sharp_pass=False`` they are left
        to the caller's own pass (``sharp`` has what it needs, `bind_sharp` binds it: the
        viewer computes them as it shows them). Validation (`benchmarks/preview_quality.py`,
        12 scenes at 512 rows): geometry at 128 rows from 128-row meshes simplified to 10k
        triangles scores 25.12 dB, drawing it all at 512 rows 24.98, for 0.74 times the cost."""
        width = 2 * height
        sharp = sharp_height is not None
        if sharp_height is not None and sharp_height < height:
            raise ValueError(f"sharp_height {sharp_height} is below the geometry's {height} rows")
        t = self._targets_for(height, width)
        layer_fbo = self._geo_fbo(t, height, width) if sharp else t["layer_fbo"]
        rot = np.asarray(c2w, np.float64)[:3, :3]
        w2c = np.eye(4)
        w2c[:3, :3] = rot.T
        w2c[:3, 3] = -rot.T @ np.asarray(c2w, np.float64)[:3, 3]
        ctx = self.ctx
        prog = self.mesh_progs[sharp]
        _uniform(prog, "u_w2c").write(w2c.T.astype("f4").tobytes())  # GL is column-major
        _uniform(prog, "u_far").value = FAR
        if not sharp:
            _uniform(prog, "u_images").value = 0
        centre = np.asarray(c2w, np.float64)[:3, 3]
        dists = np.linalg.norm(self.c2w[:, :3, 3] - centre, axis=-1)
        chosen = np.argsort(dists, kind="stable")[: self.max_views]
        self.images.use(location=0)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE)
        layer_fbo.use()
        layer_fbo.viewport = (0, 0, width * self.max_views, height)
        layer_fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)  # alpha 0: nothing drawn
        for slot, k in enumerate(chosen):
            layer_fbo.viewport = (slot * width, 0, width, height)
            if not sharp:
                _uniform(prog, "u_source").value = float(k)
            ordinary, crossing = split_seam(self.points[k], self.corners[k], self.triangles[k], w2c)
            main_ibo, seam_ibo, vaos = self.buffers[k]
            main_vao, seam_vao = vaos[sharp]
            main_ibo.write(ordinary)
            _uniform(prog, "u_unwrap").value = 0
            main_vao.render(moderngl.TRIANGLES, vertices=ordinary.size)
            if crossing.size:  # as they are, then a full turn to the left: two instances
                seam_ibo.write(crossing)
                _uniform(prog, "u_unwrap").value = 1
                seam_vao.render(moderngl.TRIANGLES, vertices=crossing.size, instances=2)
        ctx.disable(moderngl.DEPTH_TEST)
        bp = self.blend_progs[distance, sharp]
        weights = ((1.0 / (dists[chosen] + 1e-2)) ** CLOSENESS_POWER).astype(np.float32)
        sources = chosen.astype(np.float32)
        uniforms = {
            "u_layers": 1,
            "u_depth": 4,
            "u_far": FAR,
            "u_tolerance": BLEND_TOLERANCE if distance else LOG_TOLERANCE,
            "u_width": width,
        }
        for name, value in uniforms.items():
            if name in bp:  # some are compiled out (one view; no exact distances)
                _uniform(bp, name).value = value
        _uniform(bp, "u_weights").write(weights.tobytes())
        if sharp:
            _uniform(bp, "u_images").value = 0
            _uniform(bp, "u_source").write(sources.tobytes())
        t["geo" if sharp else "layers"].use(location=1)
        t["depth"].use(location=4)
        blend_fbo = t["blend_fbo" if distance else "colour_fbo"]
        blend_fbo.use()
        blend_fbo.viewport = (0, 0, width, height)
        self.blend_vaos[distance, sharp].render(moderngl.TRIANGLES, vertices=3)
        levels = t["filled"]
        fill_top = fill_top or sharp or len(levels) < 2
        self._fill(t, 0 if fill_top else 1)
        color, inputs = (levels[0][0] if fill_top else None), None
        if sharp:
            inputs = SharpInputs(
                t["geo"], levels[0][0], weights, sources, (float(width), float(height))
            )
            assert sharp_height is not None  # sharp
            color = self._draw_sharp(inputs, sharp_height) if sharp_pass else None
        return PreviewTextures(
            color=color,
            blend=t["blend"],
            coarse=levels[min(1, len(levels) - 1)][0],
            dist=t["dist"] if distance else None,
            dist_fbo=t["blend_fbo"],
            sharp=inputs,
        )

    def render(
        self, c2w: np.ndarray, height: int, geometry_height: int | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The preview of camera ``c2w`` read back: RGB uint8 [H, 2H, 3] and the distance of
        the visible surface from the camera, float32 [H, 2H] (metres; 0 where no source saw
        it and the colour was filled in). ``geometry_height`` (below ``height``): the sharp
        preview, its geometry drawn at that many rows (the distances too, repeated to H)."""
        sharp = geometry_height is not None and geometry_height < height
        g = geometry_height if sharp and geometry_height is not None else height
        out = self.render_to_framebuffer(c2w, g, sharp_height=height if sharp else None)
        rgba = np.empty((height, 2 * height, 4), np.uint8)
        d = np.empty((g, 2 * g), np.float32)
        assert out.color is not None  # filled at the top level, sharp colours drawn
        out.color.read_into(rgba)
        out.dist_fbo.read_into(d, components=1, attachment=1, dtype="f4")
        if sharp:  # nearest: a distance between two surfaces would be neither
            rows = np.minimum((np.arange(height) + 0.5) * g // height, g - 1).astype(np.int64)
            cols = np.minimum((np.arange(2 * height) + 0.5) * g // height, 2 * g - 1)
            d = d[rows][:, cols.astype(np.int64)]
        return rgba[..., :3].copy(), d

    def release(self) -> None:
        """Free every GL object this renderer made (not the context)."""
        for t in self._targets.values():
            for tex, fbo in t.pop("filled"):
                fbo.release()
                tex.release()
            for obj in reversed(list(t.values())):
                obj.release()
        self._targets.clear()
        for tex, fbo in self._sharp.values():
            fbo.release()
            tex.release()
        self._sharp.clear()
        for obj in reversed(self._objects):
            obj.release()
        self._objects.clear()

    def __enter__(self) -> PreviewRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
