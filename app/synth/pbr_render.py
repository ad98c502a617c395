"""Physically based rendering of synthetic scenes with pyrender: shadows, gloss, bounce fill.

The default renderer (`panogrf.app.synth.gl_render`) shades every surface with unshadowed
Lambertian point lights: nothing casts a shadow, nothing shines, and a room's light does not
pool under its lamps. Real captures are full of exactly those cues (contact shadows under
furniture, lit floors under ceiling lights, glossy floors reflecting windows), and a monocular
depth network trained without them cannot use them. This renderer draws the same `SynthScene`s
through pyrender's metallic-roughness PBR shader:

- every scene light becomes a downward spot light that casts shadows (pyrender has no point
  light shadows) plus a weaker point light beside it that lights the ceiling (the bounce a
  real ceiling gets from a lit floor);
- each bright window gets a "sun": a shadow-casting spot light just inside it, slanting down into
  the room, so the floor gets sun patches that furniture shadows;
- materials get a roughness by kind (floors and cabinets may be glossy);
- the exposure is a camera's, fixed per scene: a dim probe render of the first panorama
  (nothing clips) measures the mean, and every light and emitter is scaled so that the
  panorama's linear mean is `EXPOSURE_MEAN`; what is brighter clips, as in a camera.

The amounts are drawn from the scene's seed, so a scene always renders the same. Depth is the
spherical distance from each cube face's linear depth buffer, resampled to the ERP at the nearest
face pixel (a face pixel's distance exactly; at depth edges it may be the neighbour's surface).

pyrender draws through PyOpenGL on EGL, and an EGL context of pyrender and one of moderngl do not
mix in one process (DESIGN.md section 6): `panogrf.app.synth.make` runs this renderer in its own
worker processes, and nothing here creates a moderngl context.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import torch

from panogrf.app.synth.gl_render import MAX_DEPTH, face_size_for
from panogrf.app.synth.layout import SynthScene
from panogrf.model.cubemap import cubemap_to_erp, face_rotations

SHADOW_MAP = 512
"""Side of pyrender's shadow maps (its own default, 2048, costs 4x more on a CPU rasteriser
and a 256-row panorama cannot show the difference)."""
EXPOSURE_MEAN = 0.2
"""Mean linear intensity of a scene's first panorama after its auto exposure."""
PROBE = 1.0 / 16.0
"""Light scale of the exposure probe (dim enough that almost nothing clips)."""


@dataclass(frozen=True)
class Lighting:
    """Light amounts of one scene (drawn from its seed by `lighting_for`)."""

    ambient: float
    """Multiplier of the scene's ambient colour (flat fill everywhere)."""
    spot: float
    """Spot light intensity per unit of a scene light's colour."""
    fill: float
    """Point light (no shadow) intensity per unit of a scene light's colour."""
    cone: float
    """Outer cone half-angle of the ceiling spots, radians."""
    sun: float
    """Intensity of each window's sun (0: no sun)."""
    sun_elevation: float
    """Angle of the sun below the horizontal, radians."""
    gloss: float
    """Roughness of the glossy floors and cabinets (the others are 0.75-1)."""


def lighting_for(scene: SynthScene) -> Lighting:
    """The scene's light amounts, deterministic from its seed."""
    rng = np.random.default_rng([scene.seed, 0x9B12])
    return Lighting(
        ambient=float(rng.uniform(0.8, 3.0)),
        spot=float(rng.uniform(25.0, 70.0)),
        fill=float(rng.uniform(4.0, 12.0)),
        cone=float(rng.uniform(0.9, 1.3)),
        sun=float(rng.uniform(30.0, 120.0)) if rng.random() < 0.6 else 0.0,
        sun_elevation=float(rng.uniform(0.3, 0.9)),
        gloss=float(rng.uniform(0.4, 0.7)),
    )


def _import_pyrender():
    """pyrender on EGL (headless); its platform must be chosen before PyOpenGL is imported."""
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    import pyrender
    import pyrender.light
    import pyrender.renderer

    # Both modules import the constant: the textures' size and the viewport must agree.
    pyrender.light.SHADOW_TEX_SZ = SHADOW_MAP
    pyrender.renderer.SHADOW_TEX_SZ = SHADOW_MAP
    return pyrender


