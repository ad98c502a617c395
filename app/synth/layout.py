"""Procedural indoor layouts: two rooms joined by a doorway, furniture, pillars, lights, cameras.

World frame: y up, metres, floor at y = 0. Room A spans x in [0, Lx], z in [0, Lz]; room B lies
beyond the wall at x = Lx (thickness ``wall``), reached through a doorway. The three panorama
cameras stand on a line inside room A with its own random heading each; furniture is placed so
some of it stands near that line and occludes parts of the scene from one camera but not the
others (the wide-baseline problem the method is about). Deterministic from the seed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import trimesh


@dataclass(frozen=True)
class LayoutConfig:
    """Ranges of the random layout (metres unless noted)."""

    room_size: tuple[float, float] = (3.0, 10.0)
    """Side lengths of the main room."""
    ceiling: tuple[float, float] = (2.4, 3.4)
    """Ceiling height of the main room."""
    wall: float = 0.15
    """Thickness of the wall with the doorway."""
    camera_height: tuple[float, float] = (1.2, 1.7)
    """Height of each camera centre above the floor."""
    baseline: tuple[float, float] = (0.2, 2.0)
    """First-to-last camera distance, when not fixed by the caller."""
    camera_clearance: float = 0.4
    """Minimum horizontal distance from the camera line to any wall or object."""
    furniture: tuple[int, int] = (3, 9)
    """Number of furniture pieces in the main room (inclusive range)."""
    occluders: tuple[int, int] = (1, 2)
    """How many of them are placed close to the camera line."""


@dataclass(frozen=True)
class Material:
    """Triplanar texture parameters of one object."""

    layer: int
    """Index into the scene's texture array."""
    scale: float
    """Metres per texture tile."""
    offset: tuple[float, float]
    """Texture-space offset, so objects sharing a texture do not line up."""
    tint: tuple[float, float, float]
    """Multiplier of the texture's RGB."""


@dataclass
class SceneObject:
    name: str
    mesh: trimesh.Trimesh
    material: Material


@dataclass
class Light:
    position: np.ndarray  # [3] world metres
    color: np.ndarray  # [3] linear RGB intensity


@dataclass
class SynthScene:
    """A procedural scene plus its three cameras (c2w, OpenGL frame, world metres)."""

    objects: list[SceneObject]
    lights: list[Light]
    ambient: np.ndarray  # [3]
    cameras: np.ndarray  # [3, 4, 4] c2w, first / middle / last on a line
    baseline: float
    seed: int
    split: str
    meta: dict = field(default_factory=dict)

    def merged_mesh(self) -> trimesh.Trimesh:
        """All geometry as one mesh (for ray casting and triangle counts)."""
        return trimesh.util.concatenate([o.mesh for o in self.objects])


def _quad(corners: np.ndarray) -> trimesh.Trimesh:
    """A planar quad from four corners in order [4, 3]."""
    return trimesh.Trimesh(vertices=corners, faces=[[0, 1, 2], [0, 2, 3]], process=False)


def _box(extents, center, yaw: float = 0.0) -> trimesh.Trimesh:
    tf = trimesh.transformations.rotation_matrix(yaw, [0, 1, 0])
    tf[:3, 3] = center
    return trimesh.creation.box(extents=extents, transform=tf)


def _room_shell(x0, x1, z0, z1, height, skip_x1: bool) -> dict[str, trimesh.Trimesh]:
    """Floor, ceiling and walls of an axis-aligned room; the wall at x1 is left out if asked."""
    y = height
    parts = {
        "floor": _quad(np.array([[x0, 0, z0], [x1, 0, z0], [x1, 0, z1], [x0, 0, z1]], float)),
        "ceiling": _quad(np.array([[x0, y, z0], [x0, y, z1], [x1, y, z1], [x1, y, z0]], float)),
        "wall_x0": _quad(np.array([[x0, 0, z0], [x0, 0, z1], [x0, y, z1], [x0, y, z0]], float)),
        "wall_z0": _quad(np.array([[x0, 0, z0], [x0, y, z0], [x1, y, z0], [x1, 0, z0]], float)),
        "wall_z1": _quad(np.array([[x0, 0, z1], [x1, 0, z1], [x1, y, z1], [x0, y, z1]], float)),
    }
    if not skip_x1:
        parts["wall_x1"] = _quad(
            np.array([[x1, 0, z0], [x1, y, z0], [x1, y, z1], [x1, 0, z1]], float)
        )
    return parts


