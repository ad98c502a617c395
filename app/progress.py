"""Showing the stages of `panogrf.model.progress` on the terminal, in logs and in the viewer.

`TerminalProgress` writes to stderr: on a terminal a tqdm bar per stage (its name, k/n,
elapsed and ETA); elsewhere (a log file, a pipe) plain lines ``stage: k/n, elapsed 1.2 s,
eta 3.4 s``, a stage's first and last and at most one a second between. A stage is shown once
it has taken a second: one done sooner adds nothing to the screen or the log. A heartbeat thread
refreshes the innermost open stage when its unit of work is taking long (a preparation is one
outer stage around its inner ones, which covers the work between them), so nothing waits
silently for more than about a second. Commands with ``--quiet``
(`panogrf.app.runtime.PrepareOptions`) get it from `panogrf.app.cli` unless they pass it.

`StageWatch` keeps the latest stage of one thread for the viewer's overlay.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

from panogrf.model.progress import Stage, listening

#: The terminal's bar: the stage's name, k/n, elapsed and ETA.
BAR = "{desc}: {n_fmt}/{total_fmt} |{bar}| {elapsed} elapsed, eta {remaining}"
#: Seconds between two plain lines of one stage, and between a slow stage's refreshes.
INTERVAL = 1.0


class TerminalProgress:
    """A `panogrf.model.progress.Listener` that shows every stage on ``stream`` (stderr)."""

    def __init__(
        self, stream=None, tty: bool | None = None, interval: float | None = None, clock=None
    ) -> None:
        self.stream = stream if stream is not None else sys.stderr
        if tty is None:
            isatty = getattr(self.stream, "isatty", None)
            tty = bool(isatty and isatty())
        self.tty = tty
        self.interval = INTERVAL if interval is None else interval
        self.clock = clock or time.monotonic
        self._lock = threading.RLock()
        self._open: dict[int, dict] = {}  # id(stage) -> {"stage", "bar", "shown", "shown_done"}
        self._stop = threading.Event()
        self._beat: threading.Thread | None = None

    # -- the listener -------------------------------------------------------------------------
    def started(self, stage: Stage) -> None:
        if stage.total <= 0:  # no work (e.g. no view with sources): nothing to show
            return
        with self._lock:
            # Quiet until it has taken `interval` (`advanced`, or the heartbeat's `beat`).
            entry = {"stage": stage, "bar": None, "shown": self.clock(), "shown_done": 0}
            entry["quiet"] = True
            self._open[id(stage)] = entry

    def _show(self, entry: dict) -> None:
        """Start showing a stage: its bar on a terminal, else its line."""
        entry["quiet"] = False
        stage = entry["stage"]
        if self.tty:
            from tqdm import tqdm

            entry["bar"] = tqdm(
                total=stage.total,
                initial=stage.done,
                desc=stage.name,
                file=self.stream,
                leave=True,
                dynamic_ncols=True,
                bar_format=BAR,
            )
            entry["shown"] = self.clock()
        else:
            self._line(entry)

    def advanced(self, stage: Stage) -> None:
        with self._lock:
            entry = self._open.get(id(stage))
            if entry is None:
                return
            if entry["quiet"]:
                if self.clock() - entry["shown"] >= self.interval:
                    self._show(entry)
            elif entry["bar"] is not None:
                bar = entry["bar"]
                bar.update(stage.done - bar.n)
                entry["shown"] = self.clock()
            elif stage.done >= stage.total or self.clock() - entry["shown"] >= self.interval:
                self._line(entry)

    def ended(self, stage: Stage) -> None:
        with self._lock:
            entry = self._open.pop(id(stage), None)
            if entry is None or entry["quiet"]:  # a stage that never took long: no lines
                return
            if entry["bar"] is not None:
                entry["bar"].close()
            elif entry["shown_done"] != stage.done:
                self._line(entry)

    # -- output --------------------------------------------------------------------------------
    def _line(self, entry: dict) -> None:
        stage = entry["stage"]
        try:
            print(stage.text(), file=self.stream, flush=True)
        except (OSError, ValueError):  # a closed stream costs the progress only
            pass
        entry["shown"] = self.clock()
        entry["shown_done"] = stage.done

    def beat(self) -> None:
        """Refresh the innermost open stage (the latest started) when it was not shown for
        ``interval`` seconds (the heartbeat calls this): an outer stage speaks up only
        between its inner ones."""
        with self._lock:
            if not self._open:
                return
            entry = list(self._open.values())[-1]
            now = self.clock()
            if now - entry["shown"] < self.interval:
                return
            if entry["quiet"]:
                self._show(entry)
            elif entry["bar"] is not None:
                entry["bar"].refresh()
                entry["shown"] = now
            else:
                self._line(entry)

    def _beating(self) -> None:
        # A few times an interval; never a busy loop (an interval of 0 shows every stage).
        while not self._stop.wait(max(self.interval / 4, 0.05)):
            self.beat()

    def close(self) -> None:
        """End the heartbeat and every stage still open (one an exception left)."""
        self._stop.set()
        if self._beat is not None:
            self._beat.join(2.0)
        with self._lock:
            for entry in list(self._open.values()):
                if entry["bar"] is not None:
                    entry["bar"].close()
            self._open.clear()

    def start(self) -> TerminalProgress:
        self._beat = threading.Thread(target=self._beating, name="panogrf-progress", daemon=True)
        self._beat.start()
        return self


@contextmanager
def terminal_progress(quiet: bool = False, stream=None) -> Iterator[TerminalProgress | None]:
    """Every stage shown on ``stream`` (stderr) for the ``with`` block; nothing when quiet."""
    if quiet:
        yield None
        return
    shower = TerminalProgress(stream).start()
    try:
        with listening(shower):
            yield shower
    finally:
        shower.close()


class StageWatch:
    """The latest stage opened by one thread (the viewer's overlay reads `text`)."""

    def __init__(self, thread: int | None = None) -> None:
        self.thread = thread
        self._lock = threading.Lock()
        self._stage: Stage | None = None

    def _mine(self, stage: Stage) -> bool:
        return self.thread is None or stage.thread == self.thread

    def started(self, stage: Stage) -> None:
        if self._mine(stage):
            with self._lock:
                self._stage = stage

    def advanced(self, stage: Stage) -> None:
        pass

    def ended(self, stage: Stage) -> None:
        pass

    def text(self) -> str | None:
        """``stage: k/n, elapsed, eta`` of the latest stage, or None before any."""
        with self._lock:
            stage = self._stage
        return None if stage is None else stage.text()
