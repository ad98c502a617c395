"""The viewer's overlay: position, what is shown, frame rate, refinement progress, keyframes,
coverage warnings and messages, drawn as a texture over the top-left corner. Mixed into
`PanoViewer`, whose state it reads; the text helpers are in `panogrf.app.viewer.screen`."""

from __future__ import annotations

import time

import moderngl
import numpy as np

from panogrf.app.viewer import screen


class OverlayMixin:
    def _draw_overlay(self, w: int, h: int) -> None:
        now = time.perf_counter()
        if self.overlay_tex is None or now - self.last_overlay > 0.25:
            self.last_overlay = now
            self._update_overlay()
        self.overlay_tex.use(location=1)
        o = self.overlay_prog
        o["u_text"].value = 1
        o["u_size"].value = (float(w), float(h))
        o["u_text_size"].value = (
            float(self.overlay_img.shape[1]),
            float(self.overlay_img.shape[0]),
        )
        th, tw = self.overlay_img.shape[:2]
        self.ctx.viewport = (0, max(0, h - th), min(w, tw), min(h, th))  # only its pixels
        self.ctx.enable(moderngl.BLEND)
        self.ctx.blend_func = moderngl.SRC_ALPHA, moderngl.ONE_MINUS_SRC_ALPHA
        self.overlay_quad.render(moderngl.TRIANGLES, vertices=3)
        self.ctx.viewport = (0, 0, w, h)
        self.ctx.disable(moderngl.BLEND)

    def _coverage_lines(self, pose: np.ndarray) -> list[str]:
        """Warnings while the camera is outside the region the sources cover or inside an
        object (behind the surface its nearest source sees); logged once when they start."""
        from panogrf.app.scene.coverage import (
            behind_surface,
            covered_radius,
            nearest_source_distance,
        )

        sources = self.setup.c2w
        lines = []
        far = float(nearest_source_distance(pose[None], sources)[0])
        outside = far > covered_radius(sources)
        if outside:
            lines.append(f"WARNING outside the covered region: {far:.2f} m from a source")
        inside = behind_surface(pose[:3, 3], sources, self.setup.depth)
        if inside is not None:
            k, dist, surface = inside
            lines.append(
                f"WARNING inside an object: {dist:.2f} m from source {k}, whose surface "
                f"there is {surface:.2f} m away"
            )
        state = (outside, inside is not None)
        if state != self.warned:
            self.warned = state
            for line in lines:
                self.setup.log(line)
        return lines

    def _update_overlay(self) -> None:
        pose = self.view_pose()
        p = pose[:3, 3]
        recent = self.frame_times[-30:]
        fps = len(recent) / max(sum(recent), 1e-6) if recent else 0.0
        status = self.refinement.status_text()
        levels = self.refinement.levels
        refining = self.refinement.worker is not None
        shown = screen.shown_label(self.mode, self.shown_level, levels, self.source_index, refining)
        view = f"perspective {self.camera.fov:.0f} deg" if self.perspective else "panorama"
        lines = [
            f"pos {p[0]:+.2f} {p[1]:+.2f} {p[2]:+.2f} m  speed {self.camera.speed:.2f} m/s",
            f"{shown}  {view}",
            f"{fps:.0f} fps  {status}",
            *([refiner.status_text()] if (refiner := self.setup.scene_refiner) else []),
            self.path.status(),
            *self._coverage_lines(pose),
            *self.messages.lines(time.perf_counter()),
        ]
        img = screen.overlay_image(lines, legend=self.mode == "distance")
        self.overlay_img = img
        if self.overlay_tex is None or self.overlay_tex.size != (img.shape[1], img.shape[0]):
            if self.overlay_tex is not None:
                self.overlay_tex.release()
            self.overlay_tex = self.ctx.texture((img.shape[1], img.shape[0]), 4)
        self.overlay_tex.write(np.ascontiguousarray(img))
