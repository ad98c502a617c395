"""The instant preview: the sources' depth meshes warped into the target view on the GPU (GL).

Each source panorama becomes a mesh with one vertex per pixel of its (estimated) depth map,
lifted to the world once, textured with the full-resolution panorama; triangles spanning a
depth discontinuity (the "stretched" triangles of a depth mesh) are dropped once, there.
Per frame every mesh is projected straight into the target's equirectangular image by the
vertex shader, into its own layer. Triangles that cross the target's seam (longitude +-180
deg) are found on the CPU and drawn apart, twice, one full turn apart, so each side gets its
part; triangles around the target's poles (longitude undefined) are dropped. A blend pass
keeps the nearest surface and mixes the sources that agree on it by closeness; a fill pass
fills what no source saw from coarser mipmap levels (push-pull). The same path renders the
viewer's preview and `--quality preview` videos.

(A geometry shader could split seam triangles on the GPU, but on Mesa's CPU rasteriser it
cost about 0.7 us per triangle, six times the whole frame budget; the CPU pass costs a few ms.)

GL objects are created and released explicitly; the context comes from the caller (the viewer's
window) or is a standalone EGL context made here (`create_headless_context`).
"""

from __future__ import annotations

import moderngl
import numpy as np

from panogrf.shaders import load as load_shader

#: Kept triangles span at most this ratio of source depths (larger: a depth discontinuity).
MAX_STRETCH = 1.15
#: Triangles whose longitudes (in half turns) spread wider than this surround a pole.
MAX_LON_SPAN = 0.5
#: Sources whose surface is within this relative distance of the nearest one are blended.
BLEND_TOLERANCE = 0.06
#: Distance (metres) mapped to the far end of the depth buffer.
FAR = 100.0
MAX_VIEWS = 16


def create_headless_context() -> moderngl.Context:
    """A standalone OpenGL 3.3+ context on EGL (no display needed)."""
    return moderngl.create_context(standalone=True, backend="egl", require=330)


