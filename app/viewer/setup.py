"""What the viewer window needs, prepared before it opens (`panogrf view`, the viewer benchmark):
the sources, their depth and poses, the render worker, and the preview's settings, whose defaults
come from the preview benchmarks (`lab/results.md`). The window is `panogrf.app.viewer.window`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from panogrf.app.scene.types import shifted

#: Rows of the preview while moving when it is shown upsampled (``ViewerSetup.sharp`` off):
#: 24.42 dB on the validation scenes, at 0.85 times the sharp preview's frame cost
#: (`benchmarks/preview_quality.py`); fewer rows blur it further.
UPSAMPLED_MOVING_ROWS = 256


@dataclass
class ViewerSetup:
    """Everything the window needs, prepared before it opens (see `panogrf view`)."""

    images: np.ndarray  # [V, H, W, 3] uint8 sources
    depth: np.ndarray  # [V, h, w] metres (estimated)
    c2w: np.ndarray  # [V, 4, 4]
    worker: object | None  # RenderWorker (None: preview only)
    start_pose: np.ndarray
    preview_height: int = 512
    # Rows of the preview's geometry while the camera moves (None: preview_height). With
    # ``sharp`` (the sharp preview) its colours are read from the sources at preview_height
    # rows all the same, and a still camera keeps the same geometry; without, the preview is
    # drawn at these rows and shown upsampled, and the first still frame draws it at
    # preview_height. The defaults here (sharp, 128 rows, 128-row meshes simplified to 10000
    # triangles) come from `python benchmarks/preview_quality.py` on 12 validation scenes:
    # see `lab/results.md`, the sharp GL preview.
    moving_height: int | None = 128  # without sharp: UPSAMPLED_MOVING_ROWS
    sharp: bool = True
    path_out: Path = Path("camera_path.json")
    screenshot_dir: Path = Path(".")
    fixed_step: float | None = None  # seconds per frame (None: wall clock)
    frames: int | None = None  # close after this many frames
    script: list[tuple[str, int]] = field(default_factory=list)  # (key name, frames held)
    fps: float = 30.0
    log: object = print
    mesh_height: int | None = 128  # rows of the preview's depth meshes (None: the depth's own)
    mesh_triangles: int | None = 10000  # each mesh simplified to this many (None: all kept)
    max_views: int | None = 2  # sources drawn per frame, the nearest (None: all)
    # The per-scene depth refinement running in the background (`SceneRefiner`; None: none):
    # its refined scene replaces the plain one at the first frame after it is ready.
    scene_refiner: object | None = None
    # Each source's rig at the nadir ([V, H, W] bool, `SourceViews.nadir_mask`; None: none):
    # the preview draws none of a source's mesh there.
    masks: np.ndarray | None = None
    # The world point the poses above are relative to (`SceneImages.origin`): saved camera
    # paths and printed positions are the world's.
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    # Dragging turns the camera with the mouse (as in games) instead of moving the image.
    drag_looks: bool = False
    # Keyframes to start with (a saved camera path read back, `--camera-path`), in the
    # viewer's frame, and where they came from (for the first message).
    keyframes: list = field(default_factory=list)
    keyframes_from: str = ""

    def world(self, c2w: np.ndarray) -> np.ndarray:
        """A pose [4, 4] of the viewer's frame -> the scene's world (float64)."""
        return shifted(c2w, self.origin)

    @classmethod
    def from_views(cls, views, start_frame: int = 0, **kw) -> ViewerSetup:
        """A setup from prepared `SourceViews` (full depth estimated), starting at a view."""
        from panogrf.app.files.images import to_uint8
        from panogrf.model.depth_config import DepthMode

        return cls(
            images=to_uint8(views.images),
            depth=views.depth[DepthMode.FULL][:, 0].cpu().numpy(),
            c2w=views.c2w.cpu().numpy(),
            start_pose=views.c2w[start_frame].cpu().numpy().astype(np.float64),
            masks=None
            if (m := getattr(views, "nadir_mask", None)) is None
            else m[:, 0].cpu().numpy(),
            **kw,
        )


def preview_sources(images: np.ndarray, preview_height: int) -> np.ndarray:
    """The sources [V, H, W, 3] uint8 as the GL preview reads them: area-averaged to twice its
    rows where they have more. It reads one point per pixel, and from far finer sources fine
    texture aliases (9 synthetic scenes photographed at 2048 rows, the sharp preview at 512
    rows: 28.25 -> 28.68 dB WS-PSNR, LPIPS 0.089 -> 0.084, `lab/preview_source_level.py`);
    an 8K photo's texture is also 15 times smaller."""
    import cv2

    from panogrf.renderer.cache import source_rows

    rows = source_rows(preview_height)  # the renders' own rule: twice the rows
    if rows is None or images.shape[1] <= rows:
        return images
    size = (2 * rows, rows)
    return np.stack([cv2.resize(im, size, interpolation=cv2.INTER_AREA) for im in images])
