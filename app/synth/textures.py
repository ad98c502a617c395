"""Textures for synthetic scenes: photographs that scikit-image ships plus procedural patterns.

The train and test splits draw from disjoint sets: different photographs *and* different
procedural families, so a network cannot pass the test split by memorising wall patterns.
Every texture is an RGB float32 array [S, S, 3] in [0, 1], tileable or not (triplanar mapping
hides little; seams of photographs are part of the realism).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cache
from pathlib import Path

import cv2
import numpy as np

TEXTURE_SIZE = 256

# Photographs in skimage/data that are in the wheel (no download). Both motorcycle views are
# near duplicates, so they stay in one split.
_PHOTOS = {
    "train": (
        "brick.png",
        "grass.png",
        "coffee.png",
        "astronaut.png",
        "coins.png",
        "moon.png",
        "motorcycle_left.png",
        "motorcycle_right.png",
        "hubble_deep_field.jpg",
        "ihc.png",
        "page.png",
    ),
    "test": (
        "gravel.png",
        "chelsea.png",
        "camera.png",
        "rocket.jpg",
        "retina.jpg",
        "cell.png",
        "text.png",
        "clock_motion.png",
    ),
}


def _smooth_noise(rng: np.random.Generator, size: int, cells: int) -> np.ndarray:
    """Value noise [size, size] in [0, 1]: random values on a cells x cells grid, upsampled."""
    grid = rng.random((cells, cells)).astype(np.float32)
    return cv2.resize(grid, (size, size), interpolation=cv2.INTER_CUBIC).clip(0, 1)


def _fbm(rng: np.random.Generator, size: int, octaves: int = 5) -> np.ndarray:
    out = np.zeros((size, size), np.float32)
    amp, total = 1.0, 0.0
    for o in range(octaves):
        out += amp * _smooth_noise(rng, size, 2 ** (o + 2))
        total += amp
        amp *= 0.5
    return out / total


def _two_colors(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    a = rng.uniform(0.15, 0.95, 3).astype(np.float32)
    b = (a * rng.uniform(0.3, 0.8) + rng.uniform(0.0, 0.2, 3)).astype(np.float32)
    return a, b


def _mix(t: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return (a[None, None] * (1 - t[..., None]) + b[None, None] * t[..., None]).clip(0, 1)


def _checker(rng: np.random.Generator, s: int) -> np.ndarray:
    n = int(rng.integers(2, 9))
    y, x = np.mgrid[0:s, 0:s]
    t = (((x * n) // s + (y * n) // s) % 2).astype(np.float32)
    return _mix(t * 0.9 + 0.1 * _fbm(rng, s), *_two_colors(rng))


def _marble(rng: np.random.Generator, s: int) -> np.ndarray:
    y, x = np.mgrid[0:s, 0:s].astype(np.float32) / s
    turb = _fbm(rng, s)
    t = 0.5 + 0.5 * np.sin((x * rng.uniform(3, 9) + turb * rng.uniform(3, 8)) * np.pi)
    return _mix(t, *_two_colors(rng))


def _wood(rng: np.random.Generator, s: int) -> np.ndarray:
    y, x = np.mgrid[0:s, 0:s].astype(np.float32) / s
    r = np.sqrt((x - rng.random()) ** 2 * 0.1 + (y - rng.random()) ** 2) * rng.uniform(10, 30)
    t = np.mod(r + _fbm(rng, s) * 2.0, 1.0)
    a = np.array([0.55, 0.35, 0.18], np.float32) * rng.uniform(0.7, 1.3)
    return _mix(t, a.clip(0, 1), (a * 0.6).clip(0, 1))


def _tiles(rng: np.random.Generator, s: int) -> np.ndarray:
    n = int(rng.integers(3, 8))
    y, x = np.mgrid[0:s, 0:s]
    cell = s / n
    grout = ((x % cell) < 3) | ((y % cell) < 3)
    a, b = _two_colors(rng)
    tile_var = _smooth_noise(rng, s, n) * 0.3
    img = _mix(tile_var, a, b)
    img[grout] = rng.uniform(0.6, 0.9)
    return img


def _stripes(rng: np.random.Generator, s: int) -> np.ndarray:
    y, x = np.mgrid[0:s, 0:s].astype(np.float32) / s
    angle = rng.uniform(0, np.pi)
    t = np.mod((x * np.cos(angle) + y * np.sin(angle)) * rng.integers(3, 12), 1.0) < 0.5
    return _mix(t.astype(np.float32) * 0.85 + 0.15 * _fbm(rng, s), *_two_colors(rng))


def _plaster(rng: np.random.Generator, s: int) -> np.ndarray:
    t = _fbm(rng, s, octaves=6)
    t = (t - t.min()) / max(float(t.max() - t.min()), 1e-6)
    return _mix(t, *_two_colors(rng))


def _cells(rng: np.random.Generator, s: int) -> np.ndarray:
    """Voronoi-like stones: distance to the nearest of random seeds."""
    n = int(rng.integers(12, 40))
    seeds = np.full((s, s), 255, np.uint8)
    pts = rng.integers(0, s, size=(n, 2))
    seeds[pts[:, 1], pts[:, 0]] = 0
    d = cv2.distanceTransform(seeds, cv2.DIST_L2, 5)  # distance to the nearest seed
    t = np.clip(d / (s / np.sqrt(n) * 0.6), 0, 1)
    return _mix(t, *_two_colors(rng))


def _bricks(rng: np.random.Generator, s: int) -> np.ndarray:
    rows = int(rng.integers(4, 10))
    h = s / rows
    y, x = np.mgrid[0:s, 0:s].astype(np.float32)
    row = (y // h).astype(int)
    xs = x + (row % 2) * h
    mortar = ((y % h) < 3) | ((xs % (2 * h)) < 3)
    a, b = _two_colors(rng)
    img = _mix(_fbm(rng, s) * 0.6, a, b)
    img[mortar] = rng.uniform(0.5, 0.85)
    return img


_PROCEDURAL: dict[str, tuple[Callable[[np.random.Generator, int], np.ndarray], ...]] = {
    "train": (_checker, _marble, _wood, _tiles),
    "test": (_stripes, _plaster, _cells, _bricks),
}


def _without_profile(data: bytes) -> bytes:
    """A PNG file's bytes without its iCCP (colour profile) chunk; other files as they are."""
    signature = b"\x89PNG\r\n\x1a\n"
    if not data.startswith(signature):
        return data
    out, at = [signature], len(signature)
    while at + 8 <= len(data):
        length = int.from_bytes(data[at : at + 4], "big")
        end = at + 12 + length  # length, type, data, CRC
        if data[at + 4 : at + 8] != b"iCCP":
            out.append(data[at:end])
        at = end
    return b"".join(out)