def _emission(linear) -> np.ndarray:
    """The emissive factor that emits ``linear``: pyrender's shader multiplies the emissive
    texture by its factor twice (``mesh.frag``: ``emissive * material.emissive_factor``)."""
    return np.sqrt(np.asarray(linear, np.float64))


def _look(direction: np.ndarray, position: np.ndarray) -> np.ndarray:
    """A pose [4, 4] at ``position`` whose -z axis points along ``direction``."""
    z = -np.asarray(direction, np.float64)
    z /= np.linalg.norm(z)
    up = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.95 else np.array([1.0, 0.0, 0.0])
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, np.cross(z, x), z, position
    return pose


def _planar_uv(tris: np.ndarray, normals: np.ndarray, scale: float, offset) -> np.ndarray:
    """Per-corner texture coordinates [F, 3, 2]: each triangle projected along its normal's
    dominant axis, as the GL renderer's triplanar shader reads it (zy, xz or xy)."""
    axis = np.abs(normals).argmax(1)[:, None, None]
    q = tris / scale
    uv = np.where(axis == 0, q[..., [2, 1]], np.where(axis == 1, q[..., [0, 2]], q[..., [0, 1]]))
    return uv + np.asarray(offset)


class PyrenderPanoramaRenderer:
    """Renders `SynthScene`s into ERP RGB + spherical depth through pyrender (EGL, offscreen).

    The same interface as `panogrf.app.synth.gl_render.PanoramaRenderer`: `set_textures`, then
    `set_scene` and `render` per scene, `release` (or a ``with`` block) at the end.
    """

    def __init__(self) -> None:
        self._pr = _import_pyrender()
        self._textures: np.ndarray | None = None
        self._texture_cache: dict[int, object] = {}
        self._scene = None
        self._camera_node = None
        self._renderer = None
        self._face = 0
        self._gain: float | None = None
        self._scalable: list[tuple[object, str, np.ndarray]] = []
        self.triangles = 0

    def set_textures(self, textures: np.ndarray) -> None:
        """The texture array [L, S, S, 3] (float in [0, 1]) that materials index into."""
        self._textures = np.clip(textures * 255.0 + 0.5, 0, 255).astype(np.uint8)
        self._texture_cache = {}

    def _texture(self, layer: int):
        if layer not in self._texture_cache:
            self._texture_cache[layer] = self._pr.Texture(
                source=self._textures[layer], source_channels="RGB"
            )
        return self._texture_cache[layer]

    def _material(self, name: str, material, light: Lighting, rng: np.random.Generator):
        pr = self._pr
        tint = np.asarray(material.tint, np.float64)
        texture = self._texture(material.layer)
        if name.startswith("window"):
            # The blown-out exterior emits; it is not lit.
            return pr.MetallicRoughnessMaterial(
                baseColorFactor=[0.0, 0.0, 0.0, 1.0],
                emissiveTexture=texture,
                emissiveFactor=_emission(np.minimum(tint, 8.0) * 1.5 * PROBE),
                metallicFactor=0.0,
                roughnessFactor=1.0,
                doubleSided=True,
            )
        if name.startswith("sheer_glow"):
            # Sheer fabric lit from behind by the window: it emits what passes through.
            return pr.MetallicRoughnessMaterial(
                baseColorTexture=texture,
                baseColorFactor=[*(tint / tint.max()), 1.0],
                emissiveTexture=texture,
                emissiveFactor=_emission(tint * 1.5 * PROBE),
                metallicFactor=0.0,
                roughnessFactor=1.0,
                doubleSided=True,
            )
        glossy = name.endswith("floor") or "cabinet" in name
        rough = light.gloss if glossy and rng.random() < 0.4 else float(rng.uniform(0.75, 1.0))
        extra = {}
        if name.startswith("sun_patch"):
            # The GL world's over-exposed floor patch: keep it (the sun spot adds real ones).
            extra = {"emissiveTexture": texture, "emissiveFactor": _emission(0.25 * tint * PROBE)}
        return pr.MetallicRoughnessMaterial(
            baseColorTexture=texture,
            baseColorFactor=[*np.minimum(tint, 1.0), 1.0],
            metallicFactor=0.0,
            roughnessFactor=rough,
            doubleSided=True,
            **extra,
        )

    def set_scene(self, scene: SynthScene) -> None:
        """Build the pyrender scene of ``scene`` (textures come from `set_textures`)."""
        if self._textures is None:
            raise RuntimeError("call set_textures() before set_scene()")
        pr = self._pr
        light = lighting_for(scene)
        rng = np.random.default_rng([scene.seed, 0x9B13])
        out = pr.Scene(
            ambient_light=np.asarray(scene.ambient) * light.ambient * PROBE, bg_color=[0, 0, 0, 0]
        )
        triangles = 0
        eye = np.asarray(scene.cameras)[:, :3, 3].mean(0)
        for obj in scene.objects:
            mesh = obj.mesh
            tris = mesh.vertices[mesh.faces]
            normals = np.asarray(mesh.face_normals, np.float64)
            if not mesh.is_watertight:
                # pyrender lights a face by its normal on both sides; the GL shader flips it to
                # the viewer. Open surfaces (room shells, windows, rugs) face the cameras.
                towards = eye - tris.mean(1)
                normals = np.where(((normals * towards).sum(1) < 0)[:, None], -normals, normals)
            uv = _planar_uv(tris, normals, obj.material.scale, obj.material.offset)
            prim = pr.Primitive(
                positions=tris.reshape(-1, 3).astype(np.float32),
                normals=np.repeat(normals, 3, axis=0).astype(np.float32),
                texcoord_0=uv.reshape(-1, 2).astype(np.float32),
                indices=np.arange(3 * len(tris), dtype=np.uint32).reshape(-1, 3),
                material=self._material(obj.name, obj.material, light, rng),
            )
            out.add(pr.Mesh([prim]))
            triangles += len(tris)
        down = np.array([0.0, -1.0, 0.0])
        for lamp in scene.lights:
            strength = float(max(lamp.color.max(), 1e-6))
            colour = np.clip(lamp.color / strength, 0.0, 1.0)
            pose = _look(down, lamp.position)
            out.add(
                pr.SpotLight(
                    color=colour,
                    intensity=strength * light.spot * PROBE,
                    innerConeAngle=0.3 * light.cone,
                    outerConeAngle=light.cone,
                ),
                pose=pose,
            )
            out.add(pr.PointLight(color=colour, intensity=strength * light.fill * PROBE), pose=pose)
        if light.sun > 0:
            for obj in scene.objects:
                if not obj.name.startswith("window"):
                    continue
                centre = obj.mesh.vertices.mean(0)
                inward = -np.asarray(obj.mesh.face_normals[0], np.float64)
                room_centre = np.array(
                    [scene.meta["room_a"][0] / 2, 0.0, scene.meta["room_a"][2] / 2]
                )
                if np.dot(inward, room_centre - centre) < 0:
                    inward = -inward
                inward[1] = 0.0
                inward /= max(np.linalg.norm(inward), 1e-9)
                yaw = rng.uniform(-0.6, 0.6)
                c, s = np.cos(yaw), np.sin(yaw)
                flat = np.array([c * inward[0] - s * inward[2], 0.0, s * inward[0] + c * inward[2]])
                e = light.sun_elevation
                direction = np.cos(e) * flat + np.array([0.0, -np.sin(e), 0.0])
                warm = np.array([1.0, 0.95, 0.85])
                out.add(
                    pr.SpotLight(
                        color=warm,
                        intensity=light.sun * PROBE,
                        innerConeAngle=0.15,
                        outerConeAngle=0.45,
                    ),
                    pose=_look(direction, centre + 0.05 * inward),
                )
        camera = pr.PerspectiveCamera(yfov=np.pi / 2, aspectRatio=1.0, znear=0.02, zfar=200.0)
        self._camera_node = out.add(camera)
        self._scene = out
        self._gain = None  # the scene's exposure, set by its first render
        # Everything that emits light, at the probe's scale: (object, attribute, probe value).
        self._scalable = [(out, "ambient_light", np.asarray(out.ambient_light, np.float64))]
        for node in out.light_nodes:
            self._scalable.append((node.light, "intensity", np.float64(node.light.intensity)))
        for mesh in out.meshes:
            for prim in mesh.primitives:
                if prim.material.emissiveFactor is not None:
                    factor = np.asarray(prim.material.emissiveFactor, np.float64) ** 2
                    self._scalable.append((prim.material, "emissiveFactor", factor))
        self.triangles = triangles

    def render(self, c2w: np.ndarray, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
        """The panorama of camera ``c2w`` [4, 4]: RGB uint8 [H, W, 3] and spherical depth
        float32 [H, W] in metres (0 where nothing is hit within ``MAX_DEPTH``); W = 2H."""
        if self._scene is None:
            raise RuntimeError("call set_textures() and set_scene() before render()")
        if width != 2 * height or height < 2:
            raise ValueError(f"an ERP must be W = 2H, got {width}x{height} (width x height)")
        pr = self._pr
        face = face_size_for(width)
        if self._renderer is None or self._face != face:
            if self._renderer is not None:
                self._renderer.delete()
            self._renderer = pr.OffscreenRenderer(face, face)
            self._face = face
        if self._gain is None:
            self._set_exposure(c2w, height, width)
        rgb, dist = self._panorama(c2w, height, width)
        return np.clip(rgb + 0.5, 0, 255).astype(np.uint8), dist

    def _set_exposure(self, c2w: np.ndarray, height: int, width: int) -> None:
        """Scale every light so that this panorama's linear mean is ``EXPOSURE_MEAN``."""
        probe, _ = self._panorama(c2w, height, width)
        mean = float(np.power(probe / 255.0, 2.2).mean())
        self._gain = float(np.clip(EXPOSURE_MEAN / max(mean, 1e-5), 0.5, 400.0))
        for obj, attr, value in self._scalable:
            scaled = value * self._gain
            setattr(obj, attr, _emission(scaled) if attr == "emissiveFactor" else scaled)

    def _panorama(self, c2w, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
        """Float RGB [H, W, 3] in 0-255 and spherical depth [H, W] of one camera."""
        pr = self._pr
        rots = face_rotations(torch.float64).numpy()
        c2w = np.asarray(c2w, np.float64)
        face = self._face
        # Distance along each face pixel's ray per unit of the depth buffer's z.
        t = (np.arange(face) + 0.5) / face * 2.0 - 1.0
        stretch = np.sqrt(1.0 + t[None, :] ** 2 + t[:, None] ** 2).astype(np.float32)
        colours, dists = [], []
        for k in range(6):
            pose = np.eye(4)
            pose[:3, :3] = c2w[:3, :3] @ rots[k]
            pose[:3, 3] = c2w[:3, 3]
            self._scene.set_pose(self._camera_node, pose)
            colour, z = self._renderer.render(self._scene, flags=pr.RenderFlags.SHADOWS_SPOT)
            colours.append(colour)
            dists.append(np.where(z > 0, z * stretch, 0.0).astype(np.float32))
        faces = torch.from_numpy(np.stack(colours)).permute(0, 3, 1, 2).float()[None]
        rgb = cubemap_to_erp(faces, height, width)[0].permute(1, 2, 0).numpy()
        dist = cubemap_to_erp(
            torch.from_numpy(np.stack(dists))[None, :, None], height, width, "nearest"
        )[0, 0].numpy()
        return rgb, np.where(dist <= MAX_DEPTH, dist, 0.0).astype(np.float32)

    def release(self) -> None:
        if self._renderer is not None:
            self._renderer.delete()
            self._renderer = None
        self._scene = None
        self._texture_cache = {}

    def __enter__(self) -> PyrenderPanoramaRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.release()
