"""Hard cases and the baseline sweep, made by the synthetic generator (`panogrf.app.synth`).

Every case is a classic-world test scene (`generate_layout`, test split, its own seed) changed
to be the case, with the sources and the target rendered by the generator's own renderer, so
the target's ground truth is exact:

| case          | what is hard                                                             |
|---------------|--------------------------------------------------------------------------|
| occlusion     | 8-9 pieces of furniture, 4 of them hugging the camera line, 2 m baseline  |
| textureless   | every surface one flat colour: nothing to match, shading only            |
| poles         | a box hanging just above the target and a crate just below it            |
| off_line      | the target 0.3 m beside the line of the sources and 0.1 m up             |
| extrapolation | sources 0.75 m apart, the target 0.75 m beyond the last one              |
| at_source     | the target exactly at the first source's pose                            |
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch
import trimesh
from torch import Tensor

from panogrf.app.synth.layout import LayoutConfig, Material, SceneObject, SynthScene

CASES = ("occlusion", "textureless", "poles", "off_line", "extrapolation", "at_source")
#: The stability sweep's baselines (metres), the issue's 0.2-5 m.
SWEEP_BASELINES = (0.2, 0.5, 1.0, 2.0, 3.0, 4.0, 5.0)
#: Base seed of the cases and sweep scenes (test split: odd seeds, textures the training never saw).
SEED = 13_000


@dataclass
class Case:
    """Posed source panoramas and a target with its true panorama."""

    name: str
    images: Tensor  # [V, 3, H, W] sources in [0, 1]
    c2w: Tensor  # [V, 4, 4] sources
    target_c2w: Tensor  # [4, 4]
    target: Tensor  # [1, 3, H, W] the true panorama at the target
    baseline: float  # metres between the outermost sources


def _flat_layer(textures: np.ndarray) -> np.ndarray:
    """The texture pool with one more layer, a flat light grey (index: the last)."""
    flat = np.full((1,) + textures.shape[1:], 0.8, textures.dtype)
    return np.concatenate((textures, flat))


def _box_object(name: str, extents, centre, layer: int) -> SceneObject:
    mesh = trimesh.creation.box(extents=extents)
    mesh.apply_translation(centre)
    return SceneObject(name, mesh, Material(layer, 0.3, (0.0, 0.0), (1.0, 1.0, 1.0)))


def case_scene(name: str, seed: int, n_layers: int) -> tuple[SynthScene, list[int], np.ndarray]:
    """The scene of case ``name``, the indices of its source cameras and the target c2w."""
    from panogrf.app.synth.make import build_scene

    config = LayoutConfig()
    baseline = 1.5
    if name == "occlusion":
        config = LayoutConfig(furniture=(8, 9), occluders=(4, 4), camera_clearance=0.3)
        baseline = 2.0
    scene = build_scene("test", seed, baseline, n_layers - 1, config)  # not the flat layer
    cams = scene.cameras
    target = cams[1].copy()
    sources = [0, 2]
    if name == "textureless":
        for k, obj in enumerate(scene.objects):
            tint = (0.7 + 0.3 * (k % 7) / 7,) * 3
            obj.material = replace(obj.material, layer=n_layers - 1, tint=tint)
    elif name == "poles":
        c = cams[1][:3, 3]
        scene.objects.append(_box_object("A_pole_top", (0.6, 0.08, 0.6), c + [0, 0.45, 0], 0))
        floor = np.array([c[0], 0.15, c[2]])
        scene.objects.append(_box_object("A_pole_bottom", (0.5, 0.3, 0.5), floor, 1))
    elif name == "off_line":
        line = cams[2][:3, 3] - cams[0][:3, 3]
        side = np.cross(line, [0.0, 1.0, 0.0])
        side /= np.linalg.norm(side)
        target[:3, 3] += 0.3 * side + [0.0, 0.1, 0.0]
    elif name == "extrapolation":
        sources, target = [0, 1], cams[2].copy()
    elif name == "at_source":
        target = cams[0].copy()
    elif name != "occlusion":
        raise ValueError(f"unknown case {name!r}: one of {CASES}")
    return scene, sources, target


def _render(renderer, scene: SynthScene, poses: list[np.ndarray], height: int) -> Tensor:
    renderer.set_scene(scene)
    rgb = [renderer.render(p, height, 2 * height)[0] for p in poses]
    return torch.from_numpy(np.stack(rgb)).permute(0, 3, 1, 2).float() / 255.0


def make_cases(
    height: int, names: tuple[str, ...] = CASES, sweep: tuple[float, ...] = (), per: int = 1
) -> list[Case]:
    """The hard cases ``names`` and, for each baseline of ``sweep``, ``per`` plain scenes with
    that first-to-last distance (target: the middle camera; named ``sweep B m`` and, past the
    first, ``sweep B m #k``), rendered at ``height`` rows."""
    from panogrf.app.synth.gl_render import PanoramaRenderer
    from panogrf.app.synth.make import build_scene, build_textures

    textures, _ = build_textures("test", SEED)
    textures = _flat_layer(textures)
    out = []
    with PanoramaRenderer() as renderer:
        renderer.set_textures(textures)
        for i, name in enumerate(names):
            scene, sources, target = case_scene(name, 2 * (SEED + i) + 1, len(textures))
            imgs = _render(renderer, scene, [scene.cameras[k] for k in sources] + [target], height)
            c2w = torch.from_numpy(scene.cameras[sources]).float()
            dist = float(torch.linalg.vector_norm(c2w[-1, :3, 3] - c2w[0, :3, 3]))
            out.append(
                Case(name, imgs[:-1], c2w, torch.from_numpy(target).float(), imgs[-1:], dist)
            )
        for k in range(per):
            for j, b in enumerate(sweep):
                seed = 2 * (SEED + 100 + 16 * k + j) + 1
                scene = build_scene("test", seed, b, len(textures) - 1)
                imgs = _render(renderer, scene, list(scene.cameras), height)
                c2w = torch.from_numpy(scene.cameras).float()
                name = f"sweep {b:g} m" + (f" #{k + 1}" if k else "")
                out.append(Case(name, imgs[[0, 2]], c2w[[0, 2]], c2w[1], imgs[1:2], b))
    return out
