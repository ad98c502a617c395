"""Per-scene depth refinement by photometric consistency between the posed source panoramas.

The networks' depth comes from a coarse cost volume (1/4 of 128 rows) and from synthetic
training; on a real capture the sources themselves say more: with known poses, a correct depth
makes every view's pixels reappear in the others. This optimises a smooth log-depth correction
per view (at the depth's own resolution) so that each reference view, warped from its sources
at ``height`` rows, matches them:

- photometric error: 0.85 (1 - SSIM) / 2 + 0.15 |a - b| over a 3x3 window, the minimum over the
  sources where there are several (a pixel occluded in one source is usually seen by another),
  and capped at ``cap`` (occlusions and reflections do not pull the depth around);
- an edge-aware smoothness of the correction (depth edges follow image edges);
- a prior that keeps the correction small where the photometric term says nothing (blank walls);
- optionally (``RefineConfig.free_space``) the views' depths checked against each other: a
  point one view puts in the world must not lie in front of the surface a source sees in its
  direction (`free_space_violation`).

Pure torch, ERP throughout (wrapping at the seam). Shapes: V views, H W the photometric
resolution, h w the depth's resolution.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor

from panogrf.model.depth_warp import warp_along, warp_rays
from panogrf.model.erp import (
    erp_directions,
    erp_to_world,
    latitude_weights,
    pad_seam,
    sample_erp,
    world_to_erp,
)
from panogrf.model.progress import open_stage
from panogrf.model.ssim import photometric_error, reference_stats
from panogrf.model.steps import OptimisationSteps, adam


@dataclass(frozen=True)
class RefineConfig:
    """The per-scene refinement."""

    iterations: int = 60
    """Adam steps."""
    lr: float = 0.02
    """Learning rate of the log-depth correction."""
    height: int = 256
    """Rows of the photometric comparison (the depth itself stays at its resolution)."""
    smooth: float = 0.05
    """Weight of the edge-aware smoothness of the correction."""
    prior: float = 0.01
    """Weight of |correction| (log units)."""
    cap: float = 0.4
    """Largest photometric error a pixel contributes."""
    coarse: int = 0
    """Adam steps compared at ``height // 2`` rows before the ``iterations`` at ``height`` (a
    quarter of the pixels each: the correction's large moves are made cheaply, the last steps
    see the detail)."""
    fine: int = 0
    """Adam steps compared at ``2 * height`` rows after the ``iterations`` (four times the
    pixels each; capped at the images' own rows): the detail of a 512-row capture."""
    free_space: float = 0.0
    """Weight of `free_space_violation` (log units): the views' depths must not contradict each
    other. Photometric error says little on blank walls and bright windows, where the views'
    depths can disagree; this term makes them agree. Where one view's photometry is sure, the
    other follows it; where neither's is, they meet between their depths. 0: off."""
    free_space_shrink: int = 1
    """The free-space term is computed at the stage's rows divided by this (its cost grows with
    the pixels; the corrections it makes are large and smooth)."""
    damping: float = 0.0
    """Adam's epsilon for the loss summed over the correction's pixels (the loss is their mean:
    epsilon = damping / pixels, the same at any resolution). Adam moves every pixel by about
    the rate, however small its gradient; a pixel whose gradient is well under the damping
    moves little instead, so where the photometry says almost nothing, rounding does not
    decide millimetre steps. 0: torch's 1e-8."""

    def __post_init__(self) -> None:
        if not self.damping >= 0.0:
            raise ValueError(f"damping must be >= 0, got {self.damping}")


#: The refinement of a scene's cached depth at preparation (`SourceViews.refine`; on by
#: default in view, render and eval, ``--no-refine-depth`` to skip it), after the networks, the
#: sweep and the median. Each setting was chosen on validation scenes by a rule set before the
#: runs (`benchmarks/refine_depth.py`; every figure in `lab/results.md`, "How the per-scene
#: refinement's settings were chosen"): smoothness 1.0, a coarse stage at half the rows, no
#: stage at twice the rows, the free-space term at weight 1.0 and half the rows, then
#: 30 + 30 steps, Adam damped by 3 (the largest of 3, 8, 25 within the rule; the depth 3x
#: less sensitive to rounding: 1.94 -> 0.65 mm; `lab/analysis.md`, "a refinement that rounding
#: does not steer"). A rate settling over the last half with 20 + 20 steps (0.58x the time)
#: shipped for a while: on 18 new validation scenes it lost 0.06 dB and 1.4 % depth L1 against
#: 30 + 30 without settling (26.90 / 0.1011 / 0.0772 against 26.96 / 0.1002 / 0.0761 m;
#: `lab/analysis.md`, "the refinement's schedule checked on new scenes"), past the rule that
#: had admitted it, and left.
PREPARE_REFINE = RefineConfig(
    smooth=1.0,
    coarse=30,
    iterations=30,
    free_space=1.0,
    free_space_shrink=2,
    damping=3.0,
)


#: Gap (log depth) below which a point in front of a source's surface is not a violation: the
#: depth maps' own sampling error.
FREE_SPACE_TOLERANCE = 0.02


def free_space_violation(
    log_depth: Tensor,  # [V, 1, h, w] log metres
    c2w: Tensor,  # [V, 4, 4]
    sources: list[list[int]],
    tolerance: float = FREE_SPACE_TOLERANCE,
) -> Tensor:
    """How far the views' points lie in front of the surfaces their sources see, in log depth.

    A surface seen by source s at distance d along a ray means the ray is empty up to d. A point
    that view r puts on that ray nearer than d contradicts s: one of the two depths is wrong
    (r's too near, or s's too far). A point beyond d is only hidden from s, which says nothing,
    so the penalty is one-sided and holds at occlusions too. Per pair (r, s): the
    latitude-weighted mean of max(0, log d_s - log |p_r - o_s| - ``tolerance``), with d_s read
    at the nearest pixel; the mean over the pairs. Differentiable in both depths."""
    pairs = _Pairs.of([(r, s) for r in range(len(sources)) for s in sources[r]], log_depth.device)
    if pairs.count == 0:
        return log_depth.new_zeros(())
    return _violation(log_depth, c2w.to(log_depth.dtype), pairs, tolerance)


@dataclass(frozen=True)
class _Pairs:
    """(reference, source) pairs as index tensors on the depth's device, made once: none is
    built inside an optimisation step (a CUDA graph cannot copy from the host)."""

    ref: Tensor  # [P] reference view of each pair
    src: Tensor  # [P] its source
    count: int

    @staticmethod
    def of(pairs: list[tuple[int, int]], device: torch.device) -> _Pairs:
        ref = torch.tensor([r for r, _ in pairs], dtype=torch.long, device=device)
        src = torch.tensor([s for _, s in pairs], dtype=torch.long, device=device)
        return _Pairs(ref, src, len(pairs))


def _violation(log_depth: Tensor, c2w: Tensor, pairs: _Pairs, tolerance: float) -> Tensor:
    """`free_space_violation` of the ``pairs`` (at least one)."""
    _, _, h, w = log_depth.shape
    points = erp_to_world(torch.exp(log_depth[:, 0]), c2w)  # [V, hw, 3]
    wlat = latitude_weights(h, w, device=log_depth.device, dtype=log_depth.dtype).reshape(-1)
    # Every pair at once: view r's points projected into its source s.
    uv, dist = world_to_erp(points[pairs.ref], c2w[pairs.src], h, w)  # [P, hw, 2]
    seen = sample_erp(log_depth[pairs.src], uv, "nearest")[:, 0]  # [P, hw]
    gap = (seen - torch.log(dist.clamp(min=0.05)) - tolerance).clamp(min=0)
    return ((gap * wlat).sum(1) / wlat.sum()).mean()


#: On a GPU, replay each stage's steps from a CUDA graph (`OptimisationSteps`); False launches
#: every operation from Python, the baseline of `benchmarks/gpu.py`.
CUDA_GRAPHS = True


def refine_depth(
    images: Tensor,  # [V, 3, H', W'] in [0, 1]
    c2w: Tensor,  # [V, 4, 4]
    depth: Tensor,  # [V, 1, h, w] metres
    sources: list[list[int]],
    config: RefineConfig = RefineConfig(),
    d_range: tuple[float, float] = (0.1, 10.0),
    should_stop: Callable[[], bool] | None = None,
) -> Tensor | None:
    """Refined depth [V, 1, h, w]; views without sources are returned unchanged. None when
    ``should_stop`` (asked before every step) says so: a viewer closed before the end.

    On a GPU each stage's steps replay one CUDA graph (`OptimisationSteps`): a step is a few hundred
    small operations whose launches, not their arithmetic, would otherwise take the time."""
    v, _, h, w = depth.shape
    refs = [r for r in range(v) if sources[r]]
    if not refs or config.iterations + config.coarse + config.fine <= 0:
        return depth
    log_d0 = torch.log(depth.clamp(*d_range)).detach()
    # Only views with sources move: the free-space term would otherwise also reach a view that
    # is only another's source.
    moves = torch.zeros(v, 1, 1, 1, dtype=depth.dtype, device=depth.device)
    moves[refs] = 1.0
    problem = _Problem(
        log_d0,
        torch.zeros_like(log_d0, requires_grad=True),
        moves,
        *_edge_weights(images, (h, w)),
        c2w.to(depth.dtype),
        _Pairs.of([(r, s) for r in refs for s in sources[r]], depth.device),
        _Pairs.of([(r, s) for r in range(v) for s in sources[r]], depth.device),
        _spans([len(sources[r]) for r in refs]),
        config,
    )
    eps = config.damping / problem.delta.numel() if config.damping > 0 else 1e-8
    opt = adam([problem.delta], config.lr, eps)
    # On a GPU the rate is a tensor the graphs read, and the launches do the same arithmetic.
    graphs = CUDA_GRAPHS and depth.device.type == "cuda"
    rows = (config.height // 2, config.height, min(2 * config.height, images.shape[-2]))
    stages = tuple(zip(rows, (config.coarse, config.iterations, config.fine), strict=True))
    # Progress: a unit per step (each a warp of every view's sources).
    total = sum(max(steps, 0) for _, steps in stages)
    progress, done = open_stage("depth refinement", total), 0
    for hh, steps in stages:
        if steps <= 0:
            continue
        stage = _stage(images, problem, hh)

        def step(stage: _Stage = stage) -> None:
            _loss(problem, stage).backward()
            opt.step()

        if not OptimisationSteps(step, opt, graphs).run(steps, should_stop, progress.advance):
            progress.close()
            return None
        done += steps
    progress.close()
    with torch.no_grad():
        return torch.exp(log_d0 + problem.delta * moves).clamp(*d_range)


class _Problem(NamedTuple):
    """What every step of a refinement reads: the depth and its correction, the weights of the
    smoothness, the poses, the warped pairs and the settings."""

    log_d0: Tensor  # [V, 1, h, w] the depth given, log metres
    delta: Tensor  # [V, 1, h, w] the correction (optimised)
    moves: Tensor  # [V, 1, 1, 1] 1 for the views with sources
    wx: Tensor  # the edge-aware smoothness' weights across columns and rows
    wy: Tensor
    c2w: Tensor  # [V, 4, 4]
    pairs: _Pairs  # (reference, source) of the views that move
    all_pairs: _Pairs  # every view's, for the free-space term
    spans: list[tuple[int, int]]  # each moving view's pairs in ``pairs``
    config: RefineConfig


class _Stage(NamedTuple):
    """What does not change during a stage (at ``rows`` rows): the sources padded and the
    references' rays in their frames (`warp_rays`), the latitude weights, the references and
    their window statistics."""

    rows: int
    along: tuple[Tensor, Tensor, Tensor]
    wlat: Tensor
    target: Tensor
    stats: tuple[Tensor, Tensor]


def _stage(images: Tensor, problem: _Problem, hh: int) -> _Stage:
    like, pairs = problem.log_d0, problem.pairs
    mode = "area" if images.shape[-2] > hh else "bilinear"
    img = F.interpolate(images, size=(hh, 2 * hh), mode=mode).detach()
    dirs = erp_directions(hh, 2 * hh, device=like.device, dtype=like.dtype)
    c2w = problem.c2w
    along = (pad_seam(img[pairs.src]), *warp_rays(c2w[pairs.ref], c2w[pairs.src], dirs))
    wlat = latitude_weights(hh, 2 * hh, device=like.device, dtype=like.dtype)
    target = img[pairs.ref]
    return _Stage(hh, along, wlat, target, reference_stats(target))


def _loss(p: _Problem, stage: _Stage) -> Tensor:
    """A step's loss: the photometric error of the warps at the stage's rows, the smoothness and
    the size of the correction, and the free-space term."""
    config, delta, hh = p.config, p.delta, stage.rows
    log_d = p.log_d0 + delta * p.moves
    log_full = F.interpolate(log_d, size=(hh, 2 * hh), mode="bilinear", align_corners=False)
    warped = warp_along(stage.along[0], torch.exp(log_full)[:, 0][p.pairs.ref], *stage.along[1:])
    errs = photometric_error(warped, stage.target, stage.stats)
    loss = _photometric_sum(errs, p.spans, stage.wlat, config)
    dx = (delta - torch.roll(delta, 1, -1)).abs() * p.wx
    dy = (delta[..., 1:, :] - delta[..., :-1, :]).abs() * p.wy
    loss = loss / len(p.spans) + config.smooth * (dx.mean() + dy.mean())
    loss = loss + config.prior * delta.abs().mean()
    if config.free_space > 0:
        fs = _free_space_at(log_d, log_full, hh, p.c2w, p.all_pairs, config)
        loss = loss + config.free_space * fs
    return loss


def _photometric_sum(
    errs: Tensor, spans: list[tuple[int, int]], wlat: Tensor, config: RefineConfig
) -> Tensor:
    """The latitude-weighted mean photometric error of every reference view, summed: each
    pixel's best source (``errs`` [P, H, W] per pair, ``spans`` each reference's pairs),
    capped at ``config.cap``."""
    loss = errs.new_zeros(())
    for lo, hi in spans:
        err = errs[lo:hi].amin(0).clamp(max=config.cap)
        loss = loss + (err * wlat).sum() / wlat.sum()
    return loss


def _free_space_at(
    log_d: Tensor,
    log_full: Tensor,
    hh: int,
    c2w: Tensor,
    pairs: _Pairs,
    config: RefineConfig,
) -> Tensor:
    """`free_space_violation` of the stage at ``hh`` rows, at ``config.free_space_shrink``
    times fewer rows (``log_full``: the depth at the stage's rows, ``log_d`` at its own)."""
    k = max(1, config.free_space_shrink)
    log_fs = log_full
    if k > 1:
        size = (max(hh // k, 4), 2 * max(hh // k, 4))
        log_fs = F.interpolate(log_d, size=size, mode="bilinear", align_corners=False)
    return _violation(log_fs, c2w, pairs, FREE_SPACE_TOLERANCE)


def _edge_weights(images: Tensor, size: tuple[int, int]) -> tuple[Tensor, Tensor]:
    """The edge-aware smoothness' weights across columns and rows: exp(-10 |image gradient|)
    of the mean colour at the depth's resolution ``size`` (depth edges follow image edges)."""
    small = F.interpolate(images, size=size, mode="area").mean(1, keepdim=True)
    gx_img = (small - torch.roll(small, 1, -1)).abs()
    gy_img = (small[..., 1:, :] - small[..., :-1, :]).abs()
    return torch.exp(-10 * gx_img), torch.exp(-10 * gy_img)


def _spans(counts: list[int]) -> list[tuple[int, int]]:
    """Consecutive (start, end) index ranges of groups of ``counts`` items."""
    ends = list(itertools.accumulate(counts))
    return list(zip([0, *ends[:-1]], ends, strict=True))
