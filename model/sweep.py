"""The photometric sweep: each pixel's depth moved to the nearby candidate whose warp from the
sources matches best, and the fusion of depth hypotheses there.

After the MVS networks (`panogrf.model.depth`): the cost volume works at a quarter of 128 rows,
the sweep at `SweepConfig.height` rows puts back the detail a real capture has. Every candidate
of a reference view is scored by the same photometric error as the refinement
(`panogrf.model.ssim.photometric_error`, the minimum over the sources, summed over a window);
the depth moves where a candidate is clearly better. With several hypotheses (mono-guided and
unguided MVS) each pixel starts from the one its sources agree with (`photometric_choice`), or
from a learned `Chooser`'s choice (`panogrf.model.select`). `median_filter` then takes out the
sweep's speckle. Pure torch, ERP throughout.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import torch
import torch.nn.functional as F
from torch import Tensor

from panogrf.model.depth_warp import warp_along, warp_rays
from panogrf.model.erp import erp_directions, pad_seam
from panogrf.model.progress import open_stage
from panogrf.model.ssim import _pad_w, box_mean, photometric_error, reference_stats


@dataclass(frozen=True)
class SweepConfig:
    """The per-pixel photometric sweep around the networks' depth.

    Chosen on 12 validation scenes of the train split (8 home, 4 classic; MVS-only depth, mean
    L1 in metres): no sweep 0.2295, these defaults 0.1940, window 5: 0.1937, window 9: 0.1946,
    a second pass (span 0.15, 12 candidates) 0.1982, span 0.7 with 32 candidates 0.2038.
    """

    height: int = 256
    """Rows of the photometric comparison."""
    candidates: int = 24
    """Depths tried per pixel, log-spaced around the network's depth."""
    span: float = 0.5
    """Half-width of the searched range in log depth (0.5: 0.61x to 1.65x)."""
    window: int = 7
    """Side of the box over which the per-pixel error is summed."""
    prior: float = 0.02
    """Cost per unit of |log(d / d_net)|: where the error is flat, the network's depth wins."""
    min_gain: float = 0.02
    """A pixel moves only if its best cost is this much below the cost at the network's depth."""


class Chooser(Protocol):
    """Picks each pixel's hypothesis in `sweep_depth`."""

    def __call__(
        self, r: int, cost: Tensor, log_hyp: Tensor, ends: Tensor, offsets: Tensor
    ) -> Tensor | None:
        """(view r, cost curves [K, D, H, W], the hypotheses' log depth [K, H, W], where the
        search from each ends [K, H, W], the offsets [D]) -> index [H, W] (long) of the
        hypothesis each pixel keeps; None: decided in `finish`, once every view's search
        ends are known."""

    def finish(
        self, ends: dict[int, Tensor], c2w: Tensor, sources: list[list[int]]
    ) -> dict[int, Tensor]:
        """The indices of the views left undecided, given the search ends [K, H, W] of every
        view that has sources."""


def median_filter(depth: Tensor, window: int) -> Tensor:
    """Depth [V, 1, h, w] through a window x window median (ERP: wrapping at the seam, rows
    repeated at the poles). The sweep picks each pixel's depth on its own; where the sources'
    match is ambiguous (around thin objects, on repeated texture) single pixels jump to another
    candidate, and the median takes that speckle out while keeping depth steps where they are."""
    if window <= 1:
        return depth
    p = window // 2
    _, _, h, w = depth.shape
    out = [  # a view at a time: the patches take window^2 times the depth's memory
        F.unfold(_pad_w(d[None], p), window).median(1).values.reshape(1, h, w) for d in depth
    ]
    return torch.stack(out)


