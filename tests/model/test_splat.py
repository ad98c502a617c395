"""Proxy depth by forward splatting, checked on an analytic room with an occluding ball."""

from __future__ import annotations

import math

import torch
from helpers.room import pose, render
from torch.utils._python_dispatch import TorchDispatchMode

from panogrf.model.erp import rotation_about
from panogrf.model.splat import fill_holes, proxy_depth, splat_zbuffer

SRC_A = pose(rotation_about("y", 0.3), [-0.5, 0.0, 0.1])
SRC_B = pose(rotation_about("y", -1.1) @ rotation_about("x", 0.05), [0.6, 0.1, -0.2])
TGT = pose(rotation_about("y", 2.0), [0.05, 0.05, -0.05])


def _sources(height: int, ball: bool = True):
    a_img, a_depth = render(SRC_A, ball=ball, height=height, width=2 * height)
    b_img, b_depth = render(SRC_B, ball=ball, height=height, width=2 * height)
    return torch.cat((a_depth, b_depth)).float(), torch.stack((SRC_A, SRC_B)).float()


def test_splatted_depth_matches_the_true_target_depth():
    depth, c2w = _sources(64)
    _, true = render(TGT, ball=True, height=64, width=128)
    true = true[0, 0].float()
    proxy = proxy_depth(depth, c2w, TGT.float(), 64, 128)
    assert proxy.near.shape == (64, 128) and torch.isfinite(proxy.near).all()
    assert (proxy.near > 0).all() and (proxy.far >= proxy.near).all()
    rel = (proxy.near - true).abs() / true
    assert proxy.covered.float().mean() > 0.9
    assert (rel < 0.03).float().mean() > 0.9, (rel < 0.03).float().mean()
    # Where the proxies disagree the truth is (nearly always) inside [near, far].
    inside = (true >= proxy.near * 0.97) & (true <= proxy.far * 1.03)
    assert inside.float().mean() > 0.97


def test_zbuffer_keeps_the_nearest_surface():
    depth, c2w = _sources(64)
    # A source splatted into itself is itself.
    zbuf = splat_zbuffer(depth[:1], c2w[:1], c2w[0], 64, 128)
    assert torch.allclose(zbuf, depth[0, 0], rtol=1e-4)
    # Splatting both sources never puts anything behind the first surface the target sees.
    _, true = render(TGT, ball=True, height=64, width=128)
    both = splat_zbuffer(depth, c2w, TGT.float(), 64, 128)
    hit = both > 0
    assert hit.float().mean() > 0.95
    # (At silhouettes a background point may fill a gap the foreground left: a few pixels.)
    assert (both[hit] <= true[0, 0].float()[hit] * 1.02).float().mean() > 0.97


def test_fill_holes_takes_the_background_and_never_leaves_a_hole():
    d = torch.full((8, 16), 2.0)
    d[:, 8:] = 5.0
    d[3, 7:10] = 0.0  # a hole at the edge between 2 m and 5 m
    filled = fill_holes(d)
    assert (filled > 0).all()
    assert filled[3, 8] == 5.0 and filled[3, 9] == 5.0
    empty = fill_holes(torch.zeros(4, 8))
    assert torch.isfinite(empty).all() and (empty > 0).all()


class _Ops(TorchDispatchMode):
    """Records the operators a call dispatches (what a GPU would be asked to run)."""

    def __init__(self) -> None:
        super().__init__()
        self.names: list[str] = []

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        name = str(func)
        indices = args[1] if name.startswith("aten.index.Tensor") else ()
        if any(getattr(i, "dtype", None) == torch.bool for i in indices):
            name = "boolean selection"
        self.names.append(name)
        return func(*args, **(kwargs or {}))


WAITS = ("aten._local_scalar_dense", "aten.nonzero", "aten.masked_select", "boolean selection")


def test_splatting_never_waits_for_the_device_and_matches_the_point_by_point_zbuffer():
    depth, c2w = _sources(32)
    depth[0, 0, 10:14] = 0.0  # unknown depth lands nowhere
    with _Ops() as ops:
        zbuf = splat_zbuffer(depth, c2w, TGT.float(), 32, 64)
    assert not [n for n in ops.names if n.startswith(WAITS)], ops.names
    # The reference: every known point on its nearest pixel, else the 2x2 footprint's minimum.
    from panogrf.model.erp import erp_to_world, world_to_erp

    keep = depth[:, 0].reshape(-1) > 0
    points = erp_to_world(depth[:, 0], c2w).reshape(-1, 3)[keep]
    uv, dist = world_to_erp(points, TGT.float(), 32, 64)
    nearest = torch.full((32, 64), float("inf"))
    wide = torch.full((32, 64), float("inf"))
    for (u, v), d in zip(uv.tolist(), dist.tolist(), strict=True):
        ru, rv = round(u), round(v)  # torch.round: half to even, as Python's round
        r = nearest[min(max(rv, 0), 31), ru % 64]
        nearest[min(max(rv, 0), 31), ru % 64] = min(float(r), d)
        for du in (0, 1):
            for dv in (0, 1):
                fu, fv = math.floor(u) + du, min(max(math.floor(v) + dv, 0), 31)
                wide[fv, fu % 64] = min(float(wide[fv, fu % 64]), d)
    ref = torch.where(torch.isfinite(nearest), nearest, wide)
    ref = torch.where(torch.isfinite(ref), ref, torch.zeros_like(ref))
    torch.testing.assert_close(zbuf, ref, rtol=0, atol=0)


def test_filling_waits_once_when_nothing_is_missing():
    d = torch.full((8, 16), 2.0)
    with _Ops() as ops:
        out = fill_holes(d)
    assert sum(n.startswith(WAITS) for n in ops.names) == 1
    assert torch.equal(out, d)


def test_looking_for_holes_less_often_fills_the_same_with_fewer_waits():
    depth, c2w = _sources(32)
    zbuf = splat_zbuffer(depth, c2w, TGT.float(), 32, 64)
    zbuf[5:12, 20:29] = 0.0  # a hole 7 passes deep
    waits = {}
    for look in (1, 4):
        with _Ops() as ops:
            filled = fill_holes(zbuf, look=look)
        waits[look] = sum(n.startswith(WAITS) for n in ops.names)
        if look == 1:
            reference = filled
    assert torch.equal(filled, reference) and (filled > 0).all()
    assert waits[4] < waits[1]