@cache
def _photo(name: str, size: int) -> np.ndarray:
    import skimage

    path = Path(skimage.__file__).parent / "data" / name
    # Gray photos become 3 equal channels; a PNG's colour profile is dropped unread (page.png's
    # is malformed and libpng would warn on every run), the pixels are the same.
    img = cv2.imdecode(
        np.frombuffer(_without_profile(path.read_bytes()), np.uint8), cv2.IMREAD_COLOR
    )
    if img is None:
        raise FileNotFoundError(f"scikit-image data image {path} is missing")
    h, w = img.shape[:2]
    side = min(h, w)
    img = img[(h - side) // 2 : (h + side) // 2, (w - side) // 2 : (w + side) // 2]
    img = cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0


def photo_names(split: str) -> tuple[str, ...]:
    """The photographs of a split."""
    return _PHOTOS[split]


def texture_bank(
    split: str, rng: np.random.Generator, n_procedural: int, size: int = TEXTURE_SIZE
) -> np.ndarray:
    """All photographs of ``split`` plus ``n_procedural`` random procedural ones: [L, S, S, 3]."""
    if split not in _PHOTOS:
        raise ValueError(f"split must be one of {sorted(_PHOTOS)}, got {split!r}")
    layers = [_photo(name, size) for name in _PHOTOS[split]]
    families = _PROCEDURAL[split]
    for i in range(n_procedural):
        layers.append(families[i % len(families)](rng, size).astype(np.float32))
    return np.stack(layers)