def sweep_depth(
    images: Tensor,  # [V, 3, H', W'] in [0, 1]
    c2w: Tensor,  # [V, 4, 4]
    depth: Tensor,  # [V, 1, h, w] metres
    sources: list[list[int]],
    config: SweepConfig = SweepConfig(),
    d_range: tuple[float, float] = (0.1, 10.0),
    others: tuple[Tensor, ...] = (),
    switch_gain: float = 0.0,
    chooser: Chooser | None = None,
) -> Tensor:
    """Depth [V, 1, h, w] moved, pixel by pixel, to the candidate around it whose warp from the
    sources matches best, where clearly better than at the network's depth (module docstring).
    ``others``: further hypotheses [V, 1, h, w]; each pixel starts from the one whose own depth
    matches best (``depth`` unless another is better by ``switch_gain``) or that ``chooser``
    picks (`Chooser`: given every hypothesis' costs and search ends, now or in its ``finish``,
    which sees every view's ends), and the search runs around it.
    """
    v = depth.shape[0]
    hh, ww = config.height, 2 * config.height
    mode = "area" if images.shape[-2] > hh else "bilinear"
    img = F.interpolate(images, size=(hh, ww), mode=mode)
    dirs = erp_directions(hh, ww, device=depth.device, dtype=depth.dtype)
    hyps = (depth, *others)
    logs = [torch.log(d.clamp(*d_range)) for d in hyps]
    log_hyp = torch.stack([F.interpolate(x, size=(hh, ww), mode="bilinear")[:, 0] for x in logs])
    offsets = torch.linspace(
        -config.span, config.span, config.candidates, dtype=depth.dtype, device=depth.device
    )
    out = depth.clone()

    def move(r: int, ends: Tensor, start: Tensor) -> None:
        out[r] = _moved(depth[r], log_hyp[0, r], ends.gather(0, start[None])[0], d_range)

    pending: dict[int, Tensor] = {}  # search ends of the views the chooser decides at the end
    # Progress: a unit per view and hypothesis (each a sweep of its candidates).
    progress = open_stage("depth: photometric sweep", len(hyps) * sum(map(bool, sources)))
    for r in range(v):
        if not sources[r]:
            continue
        cost, ends = _view_search(img, c2w, r, sources[r], log_hyp[:, r], offsets, dirs, config,
                                  d_range, progress.advance)  # fmt: skip
        start: Tensor | None
        if chooser is None:
            start = photometric_choice(cost, offsets, switch_gain)
        else:
            start = chooser(r, cost, log_hyp[:, r], ends, offsets)
        if start is None:
            pending[r] = ends
        else:
            move(r, ends, start)
    if pending:
        assert chooser is not None  # only a chooser leaves views pending
        for r, start in chooser.finish(pending, c2w, sources).items():
            move(r, pending[r], start)
    progress.close()
    return out


def _moved(depth: Tensor, log_first: Tensor, end: Tensor, d_range: tuple[float, float]) -> Tensor:
    """One view's depth [1, h, w] moved by where its search ended (log depth [H, W]) against
    its first hypothesis ``log_first``, the change averaged down to the depth's grid: pixels
    that keep the first hypothesis and do not move stay exactly as given."""
    change = end - log_first
    small = F.interpolate(change[None, None], size=depth.shape[-2:], mode="area")[0]
    return (depth * torch.exp(small)).clamp(*d_range)


def _view_search(
    img: Tensor,
    c2w: Tensor,
    r: int,
    sources: list[int],
    log_hyp: Tensor,
    offsets: Tensor,
    dirs: Tensor,
    config: SweepConfig,
    d_range: tuple[float, float],
    advance: Callable[[], object],
) -> tuple[Tensor, Tensor]:
    """View r's cost curves [K, D, H, W], one per hypothesis of ``log_hyp`` [K, H, W], and where
    the search from each ends (log depth) [K, H, W]; ``advance()`` after each hypothesis."""
    centre = int(torch.argmin(offsets.abs()))
    step = float(offsets[1] - offsets[0]) if len(offsets) > 1 else 0.0
    costs = []
    for k in range(len(log_hyp)):
        costs.append(_sweep_costs(img, c2w, r, sources, log_hyp[k], offsets, dirs, config, d_range))
        advance()
    cost = torch.stack(costs)
    ends = log_hyp + torch.stack([_search(c, offsets, centre, step, config) for c in cost])
    return cost, ends


def photometric_choice(cost: Tensor, offsets: Tensor, switch_gain: float = 0.0) -> Tensor:
    """The hypothesis [H, W] each pixel starts from by the sweep's own rule: the one whose cost
    at its own depth is lowest (cost curves [K, D, H, W]), the first keeping it within
    ``switch_gain`` and on exact ties (no texture)."""
    at_centre = cost[:, int(torch.argmin(offsets.abs()))].clone()
    at_centre[1:] += switch_gain + 1e-4
    return at_centre.argmin(0)


