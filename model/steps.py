"""Optimisation steps, on a GPU replayed from one CUDA graph.

A per-scene optimisation step (the depth refinement's) is a few hundred small tensor
operations; on a GPU their launches from Python, not their arithmetic, take the time. Captured
once into a CUDA graph (`torch.cuda.CUDAGraph`) and replayed, a step is one launch.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable
from typing import Any, Protocol

import torch
from torch import Tensor

#: Held while a CUDA graph is captured, and by GPU work of another thread that must not run
#: meanwhile. The viewer renders (and captures its renders, `panogrf.renderer.graphs`) while
#: the scene's refinement captures its steps in another thread; `torch.cuda.graph` synchronises
#: the device and empties the allocator's cache as it starts, which breaks a capture under way
#: in another thread: on an H200 `tests/renderer/test_graphs.py`'s threaded test failed so
#: ("operation not permitted when stream is capturing") in 2 runs of 5 without this lock.
CAPTURE_LOCK = threading.RLock()


def apart_from_captures(on: Tensor) -> contextlib.AbstractContextManager[object]:
    """`CAPTURE_LOCK` for GPU work on ``on``'s device (a CUDA one), nothing on a CPU."""
    return CAPTURE_LOCK if on.is_cuda else contextlib.nullcontext()


class Optimiser(Protocol):
    """What the steps need of an optimiser (`torch.optim.Adam` and `PlainAdam` have it)."""

    param_groups: list[dict[str, Any]]

    def zero_grad(self, set_to_none: bool = True) -> None: ...

    def step(self) -> Any: ...


class PlainAdam:
    """`torch.optim.Adam`'s update (no weight decay, amsgrad or maximize) for tensors on a CPU,
    the same arithmetic in the same order (torch's single-tensor path): making a torch
    optimiser first imports torch._dynamo, about 1.2 s of a 2-core CPU once in a process."""

    def __init__(
        self,
        params: list[Tensor],
        lr: float,
        betas: tuple[float, float] = (0.9, 0.999),
        eps: float = 1e-8,
    ) -> None:
        self.params = params
        self.param_groups: list[dict[str, Any]] = [{"lr": lr}]
        self.betas, self.eps, self.steps = betas, eps, 0.0
        zeros = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in params]
        self.moments = [(z, z.clone()) for z in zeros]

    def zero_grad(self, set_to_none: bool = True) -> None:
        for p in self.params:
            p.grad = None

    @torch.no_grad()
    def step(self) -> None:
        self.steps += 1.0
        lr, (beta1, beta2) = self.param_groups[0]["lr"], self.betas
        for p, (avg, avg_sq) in zip(self.params, self.moments, strict=True):
            if p.grad is None:
                continue
            avg.lerp_(p.grad, 1 - beta1)
            avg_sq.mul_(beta2).addcmul_(p.grad, p.grad, value=1 - beta2)
            step_size = lr / (1 - beta1**self.steps)
            denom = (avg_sq.sqrt() / (1 - beta2**self.steps) ** 0.5).add_(self.eps)
            p.addcdiv_(avg, denom, value=-step_size)


def adam(params: list[Tensor], lr: float, eps: float = 1e-8) -> Optimiser:
    """Adam for ``params``: on a CUDA device torch's, capturable, its rate a tensor (CUDA
    graphs read it); elsewhere `PlainAdam`."""
    if params[0].device.type != "cuda":
        return PlainAdam(params, lr, eps=eps)
    rate = torch.tensor(lr, device=params[0].device)
    return torch.optim.Adam(params, lr=rate, eps=eps, capturable=True)


class OptimisationSteps:
    """``steps`` optimisation steps of ``step`` (forward, backward and the optimiser's update;
    gradients are set to None before each). With ``graph`` (CUDA): the first `WARM_UP` steps
    run on a side stream (the optimiser's state is made, the kernels chosen), the next one is
    captured into a CUDA graph, and the graph is replayed for it and the rest: the same
    arithmetic, one launch per step."""

    WARM_UP = 1

    def __init__(
        self,
        step: Callable[[], None],
        opt: Optimiser,
        graph: bool,
    ) -> None:
        self.step, self.opt, self.graph = step, opt, graph

    def run(
        self, steps: int, should_stop: Callable[[], bool] | None, advance: Callable[[], None]
    ) -> bool:
        """False when ``should_stop`` said so before a step."""
        warm = min(steps, self.WARM_UP) if self.graph else steps
        stream = torch.cuda.Stream() if self.graph else None
        if stream is not None:
            stream.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(stream) if stream is not None else contextlib.nullcontext():
            for _ in range(warm):
                if should_stop is not None and should_stop():
                    return False
                self.opt.zero_grad(set_to_none=True)
                self.step()
                advance()
        if stream is not None:
            torch.cuda.current_stream().wait_stream(stream)
        if stream is None or warm == steps:
            return True
        graph = torch.cuda.CUDAGraph()
        self.opt.zero_grad(set_to_none=True)
        with CAPTURE_LOCK, torch.cuda.graph(graph, capture_error_mode="thread_local"):
            self.step()  # captured, not run: the gradients it makes stay in the graph's pool
        for _ in range(warm, steps):
            if should_stop is not None and should_stop():
                return False
            graph.replay()
            advance()
        return True
