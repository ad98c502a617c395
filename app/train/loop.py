"""What the training loops share (`panogrf.app.train.depth`, `panogrf.app.train.renderer`).

- `lr_at`: the cosine schedule, from ``lr`` down to 1 % of it;
- `held_back`: the last scenes of the train split, kept for validation;
- `init_from`: start from earlier weights of the same network (parts added since may be new);
- `Steps`: the optimiser steps with their schedule, the running mean of the loss terms and a
  log line every ``log_every`` steps;
- `save_weights`: safetensors, written atomically, with JSON metadata.
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict
from pathlib import Path

import torch
from torch import Tensor

from panogrf.app.files.atomic import save_tensors_atomic


def lr_at(step: int, steps: int, lr: float) -> float:
    """Cosine decay from ``lr`` at step 0 to 1 % of it at ``steps``."""
    return lr * (0.01 + 0.99 * 0.5 * (1 + math.cos(math.pi * step / steps)))


def held_back(n: int, val_scenes: int) -> tuple[Tensor, Tensor]:
    """(train, validation) scene indices: the last ``val_scenes`` (at most a fifth, at least
    one) are held back."""
    from panogrf.app.errors import UserError

    k = min(val_scenes, max(1, n // 5))
    if n - k < 1:
        raise UserError(
            f"--data: {n} scene(s), and {k} held back for validation leaves none to train on; "
            "give more scenes"
        )
    return torch.arange(n - k), torch.arange(n - k, n)


def init_from(net: torch.nn.Module, path: Path | None, log, new: tuple[str, ...] = ()) -> None:
    """Load starting weights into ``net`` when a path is given: the same network, except that
    parameters whose names start with one of ``new`` may be absent (they keep their
    initialisation: parts added to a trained network)."""
    if path is None:
        return
    from panogrf.app.errors import UserError

    state = read_weights_file(path, "--init")
    try:
        missing, unexpected = net.load_state_dict(state, strict=False)
    except RuntimeError as exc:  # a tensor of another shape: another preset's weights
        first = str(exc).strip().splitlines()[-1].strip()
        raise UserError(f"--init {path}: does not fit the network ({first})") from None
    wrong = [k for k in missing if not k.startswith(new)] + list(unexpected)
    if wrong:
        raise UserError(f"--init {path}: does not fit the network: {wrong[:6]}")
    log(f"initialised from {path}" + (f" ({len(missing)} new tensors)" if missing else ""))


def read_weights_file(path: Path, option: str) -> dict[str, torch.Tensor]:
    """The tensors of the weights file ``path`` (checked as `read_weights` does: a `UserError`
    naming ``option`` and the file for a folder, another format, a truncated file)."""
    from panogrf.app.errors import UserError
    from panogrf.app.weights.networks import read_weights

    try:
        return read_weights(Path(path))
    except UserError as exc:
        raise UserError(f"{option} {exc}") from None


class Steps:
    """The optimiser steps of one run::

        steps = Steps(opt, cfg.steps, cfg.lr, cfg.log_every, log)
        for step in steps:                # sets the step's learning rate
            loss = ...
            steps.update(loss, terms)     # backward, optional clipping, optimiser step

    ``terms`` (a float or a 1-D tensor, default the loss) are averaged between log lines and
    written by ``describe(mean)``."""

    def __init__(
        self,
        opt: torch.optim.Optimizer,
        total: int,
        lr: float,
        log_every: int,
        log: Callable[[str], None],
        describe: Callable[[Tensor], str] = lambda m: f"loss {float(m):.4f}",
        clip: tuple[torch.nn.Parameter, ...] | None = None,
    ) -> None:
        self.opt, self.total, self.lr = opt, total, lr
        self.log_every, self.log, self.describe = log_every, log, describe
        self.clip = clip
        self.start = time.perf_counter()
        self.step = 0
        self._running: Tensor | None = None
        self._count = 0

    @property
    def seconds(self) -> float:
        return round(time.perf_counter() - self.start, 1)

    def __iter__(self) -> Iterator[int]:
        for step in range(1, self.total + 1):
            self.step = step
            for group in self.opt.param_groups:
                group["lr"] = lr_at(step, self.total, self.lr)
            yield step

    def update(self, loss: Tensor, terms: Tensor | float | None = None) -> None:
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        if self.clip is not None:
            torch.nn.utils.clip_grad_norm_(self.clip, 1.0)
        self.opt.step()
        value = torch.as_tensor(loss.item() if terms is None else terms, dtype=torch.float64)
        value = value.detach().double()
        self._running = value if self._running is None else self._running + value
        self._count += 1
        if self.step % self.log_every == 0 or self.step == self.total:
            mean = self._running / self._count
            self.log(
                f"step {self.step:5d}  {self.describe(mean)}  "
                f"lr {self.opt.param_groups[0]['lr']:.2e}  "
                f"{time.perf_counter() - self.start:7.1f} s"
            )
            self._running, self._count = None, 0


def save_weights(module: torch.nn.Module, path: Path, metadata: dict) -> None:
    """Write a module's state dict as safetensors, atomically, with JSON metadata; frozen
    ImageNet trunks are left out (`panogrf.app.weights.networks.trunk_prefixes`: loading puts
    them back from the LPIPS asset)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    from panogrf.app.weights.networks import trunk_prefixes

    frozen = tuple(trunk_prefixes(module))  # the bundled LPIPS AlexNet's: not stored again
    state = {
        k: v.detach().contiguous().cpu()
        for k, v in module.state_dict().items()
        if not (frozen and k.startswith(frozen))
    }
    meta = {k: v if isinstance(v, str) else json.dumps(v) for k, v in metadata.items()}
    save_tensors_atomic(path, state, meta)


def save_trained(net: torch.nn.Module, cfg, figures: dict, **extra: str) -> None:
    """Write a trained network to ``cfg.out`` (`save_weights`) with what reproduces it: its
    class and config, the training config ``cfg`` (a dataclass), the command line, the final
    figures, and ``extra`` (e.g. the preset)."""
    save_weights(
        net,
        cfg.out,
        {
            "network": type(net).__name__,
            **extra,
            "config": asdict(net.config),
            "train": {k: str(v) for k, v in asdict(cfg).items()},
            "command": " ".join(["panogrf"] + sys.argv[1:]),
            "final": figures,
        },
    )
