"""Materials of the "home" world: what real rooms are made of, procedurally.

The classic world (`panogrf.app.synth.textures`) dresses rooms in scikit-image's photographs
(an astronaut, coins, a motorcycle) and simple patterns; networks trained only there learn the
generator, not rooms. This bank holds painted plaster, wallpapers with repeated motifs, wood
planks, floor tiles, carpet, rugs with borders, fabric weaves and kitchen fronts, grouped so a
room can put wallpaper on walls and planks on floors, plus blown-out "exteriors" for windows
and near-white sheer and lace curtain fabric.

Every texture is RGB float32 [S, S, 3] in [0, 1] and tiles (wrapping patterns), so walls show no
seams. The train and test splits draw different parameter ranges' seeds from disjoint streams.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from panogrf.app.synth.textures import TEXTURE_SIZE

Rng = np.random.Generator


def _noise(rng: Rng, s: int, cells: int) -> np.ndarray:
    """Tileable value noise [s, s] in [0, 1]: a random grid upsampled with wrap-around."""
    grid = rng.random((cells, cells)).astype(np.float32)
    big = np.tile(grid, (3, 3))
    up = cv2.resize(big, (3 * s, 3 * s), interpolation=cv2.INTER_CUBIC)
    return up[s : 2 * s, s : 2 * s].clip(0, 1)


def _fbm(rng: Rng, s: int, octaves: int = 5, base: int = 4) -> np.ndarray:
    out, amp, total = np.zeros((s, s), np.float32), 1.0, 0.0
    for o in range(octaves):
        out += amp * _noise(rng, s, base * 2**o)
        total += amp
        amp *= 0.55
    return out / total


def _blur(img: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur that wraps around (OpenCV has no wrapping border for it)."""
    p = int(3 * sigma) + 1
    padded = np.pad(img, ((p, p), (p, p)), mode="wrap")
    return cv2.GaussianBlur(padded, (0, 0), sigma)[p:-p, p:-p]


def _colour(rng: Rng, lo: float = 0.2, hi: float = 0.95, sat: float = 0.35) -> np.ndarray:
    """A household colour: mostly muted, a brightness in [lo, hi]."""
    grey = rng.uniform(lo, hi)
    hue = rng.normal(0, sat, 3)
    return np.clip(grey * (1 + hue - hue.mean()), 0.02, 1).astype(np.float32)


