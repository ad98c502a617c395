"""The refinement state machine, beside the render worker: the window only reports the pose.

States of the view on screen, one owner for all of them (nerfstudio's viewer keeps the same in
its ``RenderStateMachine``; our worker keeps its cancellation per chunk of rays):

- ``off``: no worker (``panogrf view --no-refine``), the GL preview only;
- ``moving``: the pose changed this frame; whatever was being refined is cancelled;
- ``settling``: still, but for less than `STILL_DELAY` (a camera held for one frame between
  two key presses is not worth a refinement);
- ``refining``: the worker refines the still pose level by level; `frame` hands each finished
  level of *this* request to the window (a level of an older pose never reaches the screen);
- ``refined``: every level is done.

Live (`RenderWorker.live`, on a GPU): every moved pose is requested at once, nothing is
cancelled, and `frame` hands out the newest finished frame of any request, one render behind
the camera while it moves.

The window calls `observe` once per frame with the pose it shows, draws `frame` when there is
one, and sleeps with `idle`. Nothing here touches GL.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from panogrf.app.viewer import screen
from panogrf.app.viewer.worker import Refined, RenderWorker

#: Seconds the camera must stay still before refinement starts.
STILL_DELAY = 0.1
#: Frame rate while the camera is still and the worker refines: each redraw of an unchanged
#: view takes the cores from the refinement (about 15 % of its speed at 30 fps on 2 cores); a
#: finished level is shown at once all the same (`RenderWorker.wait_for_result`).
REFINING_FPS = 15.0

STATES = ("off", "moving", "settling", "refining", "refined")


class Refinement:
    """When to cancel, when to ask the worker for a pose, and which finished frame is current."""

    def __init__(
        self,
        worker: RenderWorker | None,
        still_delay: float = STILL_DELAY,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        self.worker = worker
        self.still_delay = still_delay
        self.clock = clock
        self.pose: np.ndarray | None = None
        self.still_since = clock()
        self.moved = False
        self.requested = False
        self.generation = -1  # the worker's generation of the current request
        self.shown: tuple[int, int] = (-1, -1)  # (generation, level) last handed out as new
        self.log: list[tuple[int, float]] = []  # (level, seconds from still to that level shown)

    @property
    def levels(self) -> int:
        return len(self.worker.levels) if self.worker is not None else 0

    @property
    def live(self) -> bool:
        return self.worker is not None and self.worker.live

    def observe(self, pose: np.ndarray) -> bool:
        """The pose shown this frame; returns whether it moved. Moving cancels the refinement;
        still for `still_delay` seconds requests it (once per still pose)."""
        now = self.clock()
        self.moved = self.pose is None or not np.allclose(pose, self.pose, atol=1e-9)
        if self.moved:
            self.pose = np.array(pose, np.float64)
            self.still_since = now
            self.requested = False
            if self.live:
                self.generation = self.worker.request(self.pose)
                self.requested = True
            elif self.worker is not None:
                self.worker.cancel()
        elif (
            self.worker is not None
            and not self.requested
            and now - self.still_since >= self.still_delay
        ):
            self.generation = self.worker.request(self.pose)
            self.requested = True
        return self.moved

    def restart(self) -> None:
        """The scene changed under a still camera (refined depth arrived): request the same
        pose again at once; until its first level is done the preview is shown."""
        self.requested = False
        self.shown = (-1, -1)
        self.still_since = self.clock() - self.still_delay

    @property
    def state(self) -> str:
        if self.worker is None:
            return "off"
        if self.moved:
            return "moving"
        if not self.requested:
            return "settling"
        return "refined" if self.worker.status[0] >= self.levels else "refining"

    def done(self) -> bool:
        """Every level of the still view refined (or no refinement at all): a script's wait."""
        return self.state in ("off", "refined")

    def frame(self) -> tuple[Refined | None, bool]:
        """(the newest finished level of the current request or None, whether it is new since
        the last call). A new level is logged with its time since the camera stopped."""
        if self.worker is None or not self.requested:
            return None, False
        latest = self.worker.latest()
        if latest is None or (latest.generation != self.generation and not self.live):
            return None, False
        key = (latest.generation, latest.level)
        new = key != self.shown  # levels may share a size: compare the level, not the image
        if self.live and key < self.shown:  # never back to an older frame
            return None, False
        if new:
            self.shown = key
            if latest.generation == self.generation:  # a frame of the pose on screen
                self.log.append((latest.level, self.clock() - self.still_since))
        return latest, new

    def status_text(self) -> str:
        """What refinement is doing, for the overlay (what is shown is the window's business)."""
        worker = self.worker
        if worker is not None and worker.error:  # the worker died: say why, on screen
            return f"refinement stopped: {worker.error}"
        done, fraction = worker.status if worker is not None else (0, 0.0)
        levels = worker.levels if worker is not None else []
        return screen.refine_status(worker is not None, self.requested, done, fraction, levels)

    def idle(self, frame_start: float, fps: float) -> None:
        """The camera is still: nothing to redraw fast, so leave the cores to the refinement
        until the next frame is due, but wake when the refinement should start (end of the
        debounce) or a refined level is ready."""
        refining = self.state == "refining"
        due = frame_start + 1.0 / (min(fps, REFINING_FPS) if refining else fps)
        if self.worker is not None and not self.requested:
            due = min(due, self.still_since + self.still_delay)
        remaining = due - self.clock()
        if refining:
            self.worker.wait_for_result(remaining)
        elif remaining > 0:
            time.sleep(remaining)

    def stop(self) -> None:
        if self.worker is not None:
            self.worker.stop()
