"""The instant preview's render targets and full-screen passes, and the constants its shaders
share: the base of `panogrf.renderer.gl_preview.PreviewRenderer`.

The sources' layers sit side by side in one texture (`MAX_VIEWS` at most) with one depth
buffer; the blend writes into a texture with a mip chain, which the push-pull fill (`_fill`)
fills from ever coarser averages; the sharp preview's layers (`_geo_fbo`) and its colours at
the output's rows (`bind_sharp`, `_draw_sharp`) come on top. Every target is made on first use
for its size and kept until the renderer is released.
"""

from __future__ import annotations

from typing import Any, NamedTuple, cast

import moderngl
import numpy as np

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


class PreviewPasses:
    """The render targets and the fill and sharp passes of a `PreviewRenderer` (which sets up
    the attributes declared here)."""

    ctx: moderngl.Context
    max_views: int
    images: moderngl.TextureArray
    sharp_prog: moderngl.Program
    sharp_vao: moderngl.VertexArray
    fill_prog: moderngl.Program
    fill_vao: moderngl.VertexArray
    _targets: dict[tuple[int, int], dict[str, Any]]
    _sharp: dict[int, tuple[moderngl.Texture, moderngl.Framebuffer]]

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
            # The blend without exact distances writes no distance: the colour alone.
            t["colour_fbo"] = ctx.framebuffer(color_attachments=[t["blend"]])
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
        next coarser one, coarsest first, down to level ``last`` (in ``t["filled"][last]``).
        Only the mip levels the fill reads are made (not those below its coarsest)."""
        levels = t["filled"]
        t["blend"].build_mipmaps(max_level=len(levels) - 1)
        t["blend"].use(location=2)
        fp = self.fill_prog
        _uniform(fp, "u_level").value = 2
        _uniform(fp, "u_coarser").value = 3
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
