"""The instant preview: the sources' depth meshes warped into the target view on the GPU (GL).

Each source panorama becomes a mesh over its (estimated) depth map, rows at pixel latitudes
and as many vertices per row as the row's circumference needs (`sphere_mesh`), lifted to the
world once, textured with the full-resolution panorama; triangles spanning a depth
discontinuity (the "stretched" triangles of a depth mesh) are dropped once, there, and the
mesh may be simplified (`decimate`: flat walls need few triangles). Per frame every mesh is
projected straight into the target's equirectangular image by the vertex shader, into its own
layer (8-bit colour, or for the sharp preview the direction in which the source saw the
point; the distance in the depth buffer). Triangles that cross the target's seam (longitude
+-180 deg) are found on the CPU and drawn apart, twice, one full turn apart, so each side gets
its part; triangles around the target's poles (longitude undefined) are dropped. A blend pass
keeps the nearest surface and mixes the sources that agree on it by closeness; push-pull
passes fill what no source saw from ever coarser averages of what they did. The same path
renders the viewer's preview and `--quality preview` videos.

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
"""

from __future__ import annotations

from typing import Any, NamedTuple, Protocol, cast

import moderngl
import numpy as np

from panogrf.shaders import load as load_shader

#: A triangle is kept unless its depths differ more than a plane this oblique to the source's
#: rays (tan of the angle between ray and normal, here 80.5 deg) would make them differ at the
#: mesh's row spacing: beyond it the triangle spans a depth discontinuity (a "stretched"
#: triangle). The ratio of depths allowed is 1 + (pi / rows) * MAX_OBLIQUE_TAN: 1.15 at 128
#: rows, 1.29 at 64. A fixed ratio of 1.15 dropped floors and walls seen obliquely at 64 rows.
MAX_OBLIQUE_TAN = 6.0
#: Triangles whose longitudes (in half turns) spread wider than this surround a pole.
MAX_LON_SPAN = 0.5
#: Sources whose surface is within this relative distance of the nearest one are blended.
BLEND_TOLERANCE = 0.06
#: Distance (metres) mapped to the far end of the depth buffer.
FAR = 100.0
#: Nearest distance (metres) of the layers' 8-bit log scale (compiled into preview_mesh.vert).
LOG_NEAR = 0.1
#: Sources drawn per frame at most (their layers sit side by side in one texture).
MAX_VIEWS = 16
#: BLEND_TOLERANCE on the layers' log-distance scale (the blend without exact distances, the
#: sharp colours).
LOG_TOLERANCE = float(np.log1p(BLEND_TOLERANCE) / np.log(FAR / LOG_NEAR))


class _GLObject(Protocol):
    """A moderngl object this renderer makes and releases."""

    def release(self) -> None: ...


def _uniform(prog: moderngl.Program, name: str) -> moderngl.Uniform:
    """``prog[name]``, a uniform (moderngl types members as any of uniform, uniform block,
    attribute or varying)."""
    return cast(moderngl.Uniform, prog[name])


class SharpInputs(NamedTuple):
    """What the sharp preview's colours (shaders/preview_sharp.glsl) are computed from; a pass
    that computes them binds these with `PreviewRenderer.bind_sharp`."""

    geo: moderngl.Texture  # the layers: each source's viewing direction, log distance
    filled: moderngl.Texture  # the filled preview at the layers' rows (for holes)
    weights: np.ndarray  # float32 [layers]: closeness of each drawn source
    sources: np.ndarray  # float32 [layers]: which source each layer holds
    layer: tuple[float, float]  # one layer's width and height


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


