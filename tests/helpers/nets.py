"""Seeded random networks in place of the shipped weights, for fast CLI plumbing tests."""

from __future__ import annotations

from dataclasses import replace

import torch

from panogrf.model.depth import DEFAULT_SWEEP, DepthEstimator
from panogrf.model.mono import MonoDepthConfig, MonoDepthNet
from panogrf.model.mvs import PRESETS as MVS_PRESETS
from panogrf.model.mvs import MVSNet
from panogrf.model.render_net import PRESETS, RendererNet
from panogrf.renderer.cache import SceneCache, build_cache
from panogrf.renderer.methods import Models


def random_models(device="cpu") -> Models:
    """`Models` with tiny seeded random networks (depth estimated at 32 rows, its photometric
    sweep at twice that, as the shipped estimator sweeps at twice its 128 rows), on the CPU
    (``device`` is taken as `panogrf.app.scene.session.default_models` takes it)."""
    torch.manual_seed(0)
    mvs = {m: MVSNet(MVS_PRESETS[m]).eval() for m in ("full", "mvs")}
    sweep = replace(DEFAULT_SWEEP, height=64)
    est = DepthEstimator(
        MonoDepthNet(MonoDepthConfig()), mvs, working_height=32, sweep=sweep, fusion_sweep=sweep
    ).eval()
    nets = {k: RendererNet(v).eval() for k, v in PRESETS.items()}
    return Models(estimator=lambda mode: est, renderer=lambda preset: nets[preset])


def random_cache(views: int = 2) -> tuple[RendererNet, SceneCache]:
    """A seeded random renderer and the cache of ``views`` random 32 x 64 sources, one metre
    apart along x, all at 2 m depth (for the viewer's worker)."""
    torch.manual_seed(0)
    net = RendererNet().eval()
    c2w = torch.eye(4).repeat(views, 1, 1)
    c2w[:, 0, 3] = torch.arange(views, dtype=c2w.dtype)
    with torch.no_grad():
        cache = build_cache(
            net, torch.rand(views, 3, 32, 64), c2w, torch.full((views, 1, 16, 32), 2.0)
        )
    return net, cache


def tiny_cache_models(kind: type[Models] = Models) -> Models:
    """Random networks for the scene cache's tests: the estimator at 32 rows (mode full, no
    unguided network), the default renderer; ``kind``: `Models` or a subclass
    (`panogrf.app.scene.session.ShippedModels`)."""
    torch.manual_seed(0)
    est = DepthEstimator(
        MonoDepthNet(MonoDepthConfig()),
        {"full": MVSNet(MVS_PRESETS["full"]).eval()},
        working_height=32,
    ).eval()
    net = RendererNet().eval()
    return kind(estimator=lambda mode: est, renderer=lambda preset: net)


def tiny_views(seed: int = 0):
    """Two random 32x64 panoramas 1 m apart (`SourceViews`)."""
    from panogrf.renderer.methods import SourceViews

    gen = torch.Generator().manual_seed(seed)
    c2w = torch.eye(4).repeat(2, 1, 1)
    c2w[1, 0, 3] = 1.0
    return SourceViews(torch.rand(2, 3, 32, 64, generator=gen), c2w)
