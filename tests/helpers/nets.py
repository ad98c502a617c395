"""Seeded random networks in place of the shipped weights, for fast CLI plumbing tests."""

from __future__ import annotations

import torch

from panogrf.model.depth import DepthEstimator
from panogrf.model.mono import MonoDepthConfig, MonoDepthNet
from panogrf.model.mvs import PRESETS as MVS_PRESETS
from panogrf.model.mvs import MVSNet
from panogrf.model.render_net import PRESETS, RendererNet
from panogrf.renderer.methods import Models


def random_models() -> Models:
    """`Models` with tiny seeded random networks (depth estimated at 32 rows)."""
    torch.manual_seed(0)
    mvs = {m: MVSNet(MVS_PRESETS[m]).eval() for m in ("full", "mvs")}
    est = DepthEstimator(MonoDepthNet(MonoDepthConfig()), mvs, working_height=32).eval()
    nets = {k: RendererNet(v).eval() for k, v in PRESETS.items()}
    return Models(estimator=lambda mode: est, renderer=lambda preset: nets[preset])