def sphere_mesh(rows: int) -> tuple[np.ndarray, np.ndarray]:
    """A mesh of the sphere in ERP texture coordinates with as many vertices per row as its
    circumference needs: ``rows`` rows at pixel-centre latitudes, ``2 rows cos(lat)`` vertices
    on each (at least 3), so near the poles, where an ERP grid crowds its pixels, it does not
    crowd its triangles (about 36 % fewer than a full grid for the same rows).

    Returns uv [N, 2] float32 (each row ends with its first vertex again at u + 1, closing the
    seam with a repeating texture) and triangles [T, 3] int32, zipping neighbouring rows
    together in order of u."""
    v = (np.arange(rows) + 0.5) / rows
    cols = np.maximum(3, np.round(2 * rows * np.cos(np.pi * (0.5 - v)))).astype(np.int64)
    starts = np.concatenate(([0], np.cumsum(cols + 1)))
    uv = np.concatenate(
        [
            np.stack(((np.arange(n + 1) + 0.5) / n, np.full(n + 1, vr)), -1)
            for n, vr in zip(cols, v, strict=True)
        ]
    ).astype(np.float32)
    tris = []
    for r in range(rows - 1):
        n1, n2 = cols[r], cols[r + 1]
        top, bot = starts[r], starts[r + 1]
        # Every step advances along one row to its next vertex, the one with the smaller u.
        nxt = np.concatenate((uv[top + 1 : top + n1 + 1, 0], uv[bot + 1 : bot + n2 + 1, 0]))
        order = np.argsort(nxt, kind="stable")
        is_top = order < n1
        i = np.cumsum(is_top) - is_top  # top vertices passed before each step
        j = np.cumsum(~is_top) - ~is_top
        third = np.where(is_top, top + i + 1, bot + j + 1)
        tris.append(np.stack((top + i, bot + j, third), -1))
    return uv, np.concatenate(tris).astype(np.int32)


