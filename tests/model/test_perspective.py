"""Perspective cut-outs of panoramas: the centre pixel looks down -z, the field of view holds."""

from __future__ import annotations

import math

import pytest
import torch

from panogrf.model.erp import erp_directions
from panogrf.model.perspective import erp_to_perspective, perspective_directions


def test_directions_centre_corners_and_field_of_view():
    d = perspective_directions(5, 3, 90.0, dtype=torch.float64)
    assert d.shape == (3, 5, 3)
    assert torch.allclose(d[1, 2], torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64))
    # The top edge of the image is fov/2 above the axis.
    top = perspective_directions(1, 100, 60.0, dtype=torch.float64)[0, 0]
    angle = math.degrees(math.atan2(top[1].item(), -top[2].item()))
    # The first row's centre sits half a pixel below the edge: atan(49.5 / f), f = 50 / tan 30.
    want = math.degrees(math.atan(49.5 * math.tan(math.radians(30.0)) / 50.0))
    assert angle == pytest.approx(want, abs=1e-9)
    assert torch.allclose(torch.linalg.vector_norm(d, dim=-1), torch.ones(3, 5, dtype=d.dtype))
    with pytest.raises(ValueError):
        perspective_directions(4, 4, 180.0)


def test_cut_out_of_a_direction_coded_panorama():
    # A panorama whose colour is its own viewing direction: the cut-out must show its rays.
    erp = erp_directions(64, 128, dtype=torch.float64).permute(2, 0, 1)
    out = erp_to_perspective(erp, 16, 12, 70.0)
    want = perspective_directions(16, 12, 70.0, dtype=torch.float64).permute(2, 0, 1)
    assert out.shape == (3, 12, 16)
    assert (out - want).abs().max() < 0.03