def _mix(t: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return (a * (1 - t[..., None]) + b * t[..., None]).clip(0, 1)


def plaster(rng: Rng, s: int) -> np.ndarray:
    """Painted plaster or drywall: a flat colour with faint low-contrast roughness."""
    c = _colour(rng, 0.55, 0.97, 0.12)
    t = _fbm(rng, s, 5, 8)
    return (c * (1 + rng.uniform(0.02, 0.08) * (t[..., None] - 0.5) * 2)).clip(0, 1)


def wallpaper(rng: Rng, s: int) -> np.ndarray:
    """Repeated motifs (dots, diamonds, flowers, stripes) on a background, printed texture."""
    n = int(rng.choice([4, 8, 16]))
    y, x = np.mgrid[0:s, 0:s].astype(np.float32) / s * n
    fy, fx = y % 1 - 0.5, x % 1 - 0.5
    kind = int(rng.integers(4))
    if kind == 0:  # dots, every other row shifted
        fx = (x + 0.5 * (np.floor(y) % 2)) % 1 - 0.5
        t = (np.hypot(fx, fy) < rng.uniform(0.12, 0.3)).astype(np.float32)
    elif kind == 1:  # diamonds / trellis
        t = (np.abs(np.abs(fx) + np.abs(fy) - 0.35) < rng.uniform(0.03, 0.09)).astype(np.float32)
    elif kind == 2:  # flowers: petals in polar coordinates
        r, a = np.hypot(fx, fy), np.arctan2(fy, fx)
        t = (r < 0.22 * (0.6 + 0.4 * np.cos(int(rng.integers(4, 8)) * a))).astype(np.float32)
    else:  # stripes of two widths
        t = ((x % 1) < rng.uniform(0.2, 0.6)).astype(np.float32)
        t = t * 0.7 + 0.3 * ((x * 4 % 1) < 0.15)
    t = _blur(t, 0.7)
    bg, fg = _colour(rng, 0.5, 0.95), _colour(rng, 0.15, 0.8, 0.5)
    return _mix(t, bg, fg) * (0.95 + 0.05 * _fbm(rng, s))[..., None]


def wood_planks(rng: Rng, s: int) -> np.ndarray:
    """Floor boards: parallel planks of varying tone with grain along them and dark joints."""
    n = int(rng.choice([4, 8]))
    y, x = np.mgrid[0:s, 0:s].astype(np.float32) / s
    plank = np.floor(y * n)
    tone = rng.uniform(0.75, 1.05, n).astype(np.float32)[np.clip(plank.astype(int), 0, n - 1)]
    grain = np.sin((x * rng.uniform(20, 60) + _fbm(rng, s) * 6 + plank * 1.7) * np.pi) * 0.5 + 0.5
    base = np.array([0.55, 0.36, 0.2], np.float32) * rng.uniform(0.5, 1.4)
    img = base * tone[..., None]
    img = img * (0.85 + 0.15 * grain[..., None])
    joint = (y * n % 1) < 0.03
    img[joint] *= 0.45
    return img.clip(0, 1).astype(np.float32)


def floor_tiles(rng: Rng, s: int) -> np.ndarray:
    """Ceramic tiles with grout, slight tone variation per tile."""
    n = int(rng.choice([2, 4, 8]))
    y, x = np.mgrid[0:s, 0:s]
    cell = s // n
    grout = ((x % cell) < 2) | ((y % cell) < 2)
    c = _colour(rng, 0.35, 0.95, 0.2)
    var = np.kron(rng.uniform(-0.06, 0.06, (n, n)), np.ones((cell, cell)))[:s, :s]
    img = (c * (1 + var[..., None] + 0.04 * (_fbm(rng, s)[..., None] - 0.5))).clip(0, 1)
    img[grout] = rng.uniform(0.45, 0.85)
    return img.astype(np.float32)


def carpet(rng: Rng, s: int) -> np.ndarray:
    """Carpet: fine high-frequency fibres around one colour."""
    c = _colour(rng, 0.2, 0.8, 0.3)
    fibre = rng.random((s, s)).astype(np.float32)
    fibre = _blur(fibre, 0.6)
    return (c * (0.8 + 0.35 * fibre[..., None] + 0.1 * _fbm(rng, s)[..., None])).clip(0, 1)


def rug(rng: Rng, s: int) -> np.ndarray:
    """A rug: borders around a central field with a repeated ornament."""
    y, x = (np.mgrid[0:s, 0:s].astype(np.float32) + 0.5) / s
    edge = np.minimum(np.minimum(x, 1 - x), np.minimum(y, 1 - y))
    a, b, c = _colour(rng, 0.3, 0.8, 0.6), _colour(rng, 0.1, 0.6, 0.6), _colour(rng, 0.5, 0.9)
    k = rng.uniform(6, 14)
    orn = (np.sin(x * k * np.pi * 2) * np.sin(y * k * np.pi * 2) > 0.3).astype(np.float32)
    img = _mix(orn, a, b)
    border = (edge < 0.12) & (edge > 0.06)
    img[border] = c
    img[edge <= 0.06] = b
    return (img * (0.85 + 0.25 * rng.random((s, s, 1)))).clip(0, 1).astype(np.float32)


def fabric(rng: Rng, s: int) -> np.ndarray:
    """Upholstery or curtain fabric: a weave of two threads, sometimes with a check."""
    y, x = np.mgrid[0:s, 0:s].astype(np.float32)
    period = float(rng.choice([4, 8]))
    weave = (np.sin(x / period * 2 * np.pi) * np.sin(y / period * 2 * np.pi) > 0).astype(np.float32)
    c = _colour(rng, 0.15, 0.9, 0.45)
    img = c * (0.85 + 0.15 * weave[..., None])
    if rng.random() < 0.4:
        n = int(rng.choice([4, 8]))
        check = ((x // (s / n) + y // (s / n)) % 2).astype(np.float32)
        img = img * (0.8 + 0.2 * check[..., None])
    return img.clip(0, 1).astype(np.float32)


def kitchen_front(rng: Rng, s: int) -> np.ndarray:
    """Cabinet doors: flat panels with gaps and a handle each, lacquer or wood tone."""
    n = int(rng.choice([2, 4]))
    y, x = (np.mgrid[0:s, 0:s].astype(np.float32) + 0.5) / s
    c = _colour(rng, 0.25, 0.97, 0.25)
    img = np.broadcast_to(c, (s, s, 3)).copy() * (0.97 + 0.03 * _fbm(rng, s)[..., None])
    gap = ((x * n % 1) < 0.02) | ((y * n % 1) < 0.02)
    img[gap] *= 0.35
    handle = (np.abs(x * n % 1 - 0.85) < 0.015) & (np.abs(y * n % 1 - 0.5) < 0.12)
    img[handle] = rng.uniform(0.1, 0.8)
    return img.clip(0, 1).astype(np.float32)


def exterior(rng: Rng, s: int) -> np.ndarray:
    """What a window shows to a camera exposed for the room: mostly blown out, some greenery."""
    y, x = np.mgrid[0:s, 0:s].astype(np.float32) / s
    sky = np.array([0.85, 0.92, 1.0], np.float32)
    green = np.array([0.45, 0.6, 0.35], np.float32) * rng.uniform(0.8, 1.6)
    horizon = rng.uniform(0.3, 0.8) + 0.1 * (_fbm(rng, s) - 0.5)
    img = _mix((y > horizon).astype(np.float32), sky, green)
    # Mullions: the window's frame bars (dark or white).
    n = int(rng.integers(1, 4))
    bars = ((x * n % 1) < 0.03) | ((y * n % 1) < 0.03)
    img[bars] = rng.uniform(0.2, 1.0)
    return img


def sheer(rng: Rng, s: int) -> np.ndarray:
    """Sheer or lace curtain fabric: near white, a fine thread, often a faint lace motif."""
    y, x = np.mgrid[0:s, 0:s].astype(np.float32)
    c = _colour(rng, 0.85, 1.0, 0.06)
    thread = 0.5 + 0.5 * np.sin(x / 2 * np.pi) * np.sin(y / 2 * np.pi)
    img = c * (0.94 + 0.06 * thread[..., None])
    if rng.random() < 0.6:  # lace: a repeated ring of petals, a little darker
        n = int(rng.choice([4, 8]))
        fy, fx = (y / s * n) % 1 - 0.5, (x / s * n) % 1 - 0.5
        r, a = np.hypot(fx, fy), np.arctan2(fy, fx)
        ring = np.abs(r - 0.25 * (0.7 + 0.3 * np.cos(6 * a))) < 0.04
        img = img * (1 - rng.uniform(0.1, 0.3) * _blur(ring.astype(np.float32), 0.8)[..., None])
    return img.clip(0, 1).astype(np.float32)


GROUPS: dict[str, tuple[Callable[[Rng, int], np.ndarray], ...]] = {
    "wall": (plaster, plaster, wallpaper, wallpaper),
    "floor": (wood_planks, floor_tiles, carpet),
    "ceiling": (plaster,),
    "furniture": (fabric, kitchen_front, wood_planks, plaster),
    "rug": (rug, carpet),
    "window": (exterior,),
    # Drawn last, so the layers above (and every scene made before sheers) stay as they were.
    "sheer": (sheer,),
}


def home_texture_bank(
    split: str, rng: Rng, per_group: int = 8, size: int = TEXTURE_SIZE
) -> tuple[np.ndarray, dict[str, range]]:
    """``per_group`` textures of every group: ([L, S, S, 3], group name -> layer range).

    The split only selects the random stream (callers pass a split-seeded ``rng``), so train and
    test draw different textures of the same families.
    """
    if split not in ("train", "test"):
        raise ValueError(f"split must be 'train' or 'test', got {split!r}")
    layers, groups = [], {}
    for name, makers in GROUPS.items():
        start = len(layers)
        for i in range(per_group):
            layers.append(makers[i % len(makers)](rng, size).astype(np.float32))
        groups[name] = range(start, len(layers))
    return np.stack(layers), groups
