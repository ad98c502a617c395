"""Pictures for people: colour-mapped depth and side-by-side sheets (uint8 RGB arrays)."""

from __future__ import annotations

import cv2
import numpy as np


def colorize_depth(depth: np.ndarray, max_depth: float | None = None) -> np.ndarray:
    """Spherical depth [H, W] (metres, 0 = unknown) -> RGB uint8 [H, W, 3], near bright.

    Uses inverse depth so that near structure keeps contrast; unknown pixels are black.
    """
    valid = np.isfinite(depth) & (depth > 0)
    if max_depth is None:
        max_depth = float(np.percentile(depth[valid], 99)) if valid.any() else 1.0
    inv = np.zeros_like(depth, dtype=np.float32)
    near = 0.3
    inv[valid] = (1.0 / np.clip(depth[valid], near, max_depth) - 1.0 / max_depth) / (
        1.0 / near - 1.0 / max_depth
    )
    # Stretch inverse depth so mid-range distances use most of the colour map.
    idx = np.clip(np.sqrt(inv) * 255.0, 0, 255).astype(np.uint8)
    rgb = cv2.applyColorMap(idx, cv2.COLORMAP_TURBO)[..., ::-1].copy()
    rgb[~valid] = 0
    return rgb


def stack_rows(images: list[np.ndarray], gap: int = 4) -> np.ndarray:
    """Stack RGB uint8 images of equal width vertically with a white gap."""
    width = images[0].shape[1]
    rows = []
    for i, img in enumerate(images):
        if img.shape[1] != width:
            raise ValueError("images must share a width")
        rows.append(img)
        if i < len(images) - 1:
            rows.append(np.full((gap, width, 3), 255, np.uint8))
    return np.concatenate(rows, 0)
