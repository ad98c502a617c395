"""Progress of the long computations: named stages that count their units of work.

The code that works (depth estimation, the per-scene refinement, feature maps, the frames of a
camera path) opens a `stage` with its name and number of units and advances it after each; it
knows nothing of who shows it. Listeners (`listening`) get every stage's start, advance and
end: the terminal's progress bar or log lines (`panogrf.app.progress`), the viewer's overlay,
a test's recorder. Without a listener a stage costs a few attribute reads.

Listeners are process-wide (a stage opened in a worker thread reaches them too); each
`Stage` says which thread opened it, so a listener may follow one thread only.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Protocol

_lock = threading.Lock()
_listeners: list[Listener] = []


class Listener(Protocol):
    def started(self, stage: Stage) -> None: ...
    def advanced(self, stage: Stage) -> None: ...
    def ended(self, stage: Stage) -> None: ...


class Stage:
    """One named stage of ``total`` units (``done`` of them done so far)."""

    def __init__(self, name: str, total: int) -> None:
        self.name = name
        self.total = max(int(total), 0)
        self.done = 0
        self.start = time.perf_counter()
        self.thread = threading.get_ident()
        self.closed = False

    @property
    def elapsed(self) -> float:
        return time.perf_counter() - self.start

    @property
    def eta(self) -> float | None:
        """Seconds left at the pace so far (None before the first unit)."""
        if self.done <= 0 or self.total <= 0:
            return None
        return self.elapsed / self.done * max(self.total - self.done, 0)

    def advance(self, units: int = 1) -> None:
        self.done = min(self.done + units, self.total) if self.total else self.done + units
        for listener in _current():
            listener.advanced(self)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        for listener in _current():
            listener.ended(self)

    def text(self) -> str:
        """``name: k/n, elapsed 1.2 s, eta 3.4 s`` (the plain log line and the overlay)."""
        eta = self.eta
        left = "?" if eta is None else f"{eta:.1f} s"
        return f"{self.name}: {self.done}/{self.total}, elapsed {self.elapsed:.1f} s, eta {left}"


def _current() -> list[Listener]:
    with _lock:
        return list(_listeners)


def open_stage(name: str, total: int) -> Stage:
    """A stage of ``total`` units, announced to the listeners; ``advance()`` it after each
    unit and ``close()`` it at the end (`stage` does both for a ``with`` block; a stage left
    open by an exception is closed by the listener's own end)."""
    s = Stage(name, total)
    for listener in _current():
        listener.started(s)
    return s


@contextmanager
def stage(name: str, total: int) -> Iterator[Stage]:
    """A stage of ``total`` units for the ``with`` block; ``advance()`` it after each unit."""
    s = open_stage(name, total)
    try:
        yield s
    finally:
        s.close()


@contextmanager
def listening(listener: Listener) -> Iterator[Listener]:
    """``listener`` gets every stage's events for the ``with`` block."""
    with _lock:
        _listeners.append(listener)
    try:
        yield listener
    finally:
        with _lock:
            if listener in _listeners:
                _listeners.remove(listener)
