"""Renders of a prepared scene replayed from a CUDA graph.

On a GPU a `fast` render is a few hundred small operations whose launches from Python take
longer than their arithmetic (`benchmarks/gpu.py`). The viewer and a camera path render one
scene at one size again and again from new poses: the second such render on a CUDA device is
captured into a CUDA graph (`torch.cuda.CUDAGraph`) and every later one replays it, the pose
copied into the graph's input first. The graph runs the eager render's operations (the parts
that would wait for the device are made not to while capturing: `fill_holes` does all its
passes; the sample range is computed outside the graph each time and read from a tensor); its
outputs are copied out. One graph is kept (its memory is that of one eager render; it holds
its scene until a render of another replaces it); a capture that fails falls back to the eager
render for good.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import torch
from torch import Tensor

from panogrf.model.render_net import RendererNet
from panogrf.model.steps import CAPTURE_LOCK
from panogrf.renderer.cache import SceneCache
from panogrf.renderer.render import QUALITY, Quality, RenderOutput, sample_range

#: Replay renders from CUDA graphs (False: every render launched operation by operation).
ENABLED = True
#: Qualities whose renders are replayed: one pass of the network, no importance sampling.
GRAPHED = (Quality.FAST, Quality.DRAFT)


@dataclass
class _Graph:
    key: tuple[Any, ...]
    net: RendererNet  # held so that the key's ids stay theirs
    cache: SceneCache
    graph: torch.cuda.CUDAGraph | None
    pose: Tensor  # [4, 4] the graph's input
    span: Tensor  # [2] float64: near and far of the uniform samples
    out: RenderOutput | None
    failed: bool = False


_current: _Graph | None = None


def _captures(device: torch.device) -> bool:
    """Whether renders on ``device`` are captured (CUDA graphs exist on CUDA devices only)."""
    return device.type == "cuda"


#: What is replayed: `panogrf.renderer.detail`'s render (net, cache, pose, rows, sampling,
#: detail settings).
Render = Callable[[RendererNet, SceneCache, Tensor, int, Any, Any], "RenderOutput | None"]


def replayed(
    render: Render,
    net: RendererNet,
    cache: SceneCache,
    c2w: Tensor,
    height: int,
    quality: object,
    config: object,
) -> RenderOutput | None:
    """``render(net, cache, c2w, height, sampling, config)`` from a CUDA graph when this render
    was asked for just before with the same scene, size and settings; None when it is not
    replayed (not on CUDA, another quality, the first such render, a failed capture): the
    caller renders eagerly."""
    global _current
    if not (ENABLED and _captures(cache.images.device) and isinstance(quality, str)):
        return None
    if quality not in GRAPHED:
        return None
    with CAPTURE_LOCK:  # the one graph is shared by threads; nothing else captures meanwhile
        key = (id(net), id(cache), height, quality, config, c2w.dtype)
        entry = _current
        if entry is None or entry.key != key:
            span = c2w.new_zeros(2, dtype=torch.float64)
            _current = _Graph(key, net, cache, None, c2w.clone(), span, None)
            return None  # the first render runs eagerly: it makes what the scene memoises
        if entry.failed:
            return None  # its capture failed
        pose = c2w.to(cache.images.dtype)
        entry.span.copy_(torch.tensor(sample_range(cache, pose[:3, 3]), dtype=torch.float64))
        entry.pose.copy_(c2w)
        if entry.graph is None:
            sampling = replace(QUALITY[Quality(quality)], near=entry.span[0], far=entry.span[1])
            try:
                entry.graph = torch.cuda.CUDAGraph()
                with torch.cuda.graph(entry.graph, capture_error_mode="thread_local"):
                    entry.out = render(net, cache, entry.pose, height, sampling, config)
            except RuntimeError:
                entry.graph, entry.failed = None, True
                return None
        entry.graph.replay()
        assert entry.out is not None  # captured with the graph
        out = entry.out
        return RenderOutput(out.rgb.clone(), out.depth.clone(), out.opacity.clone())
