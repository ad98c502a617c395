"""The viewer window (moderngl-window): preview while moving, refined when still, camera paths.

The same class runs in a real window (pyglet backend) and headless (EGL), a backend switch.
Per frame: held keys move the camera; the pose goes to the refinement state machine
(`panogrf.app.viewer.refinement`), which cancels or requests the worker's refinement; the window
draws the GL preview, or the state machine's newest finished level once there is one.
The display is the whole panorama or a perspective view, in colour or as distance.

Panorama mode shows the whole sphere, so there is nothing to look up or down to: as in any 360
degree photo viewer, the panorama stays level (horizon straight), yaw scrolls it, and vertical
look input is ignored (the pitch set in perspective mode is kept for it); the panorama keeps
2:1 in any window (black bars). The source views (4) turn with the camera's heading. A
camera path plays in real time, by the transitions of its keyframes (`--fixed-step` advances
a fixed time per frame instead, for deterministic sessions).

Keys: W/A/S/D move, Q/E down/up, arrows or mouse drag look, [ ] speed, - = field of view,
V panorama/perspective, 1 refined, 2 preview, 3 distance, 4 source views (Tab: next source,
J: jump to it), R reset the view, K add keyframe, G go to the next keyframe, Backspace delete
the selected keyframe, , . its transition -/+ 0.5 s, C clear keyframes, P play/stop the path,
O save it (camera_path.json), X screenshot (the window), F clean panorama (2:1, no overlay),
H toggle the overlay, Esc quit. The keys and the mouse are handled in
`panogrf.app.viewer.controls`; what the window is given, `ViewerSetup`, is in
`panogrf.app.viewer.setup`.
"""

from __future__ import annotations

import logging
import math
import time

import moderngl
import moderngl_window as mglw
import numpy as np

from panogrf.app.viewer import recording, screen
from panogrf.app.viewer.camera import FlyCamera, walk_speed
from panogrf.app.viewer.controls import ControlsMixin
from panogrf.app.viewer.exports import ExportsMixin
from panogrf.app.viewer.overlay import OverlayMixin
from panogrf.app.viewer.refinement import Refinement
from panogrf.app.viewer.script import ScriptPlayer, parse_script
from panogrf.app.viewer.setup import UPSAMPLED_MOVING_ROWS as UPSAMPLED_MOVING_ROWS
from panogrf.app.viewer.setup import ViewerSetup, preview_sources

__all__ = ["PanoViewer", "ViewerSetup", "parse_script", "run_viewer"]
from panogrf.shaders import load as load_shader


