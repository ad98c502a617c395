"""Frames of a camera path: equirectangular or perspective, at preview or a neural quality.

One place turns a pose into an RGB frame for the video export and the viewer's recording:
``preview`` draws the sources' depth meshes on GL (headless EGL unless a context is given),
``draft``, ``fast`` and ``paper`` run the neural renderer (`render_view`). Perspective frames
are cut out of a panorama rendered at the angular resolution they need, whose network runs at
256 rows at most (the sources add the detail, `panogrf.renderer.detail`); a neural method's
small frames, with fewer pixels than that network pass, cast exactly the camera's rays
(`render_perspective_view`). Measured at 1280 x 720 (`benchmarks/perspective.py`): own rays
7.24 s, the panorama with detail and cut 1.52 s, the two agreeing to 44.5 dB.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch

from panogrf.app.errors import UserError
from panogrf.app.files.images import to_uint8
from panogrf.app.scene.types import shifted
from panogrf.model.depth_config import DepthMode
from panogrf.model.perspective import erp_to_perspective
from panogrf.renderer.detail import DEFAULT_DETAIL
from panogrf.renderer.methods import (
    Models,
    SourceViews,
    prepare,
    render_perspective_view,
    render_view,
)
from panogrf.renderer.render import QUALITY, Quality

#: ``preview`` (GL) and every sampling of the neural renderer (what `render --help` offers).
QUALITIES = (Quality.PREVIEW, *QUALITY)


def erp_height_for(camera_type: str, width: int, height: int, fov_deg: float) -> int:
    """Panorama height that gives a frame its resolution (even, at most 1024)."""
    if camera_type == "equirectangular":
        return height
    rows = math.ceil(180.0 / fov_deg * height)
    return int(min(1024, max(16, rows + rows % 2)))


class FrameRenderer:
    """Renders camera poses of one scene to uint8 RGB frames; release() frees GL objects."""

    def __init__(
        self,
        views: SourceViews,
        models: Models,
        quality: Quality,
        method: str = "panogrf",
        origin: np.ndarray | None = None,
    ) -> None:
        """``quality``: a `Quality` or its value. ``origin`` [3]: the world point the views'
        poses are relative to (`SceneImages.origin`); the poses given to `panorama` and `frame`
        are the world's."""
        if quality not in QUALITIES:
            raise ValueError(
                f"quality must be one of {tuple(map(str, QUALITIES))}, got {quality!r}"
            )
        quality = Quality(quality)
        self.views, self.models, self.quality, self.method = views, models, quality, method
        self.origin = np.zeros(3) if origin is None else np.asarray(origin, np.float64)
        self._preview = None
        self._ctx = None

    def prepare(self) -> None:
        """Compute (once) what this quality needs before the first frame: the estimated depth
        for the preview, the method's caches for the neural qualities."""
        if self.quality == Quality.PREVIEW:
            self.views.depth_for(DepthMode.FULL, self.models)
        else:
            prepare(self.method, self.views, self.models)

    def _context(self):
        if self._ctx is None:
            from panogrf.renderer.gl_preview import create_headless_context

            self._ctx = create_headless_context()
        return self._ctx

    def check_height(self, height: int, what: str = "--height") -> None:
        """Refuse, before any work, a panorama height this quality cannot draw: the GL preview
        draws its sources' layers side by side in one texture, which the GL limits in width."""
        if self.quality != Quality.PREVIEW:
            return
        from panogrf.renderer.gl_preview import MAX_VIEWS

        limit = int(self._context().info["GL_MAX_TEXTURE_SIZE"])
        views = min(self.views.images.shape[0], MAX_VIEWS)
        if 2 * height * views > limit:
            raise UserError(
                f"{what} {height}: --quality preview draws {views} sources x {2 * height} "
                f"columns in one texture, over this GL's limit of {limit}; use at most "
                f"{limit // (2 * views)} rows or fewer sources"
            )

    def _preview_renderer(self):
        if self._preview is None:
            from panogrf.renderer.gl_preview import PreviewRenderer

            depth = self.views.depth_for(DepthMode.FULL, self.models)[:, 0].cpu().numpy()
            images = to_uint8(self.views.images)
            self._context()
            mask = self.views.nadir_mask
            self._preview = PreviewRenderer(
                self._ctx,
                images,
                depth,
                self.views.c2w.cpu().numpy(),
                masks=None if mask is None else mask[:, 0].cpu().numpy(),
            )
        return self._preview

    def panorama(self, c2w: np.ndarray, height: int) -> torch.Tensor:
        """The H x 2H panorama [3, H, 2H] in [0, 1] seen from ``c2w`` (the world's)."""
        c2w = self._local(c2w)
        if self.quality == Quality.PREVIEW:
            rgb, _ = self._preview_renderer().render(c2w, height)
            return torch.from_numpy(rgb).permute(2, 0, 1).float() / 255.0
        tgt = torch.from_numpy(np.asarray(c2w, np.float64)).to(self.views.c2w.dtype)
        return render_view(self.method, self.views, tgt, height, self.models, self.quality)

    def _local(self, c2w: np.ndarray) -> np.ndarray:
        return shifted(c2w, -self.origin)

    def frame(
        self, c2w: np.ndarray, camera_type: str, width: int, height: int, fov_deg: float
    ) -> np.ndarray:
        """One frame as uint8 RGB [height, width, 3]."""
        erp_h = erp_height_for(camera_type, width, height, fov_deg)
        # A neural panorama runs its network at no more than DEFAULT_DETAIL.net_height rows
        # (the sources add the detail): cast the frame's own rays only where they are fewer.
        pano_rays = 2 * min(erp_h, DEFAULT_DETAIL.net_height) ** 2
        if (
            camera_type == "perspective"
            and self.quality != Quality.PREVIEW
            and width * height < pano_rays
        ):
            tgt = torch.from_numpy(self._local(c2w))
            rgb = render_perspective_view(
                self.method, self.views, tgt, width, height, fov_deg, self.models, self.quality
            )
            if rgb is not None:  # a neural method casts the camera's own rays
                return to_uint8(rgb)
        pano = self.panorama(c2w, erp_h)
        if camera_type == "perspective":
            pano = erp_to_perspective(pano, width, height, fov_deg)
        elif pano.shape[-1] != width:
            pano = torch.nn.functional.interpolate(
                pano[None], size=(height, width), mode="bilinear", align_corners=False
            )[0]
        return to_uint8(pano)

    def release(self) -> None:
        if self._preview is not None:
            self._preview.release()
            self._preview = None
        if self._ctx is not None:
            self._ctx.release()
            self._ctx = None


def render_camera_path(
    frames: FrameRenderer, path, sink, progress: Callable[[int], None] | None = None
) -> None:
    """Every camera of ``path`` (a `CameraPath`) through ``frames`` into ``sink``."""
    for i, pose in enumerate(path.poses):
        sink.write(
            frames.frame(
                pose, path.camera_type, path.render_width, path.render_height, float(path.fov[i])
            )
        )
        if progress is not None:
            progress(i + 1)
