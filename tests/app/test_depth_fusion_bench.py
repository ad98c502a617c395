"""`benchmarks/depth_fusion.py`'s "true" condition: the monocular depth replaced by the truth
(resized, the network's own value kept where the truth is missing), its features as computed."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
import torch

from panogrf.app.weights.networks import load_depth_estimator

ROOT = Path(__file__).resolve().parents[2]


def _bench():
    spec = importlib.util.spec_from_file_location(
        "depth_fusion_bench", ROOT / "benchmarks" / "depth_fusion.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_true_condition_puts_the_truth_in_and_keeps_the_features():
    bench = _bench()
    est = load_depth_estimator(("full", "mvs"))
    images = torch.rand(2, 3, 64, 128, generator=torch.Generator().manual_seed(0))
    truth = torch.full((2, 128, 256), 2.5)
    truth[0, :10] = 0.0  # missing: the network's own value stays
    truth[1, -10:] = 1e4  # beyond d_max: the same
    with torch.no_grad():
        before = est.mono(images)
        inside = bench._mono_true(est, truth)(est.mono, images)
    h = before.depth.shape[-2]
    edge = max(1, h * 10 // 128)  # the rows the 10 changed rows of the truth become
    assert torch.equal(inside.features, before.features)
    assert torch.allclose(inside.depth[0, :, edge + 1 :], torch.tensor(2.5))
    assert torch.equal(inside.depth[0, :, :edge], before.depth[0, :, :edge])
    assert torch.equal(inside.depth[1, :, -edge:], before.depth[1, :, -edge:])
    assert not torch.allclose(before.depth, inside.depth)
    with torch.no_grad(), pytest.raises(ValueError, match="views"):
        bench._mono_true(est, truth[:1])(est.mono, images)
