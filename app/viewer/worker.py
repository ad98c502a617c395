"""The render worker: owns the neural renderer and refines the view while the camera is still.

The window never calls the model. It posts the current pose with `request`; the worker renders
it at each level of a resolution ladder (low first), publishing every finished level. A newer
request (the camera moved) interrupts the render in progress at the next chunk of rays, so a
stale pose is never finished. `latest` hands the newest finished frame to the window.
"""

from __future__ import annotations

import sys
import threading
import time
from dataclasses import dataclass, replace

import numpy as np
import torch

from panogrf.app.files.images import to_uint8
from panogrf.model.render_net import RendererNet
from panogrf.model.steps import apart_from_captures
from panogrf.renderer.cache import RENDER_SOURCES, SceneCache
from panogrf.renderer.detail import DEFAULT_DETAIL, render_detailed
from panogrf.renderer.render import Quality, render_panorama

#: (height, sampling, sources, network rows, detail sampling) of each refinement level, coarse
#: to fine; both are shown at 512 x 1024, the network running at the fourth entry's rows and
#: the sources giving the colour above `DEFAULT_DETAIL.cutoff` rows (`renderer/detail.py`): a quick
#: draft from the two sources nearest the camera (what the renderer was trained with; the GL
#: preview draws the same two), then the fast sampling from `RENDER_SOURCES`, both with the
#: network at 128 rows. Chosen on 12 validation scenes at 512 rows (`python
#: benchmarks/detail.py --ladder ...`, 2 sources, detail above 32 rows, WS-PSNR / LPIPS /
#: median s): draft at 128 25.61 / 0.152 / 0.22; fast at 128 26.52 / 0.121 / 0.46, at 192
#: 26.59 / 0.124 / 0.98, at 256 26.61 / 0.126 / 1.50 (detail_cutoff_val.json): the network
#: above 128 rows costs twice as much for under 0.1 dB. The draft reads the sources' detail
#: bilinearly, the fast level bicubically (`DetailConfig.sampling`; validation, draft 25.61 /
#: 0.152 bilinear, 25.68 / 0.141 bicubic): bicubic reads cost about 50-80 ms more per 512-row
#: frame here, which the first frame (target 0.5 s) cannot spare and the last can. Both
#: read the sources at their own depth splatted into the target (`DEFAULT_DETAIL`'s
#: projection; detail_projection_val.json): draft 25.61 / 0.143 / 0.15 -> 26.43 / 0.109 / 0.17,
#: fast at 128 26.66 / 0.103 / 0.31 -> 26.87 / 0.094 / 0.32.
LEVELS = (
    (512, Quality.DRAFT, 2, 128, "bilinear"),
    (512, Quality.FAST, RENDER_SOURCES, 128, "bicubic"),
)
#: The live view's one level (`RenderWorker` ``live``): the last level of `LEVELS`, every frame.
LIVE_LEVELS = LEVELS[-1:]


@dataclass
class Refined:
    """A finished refinement: RGB uint8 [H, 2H, 3] of pose ``c2w`` at ladder level ``level``."""

    rgb: np.ndarray
    c2w: np.ndarray
    level: int
    generation: int
    seconds: float  # from the request to this level being done