def _furniture(rng: np.random.Generator, kind: str, ceiling: float) -> tuple[list, float]:
    """Meshes of one piece centred at the origin on the floor, and its footprint radius."""
    if kind == "pillar":
        r = rng.uniform(0.12, 0.35)
        if rng.random() < 0.5:
            m = trimesh.creation.cylinder(radius=r, height=ceiling, sections=32)
            m.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
            m.apply_translation([0, ceiling / 2, 0])
            return [m], r
        return [_box([2 * r, ceiling, 2 * r], [0, ceiling / 2, 0])], r * math.sqrt(2)
    if kind == "table":
        w, d, h = rng.uniform(0.8, 2.0), rng.uniform(0.6, 1.2), rng.uniform(0.7, 0.8)
        parts = [_box([w, 0.05, d], [0, h - 0.025, 0])]
        for sx in (-1, 1):
            for sz in (-1, 1):
                parts.append(
                    _box(
                        [0.06, h - 0.05, 0.06],
                        [sx * (w / 2 - 0.08), (h - 0.05) / 2, sz * (d / 2 - 0.08)],
                    )
                )
        return parts, math.hypot(w, d) / 2
    if kind == "cabinet":
        w, d, h = (
            rng.uniform(0.5, 2.0),
            rng.uniform(0.4, 0.7),
            rng.uniform(0.8, min(2.2, ceiling - 0.2)),
        )
        return [_box([w, h, d], [0, h / 2, 0])], math.hypot(w, d) / 2
    if kind == "sofa":
        w, d = rng.uniform(1.4, 2.4), rng.uniform(0.8, 1.0)
        seat = _box([w, 0.45, d], [0, 0.225, 0])
        back = _box([w, 0.45, 0.2], [0, 0.675, -d / 2 + 0.1])
        return [seat, back], math.hypot(w, d) / 2
    if kind == "lamp":
        pole = trimesh.creation.cylinder(radius=0.03, height=1.5, sections=12)
        pole.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
        pole.apply_translation([0, 0.75, 0])
        shade = trimesh.creation.icosphere(subdivisions=2, radius=0.25)
        shade.apply_translation([0, 1.6, 0])
        return [pole, shade], 0.25
    if kind == "crate":
        s = rng.uniform(0.3, 0.9)
        return [_box([s, s, s], [0, s / 2, 0])], s * math.sqrt(2) / 2
    raise ValueError(kind)