def _search(cost: Tensor, offsets: Tensor, centre: int, step: float, config: SweepConfig) -> Tensor:
    """The log-depth move [H, W] the search makes on one hypothesis' cost curve [D, H, W]: to the
    best candidate (refined by a parabola through it and its neighbours) where that is better
    than the hypothesis itself by more than ``config.min_gain``, else none."""
    best = cost.argmin(0)
    gain = cost[centre] - cost.gather(0, best[None])[0]
    lo, hi = (best - 1).clamp(min=0), (best + 1).clamp(max=len(offsets) - 1)
    c0, c1, c2 = (cost.gather(0, i[None])[0] for i in (lo, best, hi))
    denom = c0 - 2 * c1 + c2
    frac = torch.where(denom > 1e-6, 0.5 * (c0 - c2) / denom, torch.zeros_like(denom))
    frac = torch.where((best > 0) & (best < len(offsets) - 1), frac.clamp(-0.5, 0.5), 0 * frac)
    off = offsets[best] + frac * step
    return torch.where(gain > config.min_gain, off, torch.zeros_like(off))


def cost_at(
    img: Tensor,
    c2w: Tensor,
    r: int,
    sources: list[int],
    log_depth: Tensor,
    dirs: Tensor,
    config: SweepConfig,
    d_range: tuple[float, float],
) -> Tensor:
    """The sweep's photometric cost [H, W] of view r at the log depth [H, W] itself (images,
    directions and ``config`` as `sweep_depth` passes them to its search)."""
    zero = torch.zeros(1, dtype=log_depth.dtype, device=log_depth.device)
    return _sweep_costs(img, c2w, r, sources, log_depth, zero, dirs, config, d_range)[0]


def _sweep_costs(
    img: Tensor,
    c2w: Tensor,
    r: int,
    sources: list[int],
    log_d0: Tensor,
    offsets: Tensor,
    dirs: Tensor,
    config: SweepConfig,
    d_range: tuple[float, float],
    batched: bool | None = None,
) -> Tensor:
    """Window-summed photometric cost [D, H, W] of view r at log depths log_d0 + offsets.

    On a CPU one candidate at a time: batched over the candidates it is 1.6 times slower on a
    2-core CPU (24 candidates of 256 x 512 do not stay in cache). Elsewhere (`GPU_BATCH`) all
    candidates at once: the same arithmetic in a twenty-fourth of the launches. ``batched``
    decides instead where given."""
    # What does not change from one candidate to the next: the reference's windows, each
    # source padded for sampling and the reference's rays in its frame.
    ref = img[r : r + 1]
    stats = reference_stats(ref)
    along = [
        (pad_seam(img[s : s + 1]), *warp_rays(c2w[r][None], c2w[s][None], dirs)) for s in sources
    ]
    if batched is None:
        batched = GPU_BATCH and log_d0.device.type != "cpu"
    if batched:
        return _batched_costs(ref, stats, along, log_d0, offsets, config, d_range)
    costs = []
    for off in offsets.tolist():
        d = torch.exp(log_d0 + off).clamp(*d_range)[None]
        errs = [
            photometric_error(warp_along(padded, d, rays, shift), ref, stats)
            for padded, rays, shift in along
        ]
        err = torch.stack(errs).amin(0)  # [1, H, W]
        costs.append(box_mean(err[None], config.window)[0, 0] + config.prior * abs(off))
    return torch.stack(costs)


#: Score all of a sweep's candidates at once on a GPU (False: one at a time, as on a CPU; the
#: baseline of `benchmarks/gpu.py`).
GPU_BATCH = True


def _batched_costs(
    ref: Tensor,
    stats: tuple[Tensor, Tensor],
    along: list[tuple[Tensor, Tensor, Tensor]],
    log_d0: Tensor,
    offsets: Tensor,
    config: SweepConfig,
    d_range: tuple[float, float],
) -> Tensor:
    """`_sweep_costs` with every candidate in one batch: [D, H, W]."""
    n = len(offsets)
    d = torch.exp(log_d0[None] + offsets[:, None, None]).clamp(*d_range)  # [D, H, W]
    errs = [
        photometric_error(warp_along(padded.expand(n, -1, -1, -1), d, rays, shift), ref, stats)
        for padded, rays, shift in along
    ]  # each [D, H, W]
    err = torch.stack(errs).amin(0)
    prior = config.prior * offsets.abs()
    return box_mean(err[:, None], config.window)[:, 0] + prior[:, None, None]
