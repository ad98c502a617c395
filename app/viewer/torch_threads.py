"""Torch work of the viewer kept off the main thread, so that the threads that do it run fast.

Torch's CPU kernels run in parallel through OpenMP (GNU libgomp in the pip wheels). Each thread
that runs a parallel kernel keeps its own pool of OpenMP workers for as long as it lives, and
libgomp counts the workers of every pool. When they outnumber the CPUs, an idle worker spins
100 times instead of 300,000 before it sleeps (libgomp's manual, GOMP_SPINCOUNT), and each of
torch's many small element-wise kernels then waits for the workers to wake.

So if the main thread has run a parallel kernel, its pool stays alive for the whole session,
and every parallel kernel of the viewer's background threads (the render worker, the depth
refinement) pays this cost. `benchmarks/viewer.py` measures both arrangements in one process on
this 2-core machine (`viewer_round18.json`): with the main thread's pool alive, the refined
512 x 1024 view came 1.66 s after the camera stopped and the bundled scene's depth refinement
took 17.8 s in a thread on two torch threads; with the main thread serial, 1.01 s and 7.3 s.

`panogrf view` therefore never runs a parallel kernel in the main thread: it sets the main
thread's torch thread count to one (`serial_main_thread`) before any torch work, prepares the
scene in a short-lived thread with the session's count (`off_main_thread`; its pool goes when the
thread ends), and the render worker and the depth refinement set their own counts.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TypeVar

import torch

T = TypeVar("T")


@contextmanager
def serial_main_thread() -> Iterator[int]:
    """Inside, the calling thread's own torch kernels run on it alone; yields torch's thread
    count before, for the threads to come (`off_main_thread`, the workers), and puts it back
    on exit. Enter it in the main thread before any torch work."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield threads
    finally:
        torch.set_num_threads(threads)


def off_main_thread(threads: int, fn: Callable[..., T], /, *args, **kwargs) -> T:
    """``fn(*args, **kwargs)`` run on ``threads`` torch threads in a thread that ends when it
    returns; its result, or its exception raised here."""
    result: list[T] = []
    error: list[BaseException] = []

    def run() -> None:
        try:
            torch.set_num_threads(threads)
            result.append(fn(*args, **kwargs))
        except BaseException as exc:  # raised in the caller's thread below
            error.append(exc)

    thread = threading.Thread(target=run, name="panogrf-prepare", daemon=True)
    thread.start()
    thread.join()
    if error:
        raise error[0]
    return result[0]