_KINDS = ("pillar", "table", "cabinet", "sofa", "lamp", "crate")


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Horizontal distance from point p to segment ab (2D points)."""
    ab = b - a
    t = np.clip(np.dot(p - a, ab) / max(np.dot(ab, ab), 1e-12), 0.0, 1.0)
    return float(np.linalg.norm(p - (a + t * ab)))


def _material(rng: np.random.Generator, n_layers: int, scale: tuple[float, float]) -> Material:
    base = rng.uniform(0.75, 1.0)
    tint = np.clip(base + rng.normal(0, 0.08, 3), 0.4, 1.0)
    return Material(
        layer=int(rng.integers(n_layers)),
        scale=float(rng.uniform(*scale)),
        offset=(float(rng.random()), float(rng.random())),
        tint=tuple(float(t) for t in tint),
    )


def _camera_pose(position: np.ndarray, yaw: float) -> np.ndarray:
    c2w = np.eye(4)
    c2w[:3, :3] = trimesh.transformations.rotation_matrix(yaw, [0, 1, 0])[:3, :3]
    c2w[:3, 3] = position
    return c2w


def generate_layout(
    seed: int,
    split: str,
    n_layers: int,
    baseline: float | None = None,
    config: LayoutConfig | None = None,
) -> SynthScene:
    """A random two-room scene with three cameras on a line (deterministic from ``seed``).

    ``n_layers`` is the number of textures available; ``baseline`` fixes the first-to-last
    camera distance (metres), otherwise it is drawn from ``config.baseline``.
    """
    config = config or LayoutConfig()
    rng = np.random.default_rng([seed, 0x5EED])
    lx, lz = rng.uniform(*config.room_size, size=2)
    ha = rng.uniform(*config.ceiling)
    if baseline is None:
        baseline = float(rng.uniform(*config.baseline))
    clear = config.camera_clearance
    if baseline > min(lx, lz) * math.sqrt(2) - 2 * clear - 0.5:
        # The line must fit inside the room with clearance: grow the room, not the rules.
        grow = baseline + 2 * clear + 0.5
        lx, lz = max(lx, grow), max(lz, grow)

    # Cameras: a line of length `baseline` (3D) inside room A, `clear` away from the walls.
    h0 = rng.uniform(*config.camera_height)
    lo_h, hi_h = config.camera_height
    rise = float(np.clip(rng.uniform(-0.25, 0.25) * baseline, lo_h - h0, hi_h - h0))
    horizontal = math.sqrt(max(baseline**2 - rise**2, 0.0))
    for _ in range(1000):
        theta = rng.uniform(0, 2 * np.pi)
        a = rng.uniform([clear, clear], [lx - clear, lz - clear])
        b = a + horizontal * np.array([math.cos(theta), math.sin(theta)])
        if clear <= b[0] <= lx - clear and clear <= b[1] <= lz - clear:
            break
    else:  # pragma: no cover - the room is grown above so this cannot happen
        raise RuntimeError("could not place the camera line")
    p0 = np.array([a[0], h0, a[1]])
    p2 = np.array([b[0], h0 + rise, b[1]])
    cameras = np.stack(
        [_camera_pose(p, rng.uniform(0, 2 * np.pi)) for p in (p0, 0.5 * (p0 + p2), p2)]
    )

    # Doorway in the wall x = lx, room B behind it.
    t = config.wall
    dw = rng.uniform(0.8, 1.6)
    dh = rng.uniform(2.0, min(2.4, ha - 0.3))
    lbx = rng.uniform(2.5, 8.0)
    lbz = rng.uniform(max(dw + 0.6, 2.0), max(lz, dw + 0.6))
    lbz = min(lbz, lz)
    zb0 = rng.uniform(0.0, lz - lbz)
    dz = rng.uniform(zb0 + 0.2, zb0 + lbz - 0.2 - dw)
    hb = rng.uniform(min(max(dh + 0.2, 2.3), ha), ha)

    n_layers = max(1, n_layers)
    wall_mat = _material(rng, n_layers, (0.8, 2.5))
    objects: list[SceneObject] = []
    for name, mesh in _room_shell(0.0, lx, 0.0, lz, ha, skip_x1=True).items():
        mat = wall_mat if name.startswith("wall") else _material(rng, n_layers, (0.5, 2.0))
        objects.append(SceneObject(f"roomA_{name}", mesh, mat))
    divider = [
        _box([t, ha, dz], [lx + t / 2, ha / 2, dz / 2]),
        _box([t, ha, lz - dz - dw], [lx + t / 2, ha / 2, (dz + dw + lz) / 2]),
        _box([t, ha - dh, dw], [lx + t / 2, (ha + dh) / 2, dz + dw / 2]),
    ]
    objects.append(SceneObject("divider", trimesh.util.concatenate(divider), wall_mat))
    threshold = np.array([[lx, 0, dz], [lx + t, 0, dz], [lx + t, 0, dz + dw], [lx, 0, dz + dw]])
    objects.append(SceneObject("threshold", _quad(threshold), wall_mat))
    wall_b = _material(rng, n_layers, (0.8, 2.5))
    for name, mesh in _room_shell(lx + t, lx + t + lbx, zb0, zb0 + lbz, hb, skip_x1=False).items():
        if name == "wall_x0":
            continue  # the divider is that wall
        mat = wall_b if name.startswith("wall") else _material(rng, n_layers, (0.5, 2.0))
        objects.append(SceneObject(f"roomB_{name}", mesh, mat))

    # Furniture: footprints as circles; the first few hug the camera line as occluders.
    placed: list[tuple[np.ndarray, float]] = []
    n_main = int(rng.integers(config.furniture[0], config.furniture[1] + 1))
    n_occ = int(rng.integers(config.occluders[0], config.occluders[1] + 1))

    def place(kind: str, lo: np.ndarray, hi: np.ndarray, near_line: bool, room: str) -> None:
        parts, radius = _furniture(rng, kind, ha if room == "A" else hb)
        if np.any(lo + radius > hi - radius):
            return  # does not fit this room
        for _ in range(200):
            c = rng.uniform(lo + radius, hi - radius)
            dist = _segment_distance(c, a, b) - radius
            if room == "A" and dist < clear:
                continue
            if near_line and dist > clear + 1.0:
                continue
            if any(np.linalg.norm(c - q) < radius + r + 0.1 for q, r in placed):
                continue
            yaw = rng.uniform(0, 2 * np.pi)
            tf = trimesh.transformations.rotation_matrix(yaw, [0, 1, 0])
            tf[:3, 3] = [c[0], 0.0, c[1]]
            mesh = trimesh.util.concatenate(parts)
            mesh.apply_transform(tf)
            objects.append(
                SceneObject(
                    f"{room}_{kind}_{len(placed)}", mesh, _material(rng, n_layers, (0.2, 1.0))
                )
            )
            placed.append((c, radius))
            return

    lo_a, hi_a = np.array([0.05, 0.05]), np.array([lx - 0.05, lz - 0.05])
    for i in range(n_main):
        kind = (
            "pillar" if i < n_occ and rng.random() < 0.6 else _KINDS[int(rng.integers(len(_KINDS)))]
        )
        place(kind, lo_a, hi_a, near_line=i < n_occ, room="A")
    lo_b = np.array([lx + t + 0.05, zb0 + 0.05])
    hi_b = np.array([lx + t + lbx - 0.05, zb0 + lbz - 0.05])
    for _ in range(int(rng.integers(1, 4))):
        place(_KINDS[int(rng.integers(1, len(_KINDS)))], lo_b, hi_b, near_line=False, room="B")

    # Lights near the ceilings, warm to cool.
    lights = []
    for room_lo, room_hi, h, n in (
        (lo_a, hi_a, ha, rng.integers(1, 4)),
        (lo_b, hi_b, hb, rng.integers(1, 3)),
    ):
        for _ in range(int(n)):
            xz = rng.uniform(room_lo, room_hi)
            warmth = rng.uniform(-1, 1)
            color = np.array([1.0 + 0.15 * warmth, 1.0, 1.0 - 0.2 * warmth]) * rng.uniform(1.5, 4.0)
            lights.append(Light(np.array([xz[0], h - 0.3, xz[1]]), color))
    ambient = np.full(3, rng.uniform(0.12, 0.35)) * rng.uniform(0.9, 1.1, 3)

    meta = {
        "room_a": [float(lx), float(ha), float(lz)],
        "room_b": [float(lbx), float(hb), float(lbz)],
        "doorway": {"z": float(dz), "width": float(dw), "height": float(dh)},
        "furniture": [o.name for o in objects if o.name[:2] in ("A_", "B_")],
    }
    return SynthScene(objects, lights, ambient, cameras, float(baseline), seed, split, meta)