def _uv_world_points(
    uv: np.ndarray, depth: np.ndarray, c2w: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Depth [h, w] sampled (nearest) at ERP coordinates uv [N, 2] -> (world points [N, 3],
    the depths [N]) of a camera c2w [4, 4]."""
    h, w = depth.shape
    row = np.minimum((uv[:, 1] * h).astype(np.int64), h - 1)
    col = np.minimum(((uv[:, 0] % 1.0) * w).astype(np.int64), w - 1)
    d = depth[row, col].astype(np.float64)
    lon = 2 * np.pi * (uv[:, 0].astype(np.float64) - 0.5)
    lat = np.pi * (0.5 - uv[:, 1].astype(np.float64))
    dirs = np.stack((np.cos(lat) * np.sin(lon), np.sin(lat), -np.cos(lat) * np.cos(lon)), -1)
    cam = dirs * d[:, None]
    return cam @ c2w[:3, :3].T + c2w[:3, 3], d


def _uv_masked(uv: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``mask`` [h, w] (bool) read (nearest) at ERP coordinates uv [N, 2] -> [N] bool."""
    h, w = mask.shape
    row = np.minimum((uv[:, 1] * h).astype(np.int64), h - 1)
    col = np.minimum(((uv[:, 0] % 1.0) * w).astype(np.int64), w - 1)
    masked: np.ndarray = mask[row, col]
    return masked


def decimate(
    points: np.ndarray, tris: np.ndarray, target: int, c2w: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A source's depth mesh (world points [N, 3], triangles [T, 3]) simplified to at most
    ``target`` triangles by quadric edge collapse (fast_simplification), its open borders (the
    edges at depth discontinuities, the seam, the rows nearest the poles) kept where they are:
    flat walls and floors need few triangles, edges and furniture keep theirs. Returns (points,
    ERP texture coordinates in the source ``c2w`` [4, 4], triangles); a triangle that crosses
    the source's seam gets copies of its vertices at u + 1 (the texture repeats in u), as the
    undecimated mesh's last column has."""
    import fast_simplification
    import torch

    from panogrf.model.erp import world_to_erp

    used = np.unique(tris)
    index = np.full(len(points), -1, np.int64)
    index[used] = np.arange(len(used))
    pts, faces = fast_simplification.simplify(
        np.asarray(points[used], np.float64),
        index[tris].astype(np.int32),
        target_count=target,
        preserve_border=True,
    )
    # ERP coordinates in [0, 1]: the pixel coordinates in a 1 x 1 image, from its corner.
    pix, _ = world_to_erp(
        torch.from_numpy(pts), torch.from_numpy(np.asarray(c2w, np.float64)), 1, 1
    )
    uv = pix.numpy() + 0.5
    faces = np.asarray(faces, np.int64)
    u = uv[faces, 0]
    low = ((u.max(1) - u.min(1)) > 0.5)[:, None] & (u < 0.5)
    if low.any():
        dup, where = np.unique(faces[low], return_inverse=True)
        faces[low] = len(pts) + where
        pts = np.concatenate((pts, pts[dup]))
        uv = np.concatenate((uv, uv[dup] + [1.0, 0.0]))
    return pts.astype(np.float32), uv.astype(np.float32), faces.astype(np.int32)


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
        mesh_triangles: int | None = None,
        masks: np.ndarray | None = None,  # [V, H', W'] bool
    ) -> None:
        """``mesh_height``: rows of the depth meshes (default: the depth's own; fewer rows,
        fewer triangles). ``max_views``: draw only this many sources per frame, the nearest to
        the camera (default: all of them, at most `MAX_VIEWS`). ``mesh_triangles``: simplify
        each source's mesh to at most this many triangles (`decimate`; default: keep all).
        ``masks``: each source's rig at the nadir (`panogrf.renderer.nadir`; True: masked):
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

    def _targets_for(self, height: int, width: int) -> dict[str, Any]:
        key = (height, width)
        if key not in self._targets:
            ctx = self.ctx
            limit = ctx.info["GL_MAX_TEXTURE_SIZE"]
            if width * self.max_views > limit:
                raise ValueError(
                    f"{self.max_views} layers of width {width} exceed this GL's texture size "
                    f"limit ({limit}): draw fewer views (max_views) or a smaller preview"
                )
            t: dict[str, Any] = {}
            # The sources' layers side by side in one texture, one viewport each: clipping in
            # clip space keeps every layer inside its own strip.
            # 8-bit colour; the distance is the depth buffer's (linear in distance, 24 bits
            # over FAR), read as a texture: cheaper to write than a float layer.
            t["layers"] = ctx.texture((width * self.max_views, height), 4)
            t["layers"].filter = (moderngl.NEAREST, moderngl.NEAREST)
            t["depth"] = ctx.depth_texture((width * self.max_views, height))
            t["depth"].compare_func = ""  # read the values, no shadow comparison
            t["depth"].filter = (moderngl.NEAREST, moderngl.NEAREST)
            t["layer_fbo"] = ctx.framebuffer(
                color_attachments=[t["layers"]], depth_attachment=t["depth"]
            )
            t["blend"] = ctx.texture((width, height), 4)
            t["blend"].filter = (moderngl.LINEAR_MIPMAP_NEAREST, moderngl.LINEAR)
            t["blend"].repeat_x, t["blend"].repeat_y = True, False
            t["dist"] = ctx.texture((width, height), 1, dtype="f4")
            t["blend_fbo"] = ctx.framebuffer(color_attachments=[t["blend"], t["dist"]])
            # Push-pull: one filled texture per mip level, down to a few pixels.
            t["filled"] = []
            level = 0
            while True:
                w, h = max(1, width >> level), max(1, height >> level)
                tex = ctx.texture((w, h), 4)
                tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
                tex.repeat_x, tex.repeat_y = True, False
                t["filled"].append((tex, ctx.framebuffer(color_attachments=[tex])))
                if min(w, h) <= 2:
                    break
                level += 1
            self._targets[key] = t
        return self._targets[key]

    def _split_seam(self, k: int, w2c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Source k's kept triangles for a target w2c: (ordinary, seam-crossing) index arrays;
        triangles around the target's poles are in neither.

        Only a triangle with vertices on both sides of the target's x = 0 plane can cross the
        seam (behind the target) or surround a pole (its vertices' longitudes then spread all
        round); longitude spans are computed for those alone. Any other triangle spans less
        than half a turn and is drawn as it is."""
        east = self.points[k] @ w2c[0, :3].astype(np.float32) >= -np.float32(w2c[0, 3])
        east = east.view(np.uint8)
        a, b, c = self.corners[k]
        e = east[a]
        suspect = ((e ^ east[b]) | (e ^ east[c])).view(bool)
        tris = self.triangles[k]
        if not suspect.any():
            return tris, tris[:0]
        cand = tris[suspect]
        cam = self.points[k][cand] @ w2c[:3, :3].T.astype(np.float32) + w2c[:3, 3].astype(
            np.float32
        )  # [S, 3, 3]
        t = np.arctan2(cam[..., 0], -cam[..., 2]) * np.float32(1 / np.pi)  # longitude, [-1, 1]
        span = t.max(1) - t.min(1)
        u = np.where(t < 0, t + 2.0, t)
        wrapped = (span > 1.0) & ((u.max(1) - u.min(1)) <= MAX_LON_SPAN)
        ordinary = ~suspect
        ordinary[suspect] = span <= MAX_LON_SPAN
        return tris[ordinary], cand[wrapped]

    def _geo_fbo(self, t: dict[str, Any], height: int, width: int) -> moderngl.Framebuffer:
        """The sharp preview's layers (32-bit floats: the direction in which each source saw
        the surface, and its log distance; sampled bilinearly by the sharp colours) with the
        layers' depth buffer; made on first use. (16-bit floats were as sharp and slower to
        sample on llvmpipe.)"""
        if "geo_fbo" not in t:
            geo = self.ctx.texture((width * self.max_views, height), 4, dtype="f4")
            geo.filter = (moderngl.LINEAR, moderngl.LINEAR)
            geo.repeat_x, geo.repeat_y = False, False
            t["geo"] = geo
            t["geo_fbo"] = self.ctx.framebuffer(
                color_attachments=[geo], depth_attachment=t["depth"]
            )
        fbo: moderngl.Framebuffer = t["geo_fbo"]
        return fbo

    def _sharp_target(self, height: int) -> tuple[moderngl.Texture, moderngl.Framebuffer]:
        if height not in self._sharp:
            tex = self.ctx.texture((2 * height, height), 4)
            tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
            tex.repeat_x, tex.repeat_y = True, False
            self._sharp[height] = (tex, self.ctx.framebuffer(color_attachments=[tex]))
        return self._sharp[height]

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
            ordinary, crossing = self._split_seam(k, w2c)
            main_ibo, seam_ibo, vaos = self.buffers[k]
            main_vao, seam_vao = vaos[sharp]
            main_ibo.write(ordinary.tobytes())
            _uniform(prog, "u_unwrap").value = 0
            _uniform(prog, "u_shift").value = 0.0
            main_vao.render(moderngl.TRIANGLES, vertices=ordinary.size)
            if crossing.size:
                seam_ibo.write(crossing.tobytes())
                _uniform(prog, "u_unwrap").value = 1
                for shift in (0.0, -2.0):
                    _uniform(prog, "u_shift").value = shift
                    seam_vao.render(moderngl.TRIANGLES, vertices=crossing.size)
        ctx.disable(moderngl.DEPTH_TEST)
        bp = self.blend_progs[distance, sharp]
        weights = (1.0 / (dists[chosen] + 1e-2)).astype(np.float32)
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
        t["blend_fbo"].use()
        t["blend_fbo"].viewport = (0, 0, width, height)
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

    def bind_sharp(self, prog: moderngl.Program, inputs: SharpInputs, first_unit: int) -> None:
        """Set up ``prog`` (a program including shaders/preview_sharp.glsl, compiled with this
        renderer's ``max_views`` as VIEWS) to compute the sharp colours from ``inputs``; its
        three textures go to units ``first_unit`` to ``first_unit + 2``."""
        values = {
            "u_images": first_unit,
            "u_geo": first_unit + 1,
            "u_filled": first_unit + 2,
            "u_tolerance": LOG_TOLERANCE,
            "u_layer": inputs.layer,
        }
        for name, value in values.items():
            if name in prog:  # some are compiled out (one view)
                _uniform(prog, name).value = value
        _uniform(prog, "u_weights").write(inputs.weights.tobytes())
        _uniform(prog, "u_source").write(inputs.sources.tobytes())
        self.images.use(location=first_unit)
        inputs.geo.use(location=first_unit + 1)
        inputs.filled.use(location=first_unit + 2)

    def _draw_sharp(self, inputs: SharpInputs, out_height: int) -> moderngl.Texture:
        """The sharp colours as a pass of their own, into an ``out_height``-row texture."""
        tex, fbo = self._sharp_target(out_height)
        self.bind_sharp(self.sharp_prog, inputs, 0)
        _uniform(self.sharp_prog, "u_size").value = (float(2 * out_height), float(out_height))
        fbo.use()
        fbo.viewport = (0, 0, 2 * out_height, out_height)
        self.sharp_vao.render(moderngl.TRIANGLES, vertices=3)
        return tex

    def _fill(self, t: dict[str, Any], last: int) -> None:
        """Push-pull: mipmap the blended preview, then fill each level's holes from the filled
        next coarser one, coarsest first, down to level ``last`` (in ``t["filled"][last]``)."""
        t["blend"].build_mipmaps()
        t["blend"].use(location=2)
        fp = self.fill_prog
        _uniform(fp, "u_level").value = 2
        _uniform(fp, "u_coarser").value = 3
        levels = t["filled"]
        for lod in range(len(levels) - 1, last - 1, -1):
            tex, fbo = levels[lod]
            _uniform(fp, "u_lod").value = lod
            _uniform(fp, "u_coarsest").value = int(lod == len(levels) - 1)
            _uniform(fp, "u_size").value = (float(tex.width), float(tex.height))
            if lod < len(levels) - 1:
                levels[lod + 1][0].use(location=3)
            fbo.use()
            fbo.viewport = (0, 0, tex.width, tex.height)
            self.fill_vao.render(moderngl.TRIANGLES, vertices=3)

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
