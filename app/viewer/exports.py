"""What the viewer writes on a key press: the camera path (O), a screenshot of the window (X)
and the clean panorama on screen (F). A failed write is said on screen and in the terminal;
the session and its keyframes carry on, and its exit status is 1 at the end (a script sees
it). Mixed into `PanoViewer`, whose state it reads."""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np

from panogrf.app.viewer import recording
from panogrf.app.viewer.camera import FlyCamera


class ExportsMixin:
    failed_writes = 0
    """Writes of this session that failed (the session's exit status says so at the end)."""

    def save_path(self) -> None:
        """O: the keyframes' path to ``--path-out``; a failed write is reported, never fatal."""
        from panogrf.app.scene.coverage import path_warning

        if not self.path.keys:
            self.say("no keyframes to save (K adds one)")
            return
        w, h = self.wnd.buffer_size
        keys = [dataclasses.replace(k, c2w=self.setup.world(k.c2w)) for k in self.path.keys]
        try:
            path = recording.recorded_path(
                keys, self.perspective, self.setup.preview_height, self.setup.fps, w / h
            )
        except (ValueError, MemoryError, OverflowError) as exc:
            self.failed_writes += 1
            self.say(f"cannot save the camera path: {exc}")
            return
        ok, message = recording.save_path_file(self.setup.path_out, path)
        self.failed_writes += not ok
        self.say(message)
        sources = np.stack([self.setup.world(c) for c in self.setup.c2w])
        warning = path_warning(path.poses, sources) if ok else None
        if warning:
            self.say(warning)

    def _image_name(self, kind: str) -> Path:
        stamp = time.strftime("%Y%m%d_%H%M%S")
        return self.setup.screenshot_dir / f"panogrf_{kind}{stamp}_{self.frame_count:05d}.png"

    def _screenshot(self) -> None:
        """X: the window as it is (overlay included; F saves the clean panorama)."""
        w, h = self.wnd.buffer_size
        data = self.wnd.fbo.read(viewport=(0, 0, w, h), components=3)
        img = np.frombuffer(data, np.uint8).reshape(h, w, 3)[::-1]
        out = self._image_name("")
        ok, problem = recording.save_image_file(out, img)
        if not ok:
            self.failed_writes += 1
            self.say(f"cannot save the screenshot {out}: {problem}")
            return
        c = FlyCamera.from_c2w(self.setup.world(self.view_pose()))
        p = c.position
        self.say(
            f"screenshot {out} at {p[0]:+.3f} {p[1]:+.3f} {p[2]:+.3f} "
            f"yaw {math.degrees(c.yaw):+.1f} pitch {math.degrees(c.pitch):+.1f}"
        )

    def _export_panorama(self, pose: np.ndarray) -> None:
        """F: the panorama of the pose on screen, 2:1 at its own resolution, no overlay: the
        refined frame when it is shown, the source in source mode, else the GL preview."""
        if self.mode == "sources":
            rgb, what = self.setup.images[self.source_index], f"source view {self.source_index}"
        elif self.shown_level is not None and self.refined_rgb is not None:
            total = self.refinement.levels
            rgb, what = self.refined_rgb, f"refined level {self.shown_level + 1}/{total}"
        else:
            s = self.setup
            geometry = s.moving_height if s.sharp else None  # what the viewer shows
            rgb, _ = self.preview.render(pose, s.preview_height, geometry_height=geometry)
            self.preview_key = None  # its textures were drawn again
            what = "GL preview"
            self.wnd.use()
        out = self._image_name("pano_")
        ok, problem = recording.save_image_file(out, rgb)
        if not ok:
            self.failed_writes += 1
            self.say(f"cannot save the panorama {out}: {problem}")
        else:
            self.say(f"panorama {out} ({rgb.shape[1]}x{rgb.shape[0]}, {what}, no overlay)")
