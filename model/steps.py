"""Optimisation steps, on a GPU replayed from one CUDA graph.

A per-scene optimisation step (the depth refinement's) is a few hundred small tensor
operations; on a GPU their launches from Python, not their arithmetic, take the time. Captured
once into a CUDA graph (`torch.cuda.CUDAGraph`) and replayed, a step is one launch.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable

import torch


class OptimisationSteps:
    """``steps`` optimisation steps of ``step`` (forward, backward and the optimiser's update;
    gradients are set to None before each), the optimiser's learning rate set to ``rate(i)``
    before the i-th when given. With ``graph`` (CUDA): the first `WARM_UP` steps
    run on a side stream (the optimiser's state is made, the kernels chosen), the next one is
    captured into a CUDA graph, and the graph is replayed for it and the rest: the same
    arithmetic, one launch per step."""

    WARM_UP = 1

    def __init__(
        self,
        step: Callable[[], None],
        opt: torch.optim.Optimizer,
        graph: bool,
        rate: Callable[[int], float] | None = None,
    ) -> None:
        self.step, self.opt, self.graph, self.rate = step, opt, graph, rate

    def _set_rate(self, i: int) -> None:
        """The learning rate of the i-th step (``rate``; a graph reads it from its tensor)."""
        if self.rate is None:
            return
        for group in self.opt.param_groups:
            if isinstance(group["lr"], torch.Tensor):
                group["lr"].fill_(self.rate(i))
            else:
                group["lr"] = self.rate(i)

    def run(
        self, steps: int, should_stop: Callable[[], bool] | None, advance: Callable[[], None]
    ) -> bool:
        """False when ``should_stop`` said so before a step."""
        warm = min(steps, self.WARM_UP) if self.graph else steps
        stream = torch.cuda.Stream() if self.graph else None
        if stream is not None:
            stream.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(stream) if stream is not None else contextlib.nullcontext():
            for i in range(warm):
                if should_stop is not None and should_stop():
                    return False
                self._set_rate(i)
                self.opt.zero_grad(set_to_none=True)
                self.step()
                advance()
        if stream is not None:
            torch.cuda.current_stream().wait_stream(stream)
        if stream is None or warm == steps:
            return True
        graph = torch.cuda.CUDAGraph()
        self.opt.zero_grad(set_to_none=True)
        with torch.cuda.graph(graph):
            self.step()  # captured, not run: the gradients it makes stay in the graph's pool
        for i in range(warm, steps):
            if should_stop is not None and should_stop():
                return False
            self._set_rate(i)
            graph.replay()
            advance()
        return True
