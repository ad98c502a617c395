"""The scene cache: everything about the source views that does not depend on the target pose.

Built once per scene (depth estimation happens before, see `panogrf.model.depth`): the source
panoramas for colour, their poses, estimated depths, appearance features and visibility
parameters, the last three stacked in one map so a sample point costs one `grid_sample` per
view. Shapes: V views, H W the source panoramas, h w the feature grid (the depth's grid).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from panogrf.model.erp import erp_directions, invert_rigid, pad_seam, sample_padded
from panogrf.model.render_net import RendererNet

#: A render at H rows reads its sources' colours at most this many times finer (`at_most`):
#: sources twice as fine as the render give it detail (`panogrf.renderer.detail`), finer ones
#: only alias. None: the sources as they are.
SOURCE_ROWS_PER_ROW: int | None = 2


#: Sources a neural render reads: the nearest to its target (`SceneCache.nearest`; None: every
#: source of the scene).
RENDER_SOURCES: int | None = None


def source_rows(height: int) -> int | None:
    """The rows of the sources that a render at ``height`` rows reads (None: all of them)."""
    return None if SOURCE_ROWS_PER_ROW is None else SOURCE_ROWS_PER_ROW * height


@dataclass
class SceneCache:
    """Pose-independent inputs of the renderer for V source views."""

    images: Tensor  # [V, 3, H, W] colours in [0, 1], the input's full resolution
    c2w: Tensor  # [V, 4, 4] camera-to-world
    depth: Tensor  # [V, 1, h, w] estimated spherical depth (metres)
    maps: Tensor  # [V, C + 6 + 1, h, w] appearance features | visibility params | depth
    feature_channels: int
    mask: Tensor | None = None
    """[V, 1, H', W'] each source's rig at the nadir (1: masked; `panogrf.renderer.nadir`):
    a sample projected into it counts as not seen by that source. None: nothing masked."""

    def __post_init__(self) -> None:
        # Padded once for the seam, sampled for every chunk of points.
        self.maps_padded = pad_seam(self.maps)
        self._images_padded = {1: pad_seam(self.images)}
        self.mask_padded = None if self.mask is None else pad_seam(self.mask.to(self.maps.dtype))
        self._surface: tuple[Tensor, Tensor] | None = None
        self._levels: dict[int, SceneCache] = {}
        self._subsets: dict[tuple[int, ...], SceneCache] = {}

    def at_most(self, rows: int | None) -> SceneCache:
        """This cache with its sources area-averaged to ``rows`` rows where they have more (made
        once per size; the rest shared). A render reads the sources' colours at one point per
        pixel: from sources far finer than it, that picks one texel of many, and fine texture
        aliases (`SOURCE_ROWS_PER_ROW`)."""
        if rows is None or self.images.shape[-2] <= rows:
            return self
        if rows not in self._levels:
            small = F.interpolate(self.images, size=(rows, 2 * rows), mode="area")
            level = SceneCache(small, self.c2w, self.depth, self.maps, self.feature_channels)
            level.maps_padded, level.mask, level.mask_padded = (
                self.maps_padded, self.mask, self.mask_padded)  # fmt: skip
            level._surface = self._surface
            self._levels[rows] = level
        return self._levels[rows]

    def surface_points(self) -> tuple[Tensor, Tensor]:
        """The sources' depth lifted to the world, [V*h*w, 3], and where it is known (> 0)
        [V*h*w]; made once per cache (every render's sample range reads them), detached."""
        if self._surface is None:
            depth = self.depth.detach()
            v, _, h, w = depth.shape
            dirs = erp_directions(h, w, device=depth.device, dtype=depth.dtype)
            world = dirs.reshape(1, -1, 3) @ self.c2w[:, :3, :3].transpose(1, 2)  # [V, h*w, 3]
            points = self.centres[:, None] + world * depth.reshape(v, -1, 1)
            self._surface = points.reshape(-1, 3), depth.reshape(-1) > 0
        return self._surface

    def masked_at(self, uv: Tensor, height: int, width: int) -> Tensor | None:
        """Masked fraction [V, N] of each source at its pixel coordinates uv [V, N, 2] on an
        ``height`` x ``width`` grid (None without a mask)."""
        if self.mask_padded is None:
            return None
        assert self.mask is not None  # mask_padded is made from it
        hm, wm = self.mask.shape[-2:]
        if (hm, wm) != (height, width):
            uv = uv * (wm / width) + 0.5 * (wm / width - 1.0)
        return sample_padded(self.mask_padded, uv)[:, 0]

    def with_mask(self, mask: Tensor | None) -> SceneCache:
        """This cache (its tensors shared) with the sources' nadir ``mask`` [V, 1, H', W']."""
        return SceneCache(self.images, self.c2w, self.depth, self.maps, self.feature_channels, mask)

    def images_padded_by(self, pad: int) -> Tensor:
        """The sources with ``pad`` wrapped columns on each side (bicubic reads need 2),
        padded once per cache."""
        if pad not in self._images_padded:
            self._images_padded[pad] = pad_seam(self.images, pad)
        return self._images_padded[pad]

    @property
    def num_views(self) -> int:
        return self.images.shape[0]

    @property
    def w2c(self) -> Tensor:
        return invert_rigid(self.c2w)

    @property
    def centres(self) -> Tensor:
        return self.c2w[:, :3, 3]

    def to(self, device: torch.device | str) -> SceneCache:
        return SceneCache(
            self.images.to(device),
            self.c2w.to(device),
            self.depth.to(device),
            self.maps.to(device),
            self.feature_channels,
            None if self.mask is None else self.mask.to(device),
        )

    def nearest(self, c2w: Tensor, count: int | None) -> SceneCache:
        """The cache of the ``count`` sources nearest to the target pose ``c2w`` [4, 4] (None,
        or as many as there are: this one), in their order here; made once per subset."""
        if count is None or count >= self.num_views:
            return self
        dist = torch.linalg.vector_norm(
            self.centres.double().cpu() - c2w[:3, 3].double().cpu(), dim=-1
        )
        key = tuple(sorted(torch.argsort(dist, stable=True)[:count].tolist()))
        if key not in self._subsets:
            self._subsets[key] = self.select(list(key))
        return self._subsets[key]

    def select(self, views: list[int]) -> SceneCache:
        """The cache of a subset of the views."""
        return SceneCache(
            self.images[views],
            self.c2w[views],
            self.depth[views],
            self.maps[views],
            self.feature_channels,
            None if self.mask is None else self.mask[views],
        )


def _check(images: Tensor, c2w: Tensor, depth: Tensor) -> None:
    if images.ndim != 4 or images.shape[1] != 3 or images.shape[-1] != 2 * images.shape[-2]:
        raise ValueError(f"images must be [V, 3, H, 2H], got {tuple(images.shape)}")
    v = images.shape[0]
    if c2w.shape != (v, 4, 4):
        raise ValueError(f"c2w must be [{v}, 4, 4], got {tuple(c2w.shape)}")
    if depth.ndim != 4 or depth.shape[:2] != (v, 1) or depth.shape[-1] != 2 * depth.shape[-2]:
        raise ValueError(f"depth must be [{v}, 1, h, 2h], got {tuple(depth.shape)}")


def resize_erp(x: Tensor, height: int) -> Tensor:
    """Resize panoramas [B, C, H, 2H] to height x 2 height (area when shrinking)."""
    if x.shape[-2] == height:
        return x
    if x.shape[-2] > height:
        return F.interpolate(x, size=(height, 2 * height), mode="area")
    return F.interpolate(x, size=(height, 2 * height), mode="bilinear", align_corners=False)


def build_cache(
    net: RendererNet, images: Tensor, c2w: Tensor, depth: Tensor, mask: Tensor | None = None
) -> SceneCache:
    """Encode V posed panoramas with their estimated depth: [V, 3, H, W], [V, 4, 4], [V, 1, h, w]
    (``mask`` [V, 1, H', W']: the sources' nadir masks, `SceneCache.mask`).

    Differentiable (training calls it under autograd); wrap in ``torch.no_grad()`` otherwise.
    """
    _check(images, c2w, depth)
    cfg = net.config
    he = cfg.encoder_height
    features = net.appearance(resize_erp(images, he))
    h, w = depth.shape[-2:]
    if features.shape[-2:] != (h, w):
        features = F.interpolate(features, size=(h, w), mode="bilinear", align_corners=False)
    if net.geometry is not None:
        small = resize_erp(images, h)
        params = net.geometry(small, depth)
    else:
        params = depth.new_zeros(depth.shape[0], 6, h, w)
    maps = torch.cat((features, params, depth), 1)
    return SceneCache(images, c2w, depth, maps, cfg.feature_channels, mask)
