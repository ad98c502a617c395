"""Load the bundled AlexNet-LPIPS weights (`assets/lpips_alex.safetensors`) into `LPIPS`.

File I/O lives here rather than in `model/`, which only builds modules from state dicts.
"""

from __future__ import annotations

from functools import cache

import torch
from safetensors.torch import load_file

from panogrf import assets
from panogrf.model.lpips import LPIPS

ASSET_NAME = "lpips_alex.safetensors"


@cache
def _load_cached(device: str) -> LPIPS:
    path = assets.path(ASSET_NAME)
    if not path.is_file():
        raise FileNotFoundError(
            f"LPIPS weights not found at {path}; regenerate them with scripts/convert_lpips.py "
            "(its docstring has the command) or reinstall panogrf"
        )
    net = LPIPS.from_state_dict(load_file(str(path)))
    # A frozen metric: no weight gradients, but gradients still flow to the inputs.
    net.requires_grad_(False)
    return net.to(device)


def load_lpips(device: torch.device | str = "cpu") -> LPIPS:
    """The pretrained AlexNet-LPIPS v0.1 model on `device`, in eval mode, cached per process.

    The same instance is returned for the same device; do not modify it. Raises
    FileNotFoundError (with how to fix it) when the asset is missing.
    """
    return _load_cached(str(torch.device(device)))
