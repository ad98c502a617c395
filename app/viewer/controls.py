"""The viewer's keyboard and mouse: which key does what (the list is in
`panogrf.app.viewer.window`), held keys moving and turning the camera each frame, the mouse
dragging the view and the wheel zooming. Mixed into `PanoViewer`, whose state it reads and
changes; key names are moderngl-window's (`panogrf.app.viewer.script.KEY_NAMES`).
"""

from __future__ import annotations

import numpy as np

from panogrf.app.viewer.camera import FlyCamera, walk_speed
from panogrf.app.viewer.script import KEY_NAMES

MODES = ("refined", "preview", "distance", "sources")
LOOK_SPEED = 1.5  # radians per second for the arrow keys
DRAG_SPEED = 0.004  # radians per pixel of mouse drag


class ControlsMixin:
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