class RenderWorker:
    """Progressive refinement in a background thread (start/stop explicitly).

    ``live`` (a GPU renders a frame in milliseconds): a render in progress is finished and
    published even when a newer pose was requested meanwhile, so a camera that moves every
    frame sees the newest finished frame, one render behind, instead of none."""

    def __init__(
        self,
        net: RendererNet,
        cache: SceneCache,
        levels: tuple[tuple, ...] = LEVELS,
        threads: int | None = None,
        live: bool = False,
    ) -> None:
        self.net, self.cache, self.live = net, cache, live
        self.levels = [
            (
                lv[0],
                lv[1],
                lv[2] if len(lv) > 2 else None,
                lv[3] if len(lv) > 3 else DEFAULT_DETAIL.net_height,
                lv[4] if len(lv) > 4 else DEFAULT_DETAIL.sampling,
            )
            for lv in levels
        ]
        self.threads = threads
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._published = threading.Condition(self._lock)
        self._generation = 0
        self._pose: np.ndarray | None = None
        self._requested_at = 0.0
        self._latest: Refined | None = None
        self._progress = 0.0
        self._level = -1
        self._stop = False
        self._error: str | None = None
        self._thread = threading.Thread(target=self._run, name="panogrf-render", daemon=True)

    def start(self) -> RenderWorker:
        self._thread.start()
        return self

    def stop(self) -> None:
        with self._wake:
            self._stop = True
            self._generation += 1
            self._wake.notify_all()
        self._thread.join(timeout=30)

    def request(self, c2w: np.ndarray) -> int:
        """Refine pose ``c2w`` [4, 4] (cancels any other); returns the request's generation."""
        with self._wake:
            self._generation += 1
            self._pose = np.array(c2w, np.float64)
            self._requested_at = time.perf_counter()
            self._progress, self._level = 0.0, -1
            self._wake.notify_all()
            return self._generation

    def replace_cache(self, cache: SceneCache) -> None:
        """Render from ``cache`` from now on (the scene's refined depth arrived); whatever was
        being refined from the old one is dropped."""
        with self._wake:
            self.cache = cache
            self._generation += 1
            self._pose = None
            self._progress, self._level = 0.0, -1
            self._latest = None

    def cancel(self) -> None:
        """The camera moves: drop whatever is being refined."""
        with self._wake:
            self._generation += 1
            self._pose = None
            self._progress, self._level = 0.0, -1

    def wait_for_result(self, timeout: float) -> None:
        """Sleep up to ``timeout`` seconds, waking as soon as a level is finished (the window
        shows it at once instead of at its next frame)."""
        if timeout > 0:
            with self._published:
                self._published.wait(timeout)

    def latest(self) -> Refined | None:
        with self._lock:
            return self._latest

    @property
    def status(self) -> tuple[int, float]:
        """(levels finished for the current request, progress of the one in flight in [0, 1])."""
        with self._lock:
            return self._level + 1, self._progress

    def _superseded(self, gen: int) -> bool:
        """Whether the render of request ``gen`` is dropped: any other request came (live: a
        cancel, a new scene or the end; a newer pose waits for it). Call under the lock or
        where a stale answer costs only one chunk more."""
        if self._generation == gen:
            return False
        return not self.live or self._stop or self._pose is None

    def _nearest(self, pose: np.ndarray, count: int | None) -> SceneCache:
        """The cache of the ``count`` sources nearest to ``pose`` (all: None), memoised."""
        with self._lock:  # `replace_cache` may swap it at any time
            cache = self.cache
        return cache.nearest(torch.from_numpy(pose), count)

    def _warm_up(self) -> None:
        """A small render of the first level before the first request: the first real one
        otherwise pays for growing the heap and first use of the kernels (a few tenths of a
        second here). 64 rows fill whole chunks of rays, as a real render does."""
        height, quality, sources, *_ = self.levels[0]
        with apart_from_captures(self.cache.images):  # as `_serve`'s
            pose = self.cache.c2w[0].double().cpu().numpy()
            render_panorama(
                self.net,
                self._nearest(pose, sources),
                self.cache.c2w[0],
                min(height, 64),
                quality,
                should_stop=lambda: self._stop or self._pose is not None,
            )

    @property
    def error(self) -> str | None:
        """Why refinement stopped for good (None while it works): the window shows it."""
        with self._lock:
            return self._error

    def _run(self) -> None:
        try:
            self._serve()
        except Exception as exc:  # shown on screen and in the terminal, never swallowed
            message = f"{type(exc).__name__}: {exc}"
            with self._lock:
                self._error = message
                self._published.notify_all()
            print(f"panogrf view: refinement stopped: {message}", file=sys.stderr, flush=True)

    def _serve(self) -> None:
        if self.threads:
            torch.set_num_threads(self.threads)
        self._warm_up()
        while True:
            with self._wake:
                while not self._stop and self._pose is None:
                    self._wake.wait()
                if self._stop:
                    return
                gen, pose, t0 = self._generation, self._pose, self._requested_at
                self._pose = None

            def stale(gen=gen) -> bool:
                return self._superseded(gen)

            def progress(f: float, gen=gen) -> None:
                with self._lock:
                    if self._generation == gen:
                        self._progress = f

            # On a GPU none of the worker's device work while the refinement captures its steps.
            with apart_from_captures(self.cache.images):
                tgt = torch.from_numpy(pose).to(self.cache.images)
            for level, (height, quality, sources, rows, reads) in enumerate(self.levels):
                # Above ``rows`` the network renders at ``rows`` and the sources add the detail.
                detail = replace(DEFAULT_DETAIL, net_height=rows, sampling=reads)
                with apart_from_captures(self.cache.images):
                    out = render_detailed(
                        self.net,
                        self._nearest(pose, sources),
                        tgt,
                        height,
                        quality,
                        detail,
                        progress=progress,
                        should_stop=stale,
                    )
                    rgb = None if out is None else to_uint8(out.rgb)
                if rgb is None or stale():
                    break
                done = Refined(rgb, pose, level, gen, time.perf_counter() - t0)
                with self._lock:
                    if self._superseded(gen):
                        break
                    self._latest = done
                    if self._generation == gen:
                        self._level, self._progress = level, 0.0
                    self._published.notify_all()
