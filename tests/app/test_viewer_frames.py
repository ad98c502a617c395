"""The viewer's per-frame GL work, counted (never timed) on short headless sessions: the preview
is drawn (its mip chain built) only in frames whose pose changed, and the window is cleared
only when the letterbox leaves black bars."""

from __future__ import annotations

import moderngl
import moderngl_window.context.headless.window as headless
import numpy as np
import pytest
import torch.nn.functional as F

from panogrf.app.scene.folder import load_scene
from panogrf.assets import path as asset_path

pytestmark = pytest.mark.gl


def _session(monkeypatch, script: str, frames: int, size: tuple[int, int]):
    """Runs a headless session; returns (counts, poses shown per frame, the last frame)."""
    from panogrf.app.viewer.refinement import Refinement
    from panogrf.app.viewer.window import PanoViewer, ViewerSetup, parse_script, run_viewer
    from panogrf.renderer.gl_preview import PreviewRenderer

    data = load_scene(asset_path("demo"), load_images=True).images
    images = (data.images.permute(0, 2, 3, 1).numpy() * 255 + 0.5).astype(np.uint8)
    depth = F.interpolate(data.depths, size=(64, 128), mode="nearest")[:, 0].numpy()
    counts = {"preview": 0, "mipmaps": 0, "clear": 0}
    poses: list[bytes] = []
    last: dict[str, np.ndarray] = {}

    def counted(cls, name, key):
        original = getattr(cls, name)

        def wrapper(*args, **kwargs):
            counts[key] += 1
            return original(*args, **kwargs)

        monkeypatch.setattr(cls, name, wrapper)

    counted(PreviewRenderer, "render_to_framebuffer", "preview")
    counted(moderngl.Texture, "build_mipmaps", "mipmaps")
    counted(headless.Window, "clear", "clear")
    observe, on_render = Refinement.observe, PanoViewer.on_render

    def observed(self, pose):
        poses.append(np.asarray(pose).tobytes())
        return observe(self, pose)

    def rendered(self, *args):
        on_render(self, *args)
        w, h = self.wnd.buffer_size
        last["rgb"] = np.frombuffer(self.wnd.fbo.read(components=3), np.uint8).reshape(h, w, 3)

    monkeypatch.setattr(Refinement, "observe", observed)
    monkeypatch.setattr(PanoViewer, "on_render", rendered)
    setup = ViewerSetup(
        images=images,
        depth=depth,
        c2w=data.c2w.numpy(),
        worker=None,
        start_pose=data.c2w[0].numpy().astype(np.float64),
        script=parse_script(script),
        frames=frames,
        fixed_step=0.05,
        preview_height=128,
        moving_height=64,
        mesh_height=32,
        log=lambda *a: None,
    )
    run_viewer(setup, "headless", size)
    return counts, poses, last["rgb"]


def test_a_still_camera_does_not_redraw_the_preview_or_clear_the_window(monkeypatch):
    counts, poses, rgb = _session(monkeypatch, "wait*4,w*3,wait*5", 12, (256, 128))
    changed = 1 + sum(a != b for a, b in zip(poses, poses[1:], strict=False))
    assert len(poses) == 12 and 3 <= changed <= 4  # the start pose, then the steps
    # One preview, and one push-pull mip chain, per pose; none for the still frames.
    assert counts["preview"] == counts["mipmaps"] == changed
    # A 2:1 window: the panorama covers every pixel, nothing to clear.
    assert counts["clear"] == 0
    assert rgb.reshape(-1, 3).any(-1).mean() > 0.99


def test_black_bars_are_cleared_every_frame(monkeypatch):
    # 256 x 128 and two bars of 16 rows; H hides the overlay (it would cover the top bar).
    counts, _, rgb = _session(monkeypatch, "h,w*4", 6, (256, 160))
    assert counts["clear"] == 6
    assert not rgb[:16].any() and not rgb[-16:].any()
    assert rgb[16:-16].reshape(-1, 3).any(-1).mean() > 0.99
