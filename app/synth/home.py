"""The "home" world: the classic two-room layout dressed as a lived-in home.

Starting from `generate_layout` (rooms, doorway, furniture, cameras), with wider ranges (camera
heights 1.0-1.8 m, baselines up to 3.5 m, the middle camera off the line), this:
- gives every surface a material of its kind from `panogrf.app.synth.materials` (plaster or
  wallpaper on walls, planks, tiles or carpet on floors, fabric and kitchen fronts on furniture);
- cuts bright windows into the walls of the main room, their exterior blown out (tint far above
  1, so the shader saturates it), some with curtains beside them: a bright patch that is *not*
  far away, which is what real captures show and the classic world never did;
- lays rugs and sun patches (the floor's own texture, over-exposed) on the floor;
- adds beds and tall shelves against the walls;
- optionally (``trims``, a probability per scene) finishes the main room's walls in parts, as
  older homes are: a picture rail with a plain frieze above it (often the ceiling's own paint,
  so the strongest horizontal edge high on the wall is the rail, not the ceiling's corner) and
  sometimes a dado rail with wainscot below. A monocular network that learned that the wall's
  material ends at the ceiling reads such a room as too low;
- optionally (``coves``, a probability per scene) softens the corner between the main room's
  walls and its ceiling: a cove (a concave quarter circle, mostly in the ceiling's paint) or a
  crown moulding (a chamfer), so the ceiling no longer meets the walls in a sharp line;
- optionally (``sheers``, a probability per scene) hangs sheer or lace curtains across the
  windows: pleated near-white fabric a few centimetres in front of the glass, wider than the
  window and often down to the floor, glowing where the window is behind it. A bright,
  textureless patch then is a near surface, not the blown-out exterior a network may read
  as far away.
Depth stays exact: windows, rugs and patches are thin quads a few millimetres off their surface.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import trimesh

from panogrf.app.synth.layout import (
    LayoutConfig,
    Material,
    SceneObject,
    _box,
    _quad,
    _segment_distance,
    generate_layout,
)

HOME_LAYOUT = LayoutConfig(camera_height=(1.0, 1.8), baseline=(0.2, 3.5))
"""Layout ranges of the home world."""


def _pick(rng: np.random.Generator, layers: range, scale, tint_range=(0.8, 1.0)) -> Material:
    tint = np.clip(rng.uniform(*tint_range) + rng.normal(0, 0.04, 3), 0.3, 10.0)
    return Material(
        layer=int(rng.choice(layers)),
        scale=float(rng.uniform(*scale)),
        offset=(float(rng.random()), float(rng.random())),
        tint=tuple(float(t) for t in tint),
    )


def _kind_of(name: str) -> str:
    if name.endswith("floor") or name == "threshold":
        return "floor"
    if name.endswith("ceiling"):
        return "ceiling"
    if name.startswith(("roomA_wall", "roomB_wall", "divider")):
        return "wall"
    return "furniture"


def _on_wall(wall: str, s: float, y: float, lx: float, lz: float, off: float) -> list[float]:
    """A point on a wall of the main room, ``off`` in front of it (towards the room)."""
    if wall == "x0":
        return [off, y, s]
    if wall == "x1":
        return [lx - off, y, s]
    return [s, y, off if wall == "z0" else lz - off]


def _wall_quad(wall, s0, s1, y0, y1, offsets, lx, lz) -> trimesh.Trimesh:
    """A quad in front of a wall of the main room with corners (``s0``, ``y0``), (``s1``,
    ``y0``), (``s1``, ``y1``), (``s0``, ``y1``), each its own ``offsets`` entry off the wall."""
    ends = ((s0, y0), (s1, y0), (s1, y1), (s0, y1))
    corners = [_on_wall(wall, s, y, lx, lz, o) for (s, y), o in zip(ends, offsets, strict=True)]
    return _quad(np.array(corners, float))


def _wall_strip(wall, s0, s1, low, high, lx, lz) -> trimesh.Trimesh:
    """A quad along a wall of the main room from ``s0`` to ``s1``, between two (off, y) edges:
    ``low`` and ``high``, each ``off`` in front of the wall at height ``y``."""
    (o0, y0), (o1, y1) = low, high
    return _wall_quad(wall, s0, s1, y0, y1, (o0, o0, o1, o1), lx, lz)


def _window(rng, wall: str, lx: float, lz: float, ha: float, groups) -> list[SceneObject]:
    """A window on one wall of room A (x = 0, z = 0 or z = lz), maybe with curtains."""
    span = lz if wall == "x0" else lx
    width = float(min(rng.uniform(0.8, 2.6), span - 0.4))
    height = float(min(rng.uniform(1.0, 1.9), ha - 0.5))
    sill = float(rng.uniform(0.2, max(0.25, ha - height - 0.2)))
    if width < 0.5 or height < 0.5:
        return []
    s0 = float(rng.uniform(0.2, span - width - 0.2))
    glass = _wall_strip(wall, s0, s0 + width, (0.01, sill), (0.01, sill + height), lx, lz)
    glow = Material(
        layer=int(rng.choice(groups["window"])),
        scale=float(max(width, height)),
        offset=(float(rng.random()), float(rng.random())),
        tint=tuple(float(t) for t in rng.uniform(3.0, 8.0) * rng.uniform(0.9, 1.1, 3)),
    )
    out = [SceneObject(f"window_{wall}", glass, glow)]
    if rng.random() < 0.5:
        cloth = _pick(rng, groups["furniture"], (0.3, 0.8))
        for side in (-1, 1):
            w = float(rng.uniform(0.2, 0.45))
            centre_s = s0 - w / 2 + 0.05 if side < 0 else s0 + width + w / 2 - 0.05
            inward = 0.08
            c = _on_wall(wall, centre_s, (sill + height + 0.15) / 2 + 0.05, lx, lz, inward)
            ext = (
                [0.06, sill + height + 0.15, w] if wall == "x0" else [w, sill + height + 0.15, 0.06]
            )
            out.append(SceneObject(f"curtain_{wall}_{side}", _box(ext, c), cloth))
    return out


def _sheers(rng, windows: list[SceneObject], lx, lz, ha, groups) -> list[SceneObject]:
    """Sheer curtains across ``windows`` of the main room (`generate_home`'s ``sheers``):
    pleats (vertical quads alternating between two distances from the wall, in front of the
    glass and behind any side curtains), the parts in front of the glass a bright backlit
    "sheer_glow", the rest lit fabric ("sheer")."""
    out = []
    for window in windows:
        if rng.random() > 0.8:
            continue
        wall = window.name.removeprefix("window_")
        lo, hi = window.mesh.bounds
        along = 2 if wall == "x0" else 0
        w0, w1, sill, head = float(lo[along]), float(hi[along]), float(lo[1]), float(hi[1])
        span = lz if wall == "x0" else lx
        top = min(ha - 0.03, head + rng.uniform(0.05, 0.3))
        if rng.random() < 0.5:  # down to the floor
            bottom = rng.uniform(0.01, 0.03)
        else:
            bottom = max(0.02, sill - rng.uniform(0.0, 0.15))
        left = max(0.03, w0 - rng.uniform(0.05, 0.35))
        right = min(span - 0.03, w1 + rng.uniform(0.05, 0.35))
        panels = [(left, right)]
        if rng.random() < 0.3:  # drawn apart in the middle
            mid, gap = (w0 + w1) / 2, rng.uniform(0.15, 0.5) * (w1 - w0)
            panels = [(left, mid - gap / 2), (mid + gap / 2, right)]
        fold = rng.uniform(0.06, 0.14)
        near, deep = 0.02, 0.02 + rng.uniform(0.01, 0.025)  # glass at 0.01, side curtains 0.05+
        lit, glow = [], []
        for a, b in panels:
            cuts = np.unique(np.concatenate([np.arange(a, b, fold), [b, w0, w1]]))
            cuts = cuts[(cuts >= a) & (cuts <= b)]
            for k, (s0, s1) in enumerate(zip(cuts[:-1], cuts[1:], strict=True)):
                o0, o1 = (near, deep) if k % 2 == 0 else (deep, near)
                if w0 <= s0 and s1 <= w1:  # in front of the glass: backlit from sill to head
                    spans = [(bottom, sill, lit), (sill, head, glow), (head, top, lit)]
                else:
                    spans = [(bottom, top, lit)]
                for y0, y1, parts in spans:
                    if y1 - y0 > 0.01:
                        parts.append(_wall_quad(wall, s0, s1, y0, y1, (o0, o1, o1, o0), lx, lz))
        layer = int(rng.choice(groups["sheer"]))
        scale, offset = float(rng.uniform(0.3, 0.8)), (float(rng.random()), float(rng.random()))
        for name, parts, tint in (
            ("sheer", lit, rng.uniform(0.8, 1.0)),
            ("sheer_glow", glow, rng.uniform(1.6, 3.5)),
        ):
            if parts:
                mat = Material(layer=layer, scale=scale, offset=offset, tint=(float(tint),) * 3)
                out.append(SceneObject(f"{name}_{wall}", trimesh.util.concatenate(parts), mat))
    return out


def _floor_quad(rng, lo, hi, size_range, lift: float) -> trimesh.Trimesh | None:
    w, d = rng.uniform(*size_range, size=2)
    if np.any(hi - lo < [w, d]):
        return None
    x0, z0 = rng.uniform(lo, hi - [w, d])
    return _quad(
        np.array([[x0, lift, z0], [x0, lift, z0 + d], [x0 + w, lift, z0 + d], [x0 + w, lift, z0]])
    )


def _wall_spans(lx: float, lz: float, doorway: dict) -> list[tuple[str, float, float, float]]:
    """The main room's four walls as (wall, start, end, lowest y) spans along them; the
    divider (x = lx) in three: beside the doorway from the floor, above it from its head."""
    dz, dw, dh = doorway["z"], doorway["width"], doorway["height"]
    return [
        ("x0", 0.0, lz, 0.0),
        ("z0", 0.0, lx, 0.0),
        ("z1", 0.0, lx, 0.0),
        ("x1", 0.0, dz, 0.0),
        ("x1", dz + dw, lz, 0.0),
        ("x1", dz, dz + dw, dh),
    ]


def _trims(rng, lx, lz, ha, doorway, groups, ceiling: Material) -> list[SceneObject]:
    """A picture rail with a frieze above it on every wall of the main room, and with
    probability 0.5 a dado rail with wainscot below (`generate_home`'s ``trims``)."""
    eps = 0.005
    low = max(doorway["height"] + 0.05, ha - 1.1)
    if low > ha - 0.25:
        return []
    rail_y = float(rng.uniform(low, ha - 0.25))
    if rng.random() < 0.5:
        frieze = ceiling  # the ceiling's paint carried down to the rail
    else:
        frieze = _pick(rng, groups["ceiling"], (1.0, 3.0), (0.6, 1.0))
    rail_mat = _pick(rng, groups["furniture"], (0.2, 0.6), (0.5, 1.0))
    bands = [(rail_y, ha, frieze, "frieze")]
    rails = [(rail_y, float(rng.uniform(0.03, 0.08)))]
    if rng.random() < 0.5:
        dado_y = float(rng.uniform(0.7, 1.1))
        bands.append((0.0, dado_y, _pick(rng, groups["furniture"], (0.3, 1.0), (0.5, 1.0)), "dado"))
        rails.append((dado_y, float(rng.uniform(0.03, 0.06))))
    out = []
    for i, (wall, s0, s1, y_min) in enumerate(_wall_spans(lx, lz, doorway)):
        if s1 - s0 < 0.05:
            continue
        for y0, y1, mat, name in bands:
            y0 = max(y0, y_min)
            if y1 - y0 < 0.02:
                continue
            band = _wall_strip(wall, s0, s1, (eps, y0), (eps, y1), lx, lz)
            out.append(SceneObject(f"{name}_{wall}_{i}", band, mat))
        for y, h in rails:
            if y - h / 2 < y_min:
                continue
            depth = 0.025
            centre = _on_wall(wall, (s0 + s1) / 2, y, lx, lz, depth / 2)
            ext = [depth, h, s1 - s0] if wall in ("x0", "x1") else [s1 - s0, h, depth]
            out.append(SceneObject(f"rail_{wall}_{i}_{y:.2f}", _box(ext, centre), rail_mat))
    return out


def _coves(rng, lx, lz, ha, groups, ceiling: Material) -> list[SceneObject]:
    """A cove or a crown moulding along the top of every wall of the main room
    (`generate_home`'s ``coves``): strips of quads whose profile runs from the wall to the
    ceiling; the strips of two walls cross at the room's corners."""
    if rng.random() < 0.5:  # cove: a quarter circle of radius r, concave towards the room
        r = float(rng.uniform(0.12, 0.3))
        theta = np.linspace(0.0, np.pi / 2, 6)
        profile = np.stack([r - r * np.cos(theta), ha - r + r * np.sin(theta)], 1)
        use_ceiling = rng.random() < 0.7
        mat = ceiling if use_ceiling else _pick(rng, groups["ceiling"], (1.0, 3.0), (0.6, 1.0))
        name = "cove"
    else:  # crown moulding: a chamfer from the wall to the ceiling
        drop, reach = rng.uniform(0.06, 0.15, size=2)
        profile = np.array([[0.0, ha - drop], [reach, ha]])
        mat = _pick(rng, groups["furniture"], (0.2, 0.6), (0.6, 1.0))
        name = "crown"
    profile[:, 0] += 0.002  # off the wall, so it is never coplanar with it
    profile[:, 1] = np.minimum(profile[:, 1], ha - 0.002)
    out = []
    for wall, length in (("x0", lz), ("x1", lz), ("z0", lx), ("z1", lx)):
        quads = [
            _wall_strip(wall, 0.0, length, low, high, lx, lz)
            for low, high in zip(profile[:-1], profile[1:], strict=True)
        ]
        out.append(SceneObject(f"{name}_{wall}", trimesh.util.concatenate(quads), mat))
    return out


def generate_home(
    seed: int,
    split: str,
    groups: dict[str, range],
    baseline: float | None = None,
    trims: float = 0.0,
    coves: float = 0.0,
    sheers: float = 0.0,
):
    """A home-world scene (deterministic from ``seed``); ``groups`` from `home_texture_bank`.
    ``trims``: the probability that the main room's walls get rails, a frieze and maybe a
    wainscot (`_trims`), ``coves`` that the corner between its walls and ceiling is a cove or
    a crown moulding (`_coves`), ``sheers`` that its windows get sheer curtains (`_sheers`).
    Each is drawn from a random stream of its own, so the rest of the scene is the same scene
    at any ``trims``, ``coves`` and ``sheers``."""
    # The layout's own materials (all replaced below) index the pool as it was before the
    # sheer group was added last, so its draws, and every scene made before, stay the same.
    n_layers = max(r.stop for name, r in groups.items() if name != "sheer")
    scene = generate_layout(seed, split, n_layers, baseline, HOME_LAYOUT)
    rng = np.random.default_rng([seed, 0x40E])
    lx, ha, lz = scene.meta["room_a"]

    # Materials by kind; one wall material per room, as painters do.
    wall_mats = {
        room: _pick(rng, groups["wall"], (0.6, 1.6), (0.5, 0.9)) for room in ("roomA", "roomB")
    }
    objects = []
    for obj in scene.objects:
        kind = _kind_of(obj.name)
        if kind == "wall":
            mat = wall_mats["roomB" if obj.name.startswith("roomB") else "roomA"]
        elif kind == "floor":
            mat = _pick(rng, groups["floor"], (0.8, 2.0))
        elif kind == "ceiling":
            mat = _pick(rng, groups["ceiling"], (1.0, 3.0), (0.6, 0.95))
        else:
            mat = _pick(rng, groups["furniture"], (0.3, 1.2), (0.6, 1.0))
        objects.append(dataclasses.replace(obj, material=mat))
    floor_a = next(o for o in objects if o.name == "roomA_floor").material

    centres = scene.cameras[:, :3, 3]
    a, b = centres[0, [0, 2]], centres[2, [0, 2]]
    for wall in rng.permutation(["x0", "z0", "z1"])[: int(rng.integers(1, 4))]:
        objects += _window(rng, str(wall), lx, lz, ha, groups)
    lo, hi = np.array([0.1, 0.1]), np.array([lx - 0.1, lz - 0.1])
    if rng.random() < 0.7 and (m := _floor_quad(rng, lo, hi, (1.2, 3.0), 0.004)) is not None:
        objects.append(SceneObject("rug", m, _pick(rng, groups["rug"], (1.5, 3.0))))
    for i in range(int(rng.integers(0, 3))):
        if (m := _floor_quad(rng, lo, hi, (0.4, 1.5), 0.007)) is not None:
            sun = dataclasses.replace(
                floor_a, tint=tuple(rng.uniform(1.5, 2.5) * np.asarray(floor_a.tint))
            )
            objects.append(SceneObject(f"sun_patch_{i}", m, sun))

    # Beds and shelves against the walls, clear of the camera line (centre from the wall).
    clear = HOME_LAYOUT.camera_clearance
    for i in range(int(rng.integers(0, 3))):
        bed = rng.random() < 0.5
        w, d = (
            (rng.uniform(0.9, 1.8), rng.uniform(1.9, 2.1))
            if bed
            else (rng.uniform(0.6, 1.6), rng.uniform(0.3, 0.45))
        )
        h = rng.uniform(0.45, 0.6) if bed else rng.uniform(1.4, min(2.2, ha - 0.2))
        x = float(rng.uniform(w / 2 + 0.05, max(w / 2 + 0.06, lx - w / 2 - 0.05)))
        z = d / 2 + 0.02 if rng.random() < 0.5 else lz - d / 2 - 0.02
        if _segment_distance(np.array([x, z]), a, b) < clear + math.hypot(w, d) / 2:
            continue
        parts = [_box([w, h, d], [x, h / 2, z])]
        if bed:
            head_z = z - d / 2 + 0.04 if z < lz / 2 else z + d / 2 - 0.04
            parts.append(_box([w, 1.0, 0.08], [x, 0.5, head_z]))
        objects.append(
            SceneObject(
                f"A_{'bed' if bed else 'shelf'}_{i}",
                trimesh.util.concatenate(parts),
                _pick(rng, groups["furniture"], (0.3, 1.0), (0.6, 1.0)),
            )
        )

    ceiling = next(o for o in objects if o.name == "roomA_ceiling").material
    trim_rng = np.random.default_rng([seed, 0x7219])
    if trims > 0 and trim_rng.random() < trims:
        objects += _trims(trim_rng, lx, lz, ha, scene.meta["doorway"], groups, ceiling)
    cove_rng = np.random.default_rng([seed, 0xC0E])
    if coves > 0 and cove_rng.random() < coves:
        objects += _coves(cove_rng, lx, lz, ha, groups, ceiling)
    sheer_rng = np.random.default_rng([seed, 0x5EE7])
    if sheers > 0 and sheer_rng.random() < sheers:
        windows = [o for o in objects if o.name.startswith("window_")]
        objects += _sheers(sheer_rng, windows, lx, lz, ha, groups)

    cameras = scene.cameras.copy()
    if scene.baseline > 0.3:
        # Middle camera off the line, horizontally, less than the clearance kept around it.
        line = (b - a) / max(np.linalg.norm(b - a), 1e-9)
        off = rng.uniform(-1, 1) * min(0.3, 0.15 * scene.baseline)
        cameras[1, :3, 3] += off * np.array([-line[1], 0.0, line[0]])
    meta = dict(scene.meta, world="home")
    return dataclasses.replace(scene, objects=objects, cameras=cameras, meta=meta)
