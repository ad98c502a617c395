"""LPIPS (Zhang et al. 2018), AlexNet backbone, linear heads v0.1, in plain torch.

Built from a state dict only (``LPIPS.from_state_dict``); reading the bundled weights is the
app's job (`panogrf.app.weights.lpips.load_lpips`), since `model/` does no file I/O.

State-dict keys (torch layout, OIHW), as written by ``scripts/convert_lpips.py``:
    ``convs.{0..4}.weight`` / ``convs.{0..4}.bias``: AlexNet ``features`` convolutions,
    ``heads.{0..4}.weight`` [1, C, 1, 1]: the non-negative per-channel LPIPS weights.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import Tensor, nn
from torch.nn import functional as F

from panogrf.model.metrics import check_image_pair

# torchvision AlexNet ``features``: (in, out, kernel, stride, padding); a 3x3/2 max-pool
# follows the first two convolutions. LPIPS taps the ReLU after each convolution.
_ALEX_CONVS = (
    (3, 64, 11, 4, 2),
    (64, 192, 5, 1, 2),
    (192, 384, 3, 1, 1),
    (384, 256, 3, 1, 1),
    (256, 256, 3, 1, 1),
)
_POOL_AFTER = (0, 1)

# LPIPS "ScalingLayer": maps ImageNet-normalised statistics onto inputs in [-1, 1].
_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)

# Smallest side the backbone accepts: 11x11/4 conv then two 3x3/2 pools must leave >= 1 pixel.
MIN_SIZE = 31


def _normalize_channels(feat: Tensor, eps: float = 1e-10) -> Tensor:
    """Unit-length feature vector per pixel: [B, C, h, w] -> [B, C, h, w] (LPIPS's eps)."""
    return feat / (feat.pow(2).sum(dim=1, keepdim=True).sqrt() + eps)


class LPIPS(nn.Module):
    """AlexNet-LPIPS v0.1 distance between RGB images in [0, 1]; lower is more similar.

    ``forward(x, y)``: x, y [B, 3, H, W] -> [B], or [3, H, W] -> [] (a scalar tensor),
    with H, W >= ``MIN_SIZE``. Differentiable in the inputs (usable as a loss).
    """

    shift: Tensor  # buffers (`register_buffer`)
    scale: Tensor

    def __init__(self) -> None:
        super().__init__()
        self.convs = nn.ModuleList(
            nn.Conv2d(cin, cout, k, stride=s, padding=p) for cin, cout, k, s, p in _ALEX_CONVS
        )
        self.heads = nn.ModuleList(nn.Conv2d(cout, 1, 1, bias=False) for _, cout, *_ in _ALEX_CONVS)
        # Constants, not weights: kept out of the state dict.
        self.register_buffer("shift", torch.tensor(_SHIFT)[None, :, None, None], persistent=False)
        self.register_buffer("scale", torch.tensor(_SCALE)[None, :, None, None], persistent=False)

    @classmethod
    def from_state_dict(cls, state: Mapping[str, Tensor]) -> LPIPS:
        """A model in eval mode with float32 weights (half-precision files are upcast)."""
        net = cls()
        net.load_state_dict({k: v.float() for k, v in state.items()}, strict=True)
        return net.eval()

    def features(self, x: Tensor) -> list[Tensor]:
        """relu1..relu5 taps of LPIPS-scaled input [B, 3, H, W] -> 5 x [B, C_k, h_k, w_k]."""
        taps = []
        for i, conv in enumerate(self.convs):
            x = F.relu(conv(x))
            taps.append(x)
            if i in _POOL_AFTER:
                x = F.max_pool2d(x, kernel_size=3, stride=2)
        return taps

    def forward(self, x: Tensor, y: Tensor) -> Tensor:
        check_image_pair(x, y, "LPIPS")
        single = x.dim() == 3
        if single:
            x, y = x[None], y[None]
        if x.shape[1] != 3 or min(x.shape[-2:]) < MIN_SIZE:
            raise ValueError(
                f"LPIPS: expected RGB images [B, 3, H, W] with H, W >= {MIN_SIZE}, "
                f"got {tuple(x.shape)}"
            )
        # [0, 1] -> [-1, 1] (the range LPIPS was trained on), then its fixed shift/scale.
        fx = self.features(((2.0 * x - 1.0) - self.shift) / self.scale)
        fy = self.features(((2.0 * y - 1.0) - self.shift) / self.scale)
        dist = x.new_zeros(x.shape[0])
        for head, a, b in zip(self.heads, fx, fy, strict=True):
            diff = (_normalize_channels(a) - _normalize_channels(b)).pow(2)
            dist = dist + head(diff).mean(dim=(1, 2, 3))  # [B, 1, h, w] -> [B]
        return dist[0] if single else dist
