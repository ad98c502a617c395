"""Sparse depth anchors: matches between posed panoramas triangulated with the known poses, and
their bounded pull in the per-scene refinement. Scenes: two cameras inside a sphere whose
depth is known exactly, textured with random blobs (SIFT needs corners) or blank."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from panogrf.model.anchors import (
    AnchorConfig,
    Anchors,
    anchor_loss,
    triangulate_known,
    triangulated_anchors,
)
from panogrf.model.erp import erp_directions
from panogrf.model.refine import RefineConfig, refine_depth

RADIUS = 3.0
CENTRES = [(0.0, 0.0, 0.0), (0.9, 0.1, -0.2)]


def _blobs(points: torch.Tensor, seed: int = 0) -> torch.Tensor:
    """Random coloured blobs on the sphere: points [..., 3] -> colours [..., 3] in [0, 1]."""
    gen = torch.Generator().manual_seed(seed)
    centres = torch.nn.functional.normalize(torch.randn(400, 3, generator=gen, dtype=points.dtype))
    colours = torch.rand(400, 3, generator=gen, dtype=points.dtype)
    sizes = 0.03 + 0.08 * torch.rand(400, generator=gen, dtype=points.dtype)
    unit = torch.nn.functional.normalize(points, dim=-1)
    d2 = ((unit[..., None, :] - centres) ** 2).sum(-1)  # [..., 400]
    weight = torch.exp(-d2 / (2 * sizes**2))
    return (0.5 + (weight[..., None] * (colours - 0.5)).sum(-2)).clamp(0, 1)


def _camera(centre, h, texture=True):
    """Image [3, h, 2h] and true spherical depth [1, h, 2h] of a camera at ``centre``."""
    d = erp_directions(h, 2 * h, dtype=torch.float64)
    o = torch.tensor(centre, dtype=torch.float64)
    b = (d * o).sum(-1)
    t = -b + torch.sqrt(b * b - (o * o).sum() + RADIUS**2)
    colour = _blobs(o + t[..., None] * d) if texture else torch.full((*t.shape, 3), 0.5)
    return colour.permute(2, 0, 1).float(), t[None].float()


def _scene(h, texture=True):
    imgs, depths = zip(*(_camera(c, h, texture) for c in CENTRES), strict=True)
    c2w = torch.eye(4).repeat(2, 1, 1)
    for i, c in enumerate(CENTRES):
        c2w[i, :3, 3] = torch.tensor(c)
    return torch.stack(imgs), c2w, torch.stack(depths)


@pytest.fixture(scope="module")
def textured():
    torch.set_num_threads(1)
    return _scene(256)


def test_triangulation_recovers_distances_and_angle():
    rng = np.random.default_rng(0)
    c2w_a, c2w_b = np.eye(4), np.eye(4)
    c2w_b[:3, 3] = [1.0, 0.0, 0.5]
    angle = 0.3
    c2w_b[:3, :3] = [
        [math.cos(angle), 0, math.sin(angle)],
        [0, 1, 0],
        [-math.sin(angle), 0, math.cos(angle)],
    ]
    points = rng.uniform(-3, 3, (50, 3)) + [0, 0, -5]
    ray_a = points - c2w_a[:3, 3]
    ray_b = points - c2w_b[:3, 3]
    dist_a, dist_b = np.linalg.norm(ray_a, axis=1), np.linalg.norm(ray_b, axis=1)
    bearings_a = ray_a / dist_a[:, None]
    bearings_b = (ray_b / dist_b[:, None]) @ c2w_b[:3, :3]  # world -> camera b
    dist, parallax = triangulate_known(c2w_a, c2w_b, bearings_a, bearings_b)
    np.testing.assert_allclose(dist[:, 0], dist_a, rtol=1e-9)
    np.testing.assert_allclose(dist[:, 1], dist_b, rtol=1e-9)
    cos = (ray_a * ray_b).sum(1) / (dist_a * dist_b)
    np.testing.assert_allclose(parallax, np.degrees(np.arccos(cos)), atol=1e-6)


def test_anchors_lie_on_the_true_surface(textured):
    images, c2w, depth = textured
    anchors = triangulated_anchors(images, c2w, [[1], [0]])
    for v in range(2):
        a = anchors[v]
        assert len(a) >= 50
        # The true distance along each anchor's bearing, from the sphere.
        o = c2w[v, :3, 3].double()
        d = a.bearings.double()
        b = d @ o
        true = -b + torch.sqrt(b * b - o @ o + RADIUS**2)
        err = (a.log_depth.double() - torch.log(true)).abs()
        assert float(err.median()) < 0.02  # a pixel at 256 rows: 0.7 degrees, parallax ~20
        assert float((err > 0.1).double().mean()) < 0.1  # blobs repeat: the loss is bounded


def test_no_sources_no_anchors(textured):
    images, c2w, _ = textured
    anchors = triangulated_anchors(images, c2w, [[], []])
    assert [len(a) for a in anchors] == [0, 0]


def test_a_narrow_parallax_leaves_no_anchors(textured):
    """Rays that meet at less than ``min_parallax_deg`` give no anchor."""
    images, c2w, _ = textured
    anchors = triangulated_anchors(images, c2w, [[1], [0]], AnchorConfig(min_parallax_deg=90.0))
    assert sum(len(a) for a in anchors) < 5


def _true_anchors(depth, c2w, count=200, seed=0, factor=1.0):
    """Anchors on the true sphere (times ``factor``) along random bearings of each view."""
    gen = torch.Generator().manual_seed(seed)
    out = []
    for v in range(depth.shape[0]):
        d = torch.nn.functional.normalize(torch.randn(count, 3, generator=gen, dtype=torch.float64))
        o = c2w[v, :3, 3].double()
        b = d @ o
        true = -b + torch.sqrt(b * b - o @ o + RADIUS**2)
        out.append(Anchors(d.float(), torch.log(factor * true).float()))
    return out


def test_anchor_loss_is_bounded_and_zero_on_the_truth():
    _, c2w, depth = _scene(32, texture=False)
    anchors = _true_anchors(depth, c2w)
    exact = anchor_loss(torch.log(depth), anchors, [0, 1], 0.1)
    assert float(exact) < 0.01  # bilinear reads of the sphere's depth
    far = anchor_loss(torch.log(depth * 20.0), anchors, [0, 1], 0.1)
    assert 0.95 < float(far) <= 1.0


def test_anchors_pull_the_depth_where_the_photometry_is_blank():
    """On a blank sphere the colours say nothing: a depth 25 % too far moves to the anchors'
    surface with them and stays without them."""
    images, c2w, depth = _scene(64, texture=False)
    small = torch.nn.functional.interpolate(depth, size=(32, 64), mode="area")
    wrong = small * 1.25
    config = RefineConfig(iterations=60, height=64, smooth=1.0, anchors=1.0, anchor_scale=0.3)
    right = _true_anchors(small, c2w, count=300)
    pulled = refine_depth(images, c2w, wrong, [[1], [0]], config, anchors=right)
    before = (wrong - small).abs().mean()
    assert (pulled - small).abs().mean() < 0.4 * before
    off = dataclasses.replace(config, anchors=0.0)
    kept = refine_depth(images, c2w, wrong, [[1], [0]], off, anchors=right)
    assert (kept - wrong).abs().mean() < 0.1 * before


def test_a_far_anchor_pulls_less_than_a_near_one():
    """The loss is bounded: the pull of an anchor 10 scales off is under a twentieth of the
    pull of one a scale off (a wrong repetition of a pattern must not drag the surface)."""
    scale = 0.1
    pulls = []
    for off in (scale, 10 * scale):
        log_depth = torch.zeros(1, 1, 8, 16, requires_grad=True)
        bearings = torch.tensor([[0.0, 0.0, -1.0]])
        anchor_loss(log_depth, [Anchors(bearings, torch.tensor([off]))], [0], scale).backward()
        pulls.append(float(log_depth.grad.abs().sum()))
    assert pulls[1] < pulls[0] / 20


def test_refinement_finds_its_own_anchors(textured):
    """With ``anchors`` on and none given, the refinement triangulates them from the images."""
    images, c2w, depth = textured
    small = torch.nn.functional.interpolate(depth, size=(64, 128), mode="area")
    config = RefineConfig(iterations=20, height=64, smooth=1.0, anchors=1.0, prior=1.0)
    wrong = small * 1.1
    out = refine_depth(images, c2w, wrong, [[1], [0]], config)
    without = refine_depth(
        images,
        c2w,
        wrong,
        [[1], [0]],
        RefineConfig(iterations=20, height=64, smooth=1.0, prior=1.0),
    )
    assert (out - small).abs().mean() < (without - small).abs().mean()
