"""The per-scene depth refinement in the background, while the viewer already shows the scene.

`panogrf view` refines the sources' depth per scene by default (`panogrf.model.refine`, a few
seconds per view on 2 cores). Unless the refined scene is in the disk cache, the window opens
on the plain scene at once and this thread refines it (`session.refine_prepared`, which also
writes the refined scene to the disk cache); the window takes the result at its next frame
(`take`) and swaps it in: the GL preview's meshes and the render worker's cache.
"""

from __future__ import annotations

import sys
import threading
import time

import torch


class SceneRefiner:
    """One background refinement of a `PreparedScene` with a pending refinement."""

    def __init__(self, prepared, log=print, threads: int = 1) -> None:
        self.prepared = prepared
        self.log = log
        self.threads = threads
        """Torch threads of the refinement. One: beside the render worker, whose OpenMP pool
        lives as long as the session, a second pool would outnumber this machine's 2 cores,
        and libgomp then puts idle workers to sleep between kernels, slowing both threads
        (`panogrf.app.viewer.torch_threads`). On the bundled scene, beside an idle render
        worker: 10.3-12.2 s on one thread, 14.9-15.0 s on two (diagnostic runs); alone in a
        thread on two, 7.3 s (`benchmarks/viewer.py`; the refinement with the free-space
        term 8.1 s, 11.4 s here). One thread also leaves the other core
        to the window and the render worker. Torch's count is process-wide for threads started
        later, so the caller's count is put back when the refinement ends."""
        self._caller_threads = torch.get_num_threads()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._result = None  # the refined PreparedScene until taken
        self._taken = False
        self._error: str | None = None
        self._started = 0.0
        self._seconds: float | None = None
        self._thread = threading.Thread(target=self._run, name="panogrf-refine", daemon=True)
        self._watch = None  # the refinement's current stage (`panogrf.app.progress.StageWatch`)

    def start(self) -> SceneRefiner:
        self._started = time.perf_counter()
        self._thread.start()
        return self

    def stop(self, timeout: float = 30.0) -> None:
        """Ask the refinement to stop at its next step (nothing is written) and wait for it."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout)

    def join(self, timeout: float | None = None) -> None:
        self._thread.join(timeout)

    def take(self):
        """The refined `PreparedScene` once it is ready, a single time; else None."""
        with self._lock:
            if self._result is None or self._taken:
                return None
            self._taken = True
            return self._result

    @property
    def seconds(self) -> float | None:
        """How long the refinement took, once it is done."""
        with self._lock:
            return self._seconds

    @property
    def error(self) -> str | None:
        with self._lock:
            return self._error

    def status_text(self) -> str:
        """For the overlay: what the depth refinement is doing."""
        with self._lock:
            if self._error is not None:
                return f"depth refinement failed: {self._error}"
            if self._seconds is not None:
                return f"depth refined ({self._seconds:.1f} s)"
        if self._stop.is_set():
            return "depth refinement stopped"
        text = f"refining depth ({time.perf_counter() - self._started:.0f} s)"
        stage = self._watch.text() if self._watch is not None else None
        return text if stage is None else f"{text}: {stage}"

    def _run(self) -> None:
        from panogrf.app.progress import StageWatch
        from panogrf.app.scene import session
        from panogrf.model.progress import listening

        if self.threads:
            torch.set_num_threads(self.threads)
        self._watch = StageWatch(threading.get_ident())
        try:
            with listening(self._watch):
                out = session.refine_prepared(self.prepared, self._stop.is_set, self.log)
        except Exception as exc:  # shown on screen and in the terminal; the plain scene stays
            message = f"{type(exc).__name__}: {exc}"
            with self._lock:
                self._error = message
            print(f"panogrf view: depth refinement failed: {message}", file=sys.stderr)
            return
        finally:
            if self.threads:
                torch.set_num_threads(self._caller_threads)
        if out is None:  # stopped
            return
        with self._lock:
            self._result = out
            self._seconds = time.perf_counter() - self._started
