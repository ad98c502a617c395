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
H toggle the overlay, Esc quit.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import moderngl
import moderngl_window as mglw
import numpy as np

from panogrf.app.scene.types import shifted
from panogrf.app.viewer import recording, screen
from panogrf.app.viewer.camera import FlyCamera, walk_speed
from panogrf.app.viewer.exports import ExportsMixin
from panogrf.app.viewer.overlay import OverlayMixin
from panogrf.app.viewer.refinement import Refinement
from panogrf.app.viewer.script import KEY_NAMES, ScriptPlayer, parse_script

__all__ = ["PanoViewer", "ViewerSetup", "parse_script", "run_viewer"]
from panogrf.shaders import load as load_shader

MODES = ("refined", "preview", "distance", "sources")
LOOK_SPEED = 1.5  # radians per second for the arrow keys
DRAG_SPEED = 0.004  # radians per pixel of mouse drag


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

        return cls(
            images=to_uint8(views.images),
            depth=views.depth["full"][:, 0].cpu().numpy(),
            c2w=views.c2w.cpu().numpy(),
            start_pose=views.c2w[start_frame].cpu().numpy().astype(np.float64),
            masks=None
            if (m := getattr(views, "nadir_mask", None)) is None
            else m[:, 0].cpu().numpy(),
            **kw,
        )


class PanoViewer(ExportsMixin, OverlayMixin, mglw.WindowConfig):
    gl_version = (3, 3)
    title = "panogrf"
    window_size = (1024, 512)
    aspect_ratio = None
    resizable = True
    vsync = False
    clear_color = (0.0, 0.0, 0.0, 1.0)
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
            s.images,
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
        refiner = self.setup.scene_refiner
        prepared = refiner.take() if refiner is not None else None
        if prepared is None:
            return
        self.scene_swapped = True
        views = prepared.views
        depth = views.depth["full"][:, 0].cpu().numpy()
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

    def _make_keymap(self) -> dict:
        k = self.wnd.keys
        out = {}
        for name in KEY_NAMES:
            code = getattr(k, name, None)
            if code is not None:
                out[code] = name
        # moderngl-window's pyglet keys name the braces `{` `}` as the brackets: the keys
        # `[` and `]` themselves (their ASCII codes in pyglet) did nothing in a real window.
        if getattr(k, "LEFT_BRACKET", None) == ord("{"):
            out[ord("[")], out[ord("]")] = "LEFT_BRACKET", "RIGHT_BRACKET"
        return out

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
    def on_key_event(self, key, action, modifiers) -> None:
        name = self._keymap.get(key)
        if name is None:
            return
        if action == self.wnd.keys.ACTION_PRESS:
            self.held.add(name)
            self.press(name)
        elif action == self.wnd.keys.ACTION_RELEASE:
            self.held.discard(name)

    def press(self, name: str) -> None:
        """One-shot actions of a key (held keys act in `_apply_held`)."""
        cam = self.camera
        if name == "ESCAPE":
            self.wnd.close()
        elif name in ("LEFT_BRACKET", "RIGHT_BRACKET"):
            cam.speed = float(
                np.clip(cam.speed * (0.8 if name == "LEFT_BRACKET" else 1.25), 0.05, 20)
            )
        elif name in ("MINUS", "EQUAL"):
            cam.fov = float(np.clip(cam.fov + (5 if name == "MINUS" else -5), 20, 140))
        elif name == "V":
            self.perspective = not self.perspective
        elif name.startswith("NUMBER_"):
            self.mode = MODES[int(name[-1]) - 1]
        elif name == "TAB":
            self.source_index = (self.source_index + 1) % len(self.sources)
        elif name == "H":
            self.show_overlay = not self.show_overlay
        elif name == "J":
            self._go_to(self.setup.c2w[self.source_index])
            self.say(f"at source view {self.source_index} (Tab: next source)")
        elif name == "R":
            self.camera = FlyCamera.from_c2w(
                self.setup.start_pose, speed=walk_speed(self.setup.c2w)
            )
            self.say("view reset to the start")
        elif name in ("K", "C", "G", "BACKSPACE", "DELETE", "COMMA", "PERIOD"):
            message, go_to = self.path.edit(name, self.view_pose(), cam.fov)
            if go_to is not None:
                self._go_to(go_to.c2w, go_to.fov)
            self.say(message)
        elif name == "P":
            if self.path.play_pose is not None:  # stopped where it is
                self._go_to(self.path.play_pose)
            self.say(self.path.toggle_playback())
        elif name == "O":
            self.save_path()
        elif name == "X":
            self.request_screenshot = True
        elif name == "F":
            self.request_export = True

    request_screenshot = False
    request_export = False

    def on_mouse_drag_event(self, x, y, dx, dy) -> None:
        # The image follows the cursor, as in every 360° photo viewer: dragging right turns the
        # camera left. Panorama mode shows every direction: only the heading turns it.
        # ``--drag-looks`` inverts it: the camera turns with the mouse, as in games.
        sign = -1.0 if self.setup.drag_looks else 1.0
        self.camera.look(
            sign * dx * DRAG_SPEED, sign * dy * DRAG_SPEED if self.perspective else 0.0
        )

    def on_mouse_scroll_event(self, x_offset: float, y_offset: float) -> None:
        """The wheel zooms: up narrows the field of view, as `=` does."""
        cam = self.camera
        cam.fov = float(np.clip(cam.fov - 5 * y_offset, 20, 140))

    def _apply_held(self, dt: float) -> None:
        h, cam = self.held, self.camera
        fwd = ("W" in h) - ("S" in h)
        right = ("D" in h) - ("A" in h)
        up = ("E" in h) - ("Q" in h)
        if fwd or right or up:
            cam.move(fwd, right, up, dt)
        yaw = ("LEFT" in h) - ("RIGHT" in h)
        pitch = (("UP" in h) - ("DOWN" in h)) if self.perspective else 0
        if yaw or pitch:
            cam.look(yaw * LOOK_SPEED * dt, pitch * LOOK_SPEED * dt)

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
        refined, self.shown_level = None, None
        if self.mode == "refined":
            done, new = self.refinement.frame()
            if done is not None:
                if new:
                    self._upload_refined(done.rgb)
                refined, self.shown_level = self.refined_tex, done.level
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
        self.ctx.viewport = box
        rotate = self.mode == "sources"
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
            rot = self.setup.c2w[self.source_index][:3, :3].T @ pose[:3, :3]
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