def _erp_world_points(depth: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    """Depth [h, w] (metres) of a camera c2w [4, 4] -> world points [h, w, 3] at pixel centres."""
    h, w = depth.shape
    v, u = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
    lon = 2 * np.pi * (u / w - 0.5)
    lat = np.pi * (0.5 - v / h)
    d = np.stack((np.cos(lat) * np.sin(lon), np.sin(lat), -np.cos(lat) * np.cos(lon)), -1)
    cam = d * depth[..., None]
    return cam @ c2w[:3, :3].T + c2w[:3, 3]


def _grid_indices(h: int, w: int) -> np.ndarray:
    """Triangles of an h x (w + 1) vertex grid (the last column closes the seam): [T, 3]."""
    cols = w + 1
    i, j = np.meshgrid(np.arange(h - 1), np.arange(w), indexing="ij")
    a = i * cols + j
    b, c, d = a + 1, a + cols, a + cols + 1
    tris = np.stack((np.stack((a, c, b), -1), np.stack((b, c, d), -1)), -2)
    return tris.reshape(-1, 3).astype(np.int32)


class PreviewRenderer:
    """Depth-mesh warping of V posed panoramas into any ERP view, on a moderngl context."""

    def __init__(
        self,
        ctx: moderngl.Context,
        images: np.ndarray,  # [V, H, W, 3] uint8
        depth: np.ndarray,  # [V, h, w] float32 metres
        c2w: np.ndarray,  # [V, 4, 4]
        mesh_height: int | None = None,
        max_views: int | None = None,
    ) -> None:
        """``mesh_height``: rows of the depth meshes (default: the depth's own; fewer rows,
        fewer triangles: the vertex stage dominates on a CPU rasteriser). ``max_views``: draw
        only this many sources per frame, the nearest to the camera (default: all)."""
        v = images.shape[0]
        if not 1 <= v <= MAX_VIEWS:
            raise ValueError(f"the preview takes 1 to {MAX_VIEWS} views, got {v}")
        if depth.shape[0] != v or c2w.shape != (v, 4, 4):
            raise ValueError(
                f"images {images.shape}, depth {depth.shape} and c2w {c2w.shape} disagree"
            )
        self.ctx = ctx
        self.views = v
        self.max_views = min(v, max_views or v)
        self.c2w = np.asarray(c2w, np.float64)
        if mesh_height is not None and mesh_height < depth.shape[1]:
            stride = max(1, depth.shape[1] // mesh_height)
            depth = depth[:, stride // 2 :: stride, stride // 2 :: stride]
        self.mesh_prog = ctx.program(
            vertex_shader=load_shader("preview_mesh.vert"),
            fragment_shader=load_shader("preview_mesh.frag"),
        )
        self.blend_prog = ctx.program(
            vertex_shader=load_shader("fullscreen.vert"),
            fragment_shader=load_shader("preview_blend.frag"),
        )
        self.fill_prog = ctx.program(
            vertex_shader=load_shader("fullscreen.vert"),
            fragment_shader=load_shader("preview_fill.frag"),
        )
        self.blend_vao = ctx.vertex_array(self.blend_prog, [])
        self.fill_vao = ctx.vertex_array(self.fill_prog, [])
        self._objects: list = [
            self.mesh_prog,
            self.blend_prog,
            self.fill_prog,
            self.blend_vao,
            self.fill_vao,
        ]
        h, w = depth.shape[1:]
        grid = _grid_indices(h, w)
        v_idx, u_idx = np.meshgrid(np.arange(h), np.arange(w + 1), indexing="ij")
        uv = np.stack(((u_idx + 0.5) / w, (v_idx + 0.5) / h), -1).astype(np.float32)
        self.textures, self.points, self.triangles, self.buffers = [], [], [], []
        for k in range(v):
            d = np.asarray(depth[k], np.float32)
            pts = _erp_world_points(d, self.c2w[k])
            pts = np.concatenate((pts, pts[:, :1]), 1).reshape(-1, 3)  # the seam column again
            dd = np.concatenate((d, d[:, :1]), 1).reshape(-1)
            tri_d = dd[grid]
            keep = (tri_d.min(1) > 0) & (tri_d.max(1) <= MAX_STRETCH * tri_d.min(1))
            tris = np.ascontiguousarray(grid[keep])
            data = np.concatenate((pts.astype(np.float32), uv.reshape(-1, 2)), -1)
            vbo = ctx.buffer(np.ascontiguousarray(data, np.float32).tobytes())
            main_ibo = ctx.buffer(reserve=max(tris.nbytes, 4), dynamic=True)
            seam_ibo = ctx.buffer(reserve=max(tris.nbytes, 4), dynamic=True)
            vaos = [
                ctx.vertex_array(self.mesh_prog, [(vbo, "3f 2f", "in_pos", "in_uv")], ibo)
                for ibo in (main_ibo, seam_ibo)
            ]
            rgba = np.concatenate(
                (images[k], np.full(images[k].shape[:2] + (1,), 255, np.uint8)), -1
            )
            tex = ctx.texture((images.shape[2], images.shape[1]), 4, np.ascontiguousarray(rgba))
            tex.repeat_x, tex.repeat_y = True, False
            tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
            self.textures.append(tex)
            self.points.append(pts.astype(np.float32))
            self.triangles.append(tris)
            self.buffers.append((main_ibo, seam_ibo, vaos))
            self._objects += [vbo, main_ibo, seam_ibo, *vaos, tex]
        self._targets: dict[tuple[int, int], tuple] = {}

    def _targets_for(self, height: int, width: int):
        key = (height, width)
        if key not in self._targets:
            ctx = self.ctx
            # The sources' layers side by side in one texture, one viewport each: clipping in
            # clip space keeps every layer inside its own strip.
            layers = ctx.texture((width * self.max_views, height), 4, dtype="f2")
            layers.filter = (moderngl.NEAREST, moderngl.NEAREST)
            depth = ctx.depth_renderbuffer((width * self.max_views, height))
            layer_fbo = ctx.framebuffer(color_attachments=[layers], depth_attachment=depth)
            blend = ctx.texture((width, height), 4)
            blend.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
            dist = ctx.texture((width, height), 1, dtype="f4")
            blend_fbo = ctx.framebuffer(color_attachments=[blend, dist])
            color = ctx.texture((width, height), 4)
            out = ctx.framebuffer(color_attachments=[color])
            self._targets[key] = (layers, depth, layer_fbo, blend, blend_fbo, color, dist, out)
        return self._targets[key]

    def _split_seam(self, k: int, w2c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Source k's kept triangles for a target w2c: (ordinary, seam-crossing) index arrays;
        triangles around the target's poles are in neither.

        Only triangles with a vertex near the seam (|lon| > 90 deg) or near a pole can be
        either; the exact longitude spans are computed for those alone."""
        cam = self.points[k] @ w2c[:3, :3].T.astype(np.float32) + w2c[:3, 3].astype(np.float32)
        lon = np.arctan2(cam[:, 0], -cam[:, 2]) * np.float32(1 / np.pi)  # [-1, 1]
        r2 = np.einsum("ij,ij->i", cam, cam)
        risky = (np.abs(lon) > 0.5) | (cam[:, 1] * cam[:, 1] > 0.9 * r2)  # seam or pole
        tris = self.triangles[k]
        suspect = risky.view(np.uint8)[tris].any(1)
        if not suspect.any():
            return tris, tris[:0]
        cand = tris[suspect]
        t = lon[cand]
        span = t.max(1) - t.min(1)
        u = np.where(t < 0, t + 2.0, t)
        wrapped = (span > 1.0) & ((u.max(1) - u.min(1)) <= MAX_LON_SPAN)
        ordinary = np.ones(len(tris), bool)
        ordinary[suspect] = span <= MAX_LON_SPAN
        return tris[ordinary], cand[wrapped]

    def render_to_framebuffer(self, c2w: np.ndarray, height: int) -> tuple:
        """Draw the preview of camera ``c2w`` [4, 4]; returns the colour and distance textures
        of the H x 2H result, left on the GPU (the viewer displays them as they are), and the
        framebuffer holding the distance."""
        width = 2 * height
        layers, _, layer_fbo, blend, blend_fbo, color, dist, out = self._targets_for(height, width)
        rot = np.asarray(c2w, np.float64)[:3, :3]
        w2c = np.eye(4)
        w2c[:3, :3] = rot.T
        w2c[:3, 3] = -rot.T @ np.asarray(c2w, np.float64)[:3, 3]
        ctx = self.ctx
        prog = self.mesh_prog
        prog["u_w2c"].write(w2c.T.astype("f4").tobytes())  # GL is column-major
        prog["u_far"].value = FAR
        prog["u_image"].value = 0
        centre = np.asarray(c2w, np.float64)[:3, 3]
        dists = np.linalg.norm(self.c2w[:, :3, 3] - centre, axis=-1)
        chosen = np.argsort(dists, kind="stable")[: self.max_views]
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE)
        layer_fbo.use()
        layer_fbo.viewport = (0, 0, width * self.max_views, height)
        layer_fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        for slot, k in enumerate(chosen):
            layer_fbo.viewport = (slot * width, 0, width, height)
            self.textures[k].use(location=0)
            ordinary, crossing = self._split_seam(k, w2c)
            main_ibo, seam_ibo, (main_vao, seam_vao) = self.buffers[k]
            main_ibo.write(ordinary.tobytes())
            prog["u_unwrap"].value = 0
            prog["u_shift"].value = 0.0
            main_vao.render(moderngl.TRIANGLES, vertices=ordinary.size)
            if crossing.size:
                seam_ibo.write(crossing.tobytes())
                prog["u_unwrap"].value = 1
                for shift in (0.0, -2.0):
                    prog["u_shift"].value = shift
                    seam_vao.render(moderngl.TRIANGLES, vertices=crossing.size)
        ctx.disable(moderngl.DEPTH_TEST)
        weights = np.zeros(MAX_VIEWS, np.float32)
        weights[: len(chosen)] = 1.0 / (dists[chosen] + 1e-2)
        bp = self.blend_prog
        bp["u_layers"].value = 1
        bp["u_views"].value = len(chosen)
        bp["u_weights"].write(weights.tobytes())
        bp["u_tolerance"].value = BLEND_TOLERANCE
        bp["u_size"].value = (float(width), float(height))
        layers.use(location=1)
        blend_fbo.use()
        blend_fbo.viewport = (0, 0, width, height)
        self.blend_vao.render(moderngl.TRIANGLES, vertices=3)
        blend.build_mipmaps()
        blend.use(location=2)
        self.fill_prog["u_blend"].value = 2
        self.fill_prog["u_size"].value = (float(width), float(height))
        out.use()
        out.viewport = (0, 0, width, height)
        self.fill_vao.render(moderngl.TRIANGLES, vertices=3)
        return color, dist, blend_fbo

    def render(self, c2w: np.ndarray, height: int) -> tuple[np.ndarray, np.ndarray]:
        """The preview of camera ``c2w`` read back: RGB uint8 [H, 2H, 3] and the distance of
        the visible surface from the camera, float32 [H, 2H] (metres; 0 where no source saw
        it and the colour was filled in)."""
        color, _, dist_fbo = self.render_to_framebuffer(c2w, height)
        rgba = np.empty((height, 2 * height, 4), np.uint8)
        d = np.empty((height, 2 * height), np.float32)
        color.read_into(rgba)
        dist_fbo.read_into(d, components=1, attachment=1, dtype="f4")
        return rgba[..., :3].copy(), d

    def release(self) -> None:
        """Free every GL object this renderer made (not the context)."""
        for group in self._targets.values():
            for obj in reversed(group):
                obj.release()
        self._targets.clear()
        for obj in reversed(self._objects):
            obj.release()
        self._objects.clear()

    def __enter__(self) -> PreviewRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.release()