class PanoViewer(ExportsMixin, OverlayMixin, ControlsMixin, mglw.WindowConfig):
    gl_version = (3, 3)
    title = "panogrf"
    window_size = (1024, 512)
    aspect_ratio = None
    resizable = True
    vsync = False
    # No clear before every frame: the display pass covers the whole window unless the
    # letterbox leaves bars, and only then is the window cleared (`on_render`).
    clear_color = None
    # moderngl-window logs its GL vendor, version and timing at INFO on stderr: ten lines of
    # noise around the viewer's own messages (and despite --quiet). Warnings still show.
    log_level = logging.WARNING
    setup: ViewerSetup | None = None  # set by `run_viewer` before the window is made

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)

        s = self.setup
        # The two nearest sources and simplified meshes: a CPU rasteriser's vertex stage and the
        # per-frame seam split scale with the triangles (see benchmarks/viewer.py).
        self.preview = self._make_preview(s.depth)
        # One display program per (perspective, distance, fill, rotate, sharp) mode, made when
        # first needed.
        self.displays: dict[tuple[int, ...], tuple] = {}
        self.overlay_prog = self.ctx.program(
            vertex_shader=load_shader("fullscreen.vert"),
            fragment_shader=load_shader("overlay.frag"),
        )
        self.overlay_quad = self.ctx.vertex_array(self.overlay_prog, [])
        self.sources = [self._texture(img) for img in s.images]
        h = s.preview_height
        self.refined_tex = self.ctx.texture((2 * h, h), 3)
        self.refined_tex.repeat_x = True
        self.refined_rgb: np.ndarray | None = None
        self.shown_level: int | None = None  # the refined level on screen (None: not refined)
        self.overlay_tex = None
        self.overlay_img = None
        self.camera = FlyCamera.from_c2w(s.start_pose, speed=walk_speed(s.c2w))
        self.mode = "refined"
        self.perspective = False
        self.show_overlay = True
        self.source_index = 0
        self.held: set[str] = set()
        self.path = recording.KeyframeSession()
        self.warned: tuple[bool, bool] = (False, False)  # (outside, inside) last logged
        self.refinement = Refinement(s.worker)
        self.frame_count = 0
        self.frame_times: list[float] = []  # seconds between consecutive frame starts
        self.moving_frame_times: list[float] = []  # the same, of frames where the camera moved
        self.neural_moving_frames = 0  # frames that moved and showed the neural view (live)
        # Moving frames while the scene's depth was still refined in the background.
        self.refining_frame_times: list[float] = []
        self.scene_swapped = False
        self.last_start: float | None = None
        self.preview_key = None
        self.preview_out = None
        self.script = ScriptPlayer(s.script)
        self.last_overlay = 0.0
        self.messages = screen.Messages()
        self._keymap = self._make_keymap()
        if s.keyframes:
            self.path.keys = [
                recording.Keyframe(k.c2w.copy(), k.fov, k.transition) for k in s.keyframes
            ]
            self.say(
                f"{len(s.keyframes)} keyframes from {s.keyframes_from} (P plays them, G goes to "
                "each, O saves)"
            )

    # -- helpers -------------------------------------------------------------------------------
    def _make_preview(self, depth: np.ndarray):
        from panogrf.renderer.gl_preview import PreviewRenderer

        s = self.setup
        return PreviewRenderer(
            self.ctx,
            preview_sources(s.images, s.preview_height),
            depth,
            s.c2w,
            mesh_height=s.mesh_height,
            max_views=s.max_views,
            mesh_triangles=s.mesh_triangles,
            masks=s.masks,
        )

    def _swap_refined_scene(self) -> None:
        """The background depth refinement finished: the GL preview's meshes and the render
        worker's cache come from the refined depth from this frame on, and the still view is
        refined again from it."""
        from panogrf.model.depth_config import DepthMode

        refiner = self.setup.scene_refiner
        prepared = refiner.take() if refiner is not None else None
        if prepared is None:
            return
        self.scene_swapped = True
        views = prepared.views
        depth = views.depth[DepthMode.FULL][:, 0].cpu().numpy()
        old, self.preview = self.preview, self._make_preview(depth)
        old.release()
        self.setup.depth = depth
        self.preview_key = self.preview_out = None
        if self.setup.worker is not None:
            self.setup.worker.replace_cache(views.cache_for("panogrf", prepared.models))
            self.refinement.restart()
        self.say(refiner.status_text())

    def _texture(self, rgb: np.ndarray) -> moderngl.Texture:
        tex = self.ctx.texture((rgb.shape[1], rgb.shape[0]), 3, np.ascontiguousarray(rgb))
        tex.repeat_x = True
        tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
        return tex

    def say(self, text: str) -> None:
        """A message on the overlay (wrapped, the last few lines) and in the terminal."""
        self.messages.add(text, time.perf_counter())
        self.setup.log(text)

    def view_pose(self) -> np.ndarray:
        """The pose on screen [4, 4]: the path's while playing; level in panorama mode."""
        if self.path.play_pose is not None:
            return self.path.play_pose
        return self.camera.c2w if self.perspective else self.camera.level_c2w

    def _go_to(self, c2w: np.ndarray, fov: float | None = None) -> None:
        cam = self.camera
        self.camera = FlyCamera.from_c2w(c2w, speed=cam.speed, fov=cam.fov if fov is None else fov)

    # -- input ---------------------------------------------------------------------------------
    @property
    def refine_log(self) -> list[tuple[int, float]]:
        """(level, seconds from the camera stopping to that level on screen), in order."""
        return self.refinement.log

    # -- frame ---------------------------------------------------------------------------------
    def on_render(self, time_s: float, frame_time: float) -> None:
        # Frame period: from this frame's start to the next one's, so it includes the GL work
        # finished at buffer swap, not only the commands issued here.
        start = time.perf_counter()
        if self.last_start is not None:
            self.frame_times.append(start - self.last_start)
            if self.refinement.moved:
                self.moving_frame_times.append(start - self.last_start)
                if self.setup.scene_refiner is not None and not self.scene_swapped:
                    self.refining_frame_times.append(start - self.last_start)
        self.last_start = start
        dt = self.setup.fixed_step or min(frame_time, 0.1)
        self._swap_refined_scene()
        self.script.step(self.press, self.held, self.refinement.done)
        if self.path.playback is not None:  # real time: the wall clock's whole frame time
            pose, self.camera.fov, finished = self.path.advance(self.setup.fixed_step or frame_time)
            if finished:
                self._go_to(pose)
        else:
            self._apply_held(dt)
            pose = self.view_pose()
        moved = self.refinement.observe(pose)

        # What to show; the GL preview is drawn only when it is shown (or shown through).
        refined, self.shown_level, frame_rot = None, None, None
        if self.mode == "refined":
            done, new = self.refinement.frame()
            if done is not None:
                if new:
                    self._upload_refined(done.rgb)
                refined, self.shown_level = self.refined_tex, done.level
                if not np.allclose(done.c2w[:3, :3], pose[:3, :3], atol=1e-9):
                    frame_rot = done.c2w[:3, :3]  # live: a frame of an earlier pose, turned
        coarse, is_depth, fill, sharp_inputs = None, False, False, None
        if self.mode == "sources":
            pano = self.sources[self.source_index]
        elif refined is not None:
            pano = refined
        else:
            distance = self.mode == "distance"  # exact distances only when shown
            s = self.setup
            sharp = s.preview_height if s.sharp and not distance else None
            height = s.preview_height
            if s.moving_height and (moved or sharp):
                height = min(s.moving_height, s.preview_height)
            key = (pose.tobytes(), height, distance, sharp)
            if key != self.preview_key:  # a still camera's preview is on the GPU already
                self.preview_out = self.preview.render_to_framebuffer(
                    pose,
                    height,
                    fill_top=False,
                    distance=distance,
                    sharp_height=sharp,
                    sharp_pass=False,
                )
                self.preview_key = key
            out = self.preview_out
            if distance:
                pano, is_depth = out.dist, True
            elif out.sharp is not None:
                pano, sharp_inputs = None, out.sharp
            else:
                pano, coarse, fill = out.blend, out.coarse, True
        self.wnd.use()
        w, hh = self.wnd.buffer_size
        # The panorama keeps 2:1 (black bars); a perspective view fills the window.
        box = (0, 0, w, hh) if self.perspective else screen.letterbox(w, hh)
        if box != (0, 0, w, hh):  # black bars; else every pixel is drawn below
            self.wnd.clear(0.0, 0.0, 0.0, 1.0)
        self.ctx.viewport = box
        if refined is not None and moved:
            self.neural_moving_frames += 1
        if self.mode == "sources":
            frame_rot = self.setup.c2w[self.source_index][:3, :3]
        rotate = frame_rot is not None
        d, quad = self._display(
            int(self.perspective),
            int(is_depth),
            int(fill),
            int(rotate),
            int(sharp_inputs is not None),
        )
        if sharp_inputs is not None:  # the preview's colours computed as they are shown
            self.preview.bind_sharp(d, sharp_inputs, 2)
        else:
            pano.use(location=0)
            d["u_pano"].value = 0
        if fill:
            coarse.use(location=1)
            d["u_coarse"].value = 1
        if self.perspective:
            d["u_fov"].value = math.radians(self.camera.fov)
        if rotate:  # view directions into the source's frame; GL reads matrices column-major
            rot = frame_rot.T @ pose[:3, :3]
            d["u_rot"].write(np.ascontiguousarray(rot.T, np.float32).tobytes())
        d["u_origin"].value = (float(box[0]), float(box[1]))
        d["u_size"].value = (float(box[2]), float(box[3]))
        if is_depth:
            d["u_max_depth"].value = screen.MAX_DISTANCE_M
        quad.render(moderngl.TRIANGLES, vertices=3)
        self.ctx.viewport = (0, 0, w, hh)
        if self.request_export:
            self.request_export = False
            self._export_panorama(pose)
        if self.show_overlay:
            self._draw_overlay(w, hh)
        if self.request_screenshot:
            self.request_screenshot = False
            self._screenshot()
        self.frame_count += 1
        if not moved and self.path.playback is None:
            self.refinement.idle(start, self.setup.fps)
        if self.setup.frames is not None and self.frame_count >= self.setup.frames:
            self.wnd.close()

    def _display(
        self, perspective: int, depth: int, fill: int, rotate: int, sharp: int = 0
    ) -> tuple:
        key = (perspective, depth, fill, rotate, sharp)
        if key not in self.displays:
            defines = {
                "PERSPECTIVE": perspective,
                "DEPTH": depth,
                "FILL": fill,
                "ROTATE": rotate,
                "SHARP": sharp,
                "VIEWS": self.preview.max_views,
            }
            prog = self.ctx.program(
                vertex_shader=load_shader("fullscreen.vert"),
                fragment_shader=load_shader("display.frag", defines),
            )
            self.displays[key] = (prog, self.ctx.vertex_array(prog, []))
        return self.displays[key]

    def _upload_refined(self, rgb: np.ndarray) -> None:
        if (rgb.shape[1], rgb.shape[0]) != self.refined_tex.size:
            self.refined_tex.release()
            self.refined_tex = self.ctx.texture((rgb.shape[1], rgb.shape[0]), 3)
            self.refined_tex.repeat_x = True
            self.refined_tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self.refined_tex.write(np.ascontiguousarray(rgb))
        self.refined_rgb = rgb

    def on_close(self) -> None:
        self.refinement.stop()


def run_viewer(setup: ViewerSetup, window: str = "pyglet", size: tuple[int, int] = (1024, 512)):
    """Open the viewer and block until it closes; returns the window config (for its stats)."""
    PanoViewer.setup = setup
    args = ["--window", window, "--size", f"{size[0]}x{size[1]}"]
    if window == "headless":
        args += ["--backend", "egl"]
    config = mglw.create_window_config_instance(PanoViewer, args=args)
    mglw.run_window_config_instance(config)
    return config
