"""The render worker never dies silently: its exception is kept for the window and printed."""

from __future__ import annotations

import time

import numpy as np
from helpers.nets import random_cache

from panogrf.app.viewer.worker import RenderWorker
from panogrf.renderer.cache import SceneCache


def test_a_failing_render_is_reported_not_swallowed(capfd):
    net, good = random_cache()
    c2w = good.c2w
    # Maps of other weights (fewer feature channels): the render cannot use them.
    bad = SceneCache(good.images, c2w, good.depth, good.maps[:, 3:], good.feature_channels)
    worker = RenderWorker(net, bad, levels=((8, "fast"),)).start()
    try:
        worker.request(np.eye(4))
        end = time.time() + 30
        while worker.error is None and time.time() < end:
            worker.wait_for_result(0.05)
        assert worker.error is not None and "out of bounds" in worker.error
    finally:
        worker.stop()
    err = capfd.readouterr().err
    assert f"panogrf view: refinement stopped: {worker.error}" in err
    assert "Traceback" not in err
