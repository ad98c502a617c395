"""Image and depth metrics: hand-computed values, skimage agreement for SSIM, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity

from panogrf.model.erp import latitude_weights
from panogrf.model.metrics import (
    ELEVATION_BANDS,
    DepthMetrics,
    band_key,
    depth_l1_by_band,
    depth_metrics,
    depth_metrics_batch,
    psnr,
    ssim,
    ws_psnr,
)


def _rand(*shape: int, seed: int = 0) -> torch.Tensor:
    return torch.rand(*shape, generator=torch.Generator().manual_seed(seed))


# ---------------------------------------------------------------- PSNR / WS-PSNR


def test_psnr_constant_error_hand_value():
    # Every pixel off by 0.1 -> MSE 0.01 -> PSNR 20 dB.
    x = torch.full((3, 16, 32), 0.5)
    assert float(psnr(x, x + 0.1)) == pytest.approx(20.0, abs=1e-4)
    assert float(psnr(x, x + 0.01)) == pytest.approx(40.0, abs=1e-3)


def test_psnr_shapes_and_batch_is_per_image():
    x = _rand(2, 3, 16, 32, seed=1)
    y = _rand(2, 3, 16, 32, seed=2)
    out = psnr(x, y)
    assert out.shape == (2,)
    assert psnr(x[0], y[0]).shape == ()
    torch.testing.assert_close(out[1], psnr(x[1], y[1]))


def test_psnr_identical_is_inf():
    x = _rand(3, 16, 32)
    assert math.isinf(float(psnr(x, x)))


def test_ws_psnr_equals_psnr_for_uniform_error():
    x = torch.full((3, 16, 32), 0.25)
    assert float(ws_psnr(x, x + 0.05)) == pytest.approx(float(psnr(x, x + 0.05)), abs=1e-4)


def test_ws_psnr_hand_value_with_row_errors():
    # Error e_r in row r: WMSE = sum_r w_r e_r^2 / sum_r w_r (columns and channels cancel).
    h, w = 8, 16
    row_err = torch.linspace(0.0, 0.2, h)
    x = torch.zeros(3, h, w)
    y = row_err[None, :, None].expand(3, h, w).clone()
    wr = latitude_weights(h, w)[:, 0]
    wmse = float((wr * row_err**2).sum() / wr.sum())
    assert float(ws_psnr(x, y)) == pytest.approx(10 * math.log10(1 / wmse), abs=1e-4)


def test_ws_psnr_weights_emphasise_equator():
    h, w = 16, 32
    x = torch.zeros(3, h, w)
    at_equator, at_pole = x.clone(), x.clone()
    at_equator[:, h // 2] = 0.5  # same error, one row each
    at_pole[:, 0] = 0.5
    assert float(psnr(x, at_equator)) == pytest.approx(float(psnr(x, at_pole)))
    assert float(ws_psnr(x, at_equator)) < float(ws_psnr(x, at_pole)) - 10.0


# ---------------------------------------------------------------- SSIM


@pytest.mark.parametrize("seed", [0, 1])
def test_ssim_matches_skimage(seed):
    x = _rand(3, 24, 40, seed=seed)
    y = (x + 0.2 * _rand(3, 24, 40, seed=seed + 10)).clamp(0, 1)
    ref = structural_similarity(
        x.permute(1, 2, 0).double().numpy(),
        y.permute(1, 2, 0).double().numpy(),
        gaussian_weights=True,
        sigma=1.5,
        use_sample_covariance=False,
        data_range=1.0,
        channel_axis=2,
    )
    assert float(ssim(x, y)) == pytest.approx(ref, abs=1e-4)
    assert float(ssim(x.double(), y.double())) == pytest.approx(ref, abs=1e-10)


def test_ssim_identical_is_one_and_batch_shape():
    x = _rand(2, 3, 16, 32)
    out = ssim(x, x)
    assert out.shape == (2,)
    torch.testing.assert_close(out, torch.ones(2))


def test_ssim_too_small_raises():
    x = _rand(3, 8, 16)
    with pytest.raises(ValueError, match="at least 11x11"):
        ssim(x, x)


# ---------------------------------------------------------------- image input errors


@pytest.mark.parametrize("metric", [psnr, ws_psnr, ssim])
def test_shape_mismatch_raises(metric):
    with pytest.raises(ValueError, match=r"shapes differ: \(3, 16, 32\) vs \(3, 16, 30\)"):
        metric(_rand(3, 16, 32), _rand(3, 16, 30))


@pytest.mark.parametrize("metric", [psnr, ws_psnr, ssim])
def test_nan_input_raises(metric):
    x = _rand(3, 16, 32)
    y = x.clone()
    y[0, 1, 2] = float("nan")
    with pytest.raises(ValueError, match="1 NaN/inf"):
        metric(x, y)


def test_out_of_range_and_dtype_and_rank_raise():
    x = _rand(3, 16, 32)
    with pytest.raises(ValueError, match=r"values in \[0, 1\], got \[0, 255\]"):
        psnr(x, (x > 0.5).float() * 255)  # an 8-bit image not divided by 255
    with pytest.raises(ValueError, match="float images"):
        psnr((x * 255).to(torch.uint8), (x * 255).to(torch.uint8))
    with pytest.raises(ValueError, match=r"\[C, H, W\] or \[B, C, H, W\]"):
        psnr(x[0], x[0])


# ---------------------------------------------------------------- depth


def test_depth_metrics_hand_values_with_invalid_pixels():
    # 2x4 map: errors +1 and -3 on the valid pixels; gt <= 0, NaN, inf are invalid and the
    # prediction there (even NaN) must not matter.
    gt = torch.tensor([[2.0, 0.0, float("nan"), 4.0], [1.0, -1.0, float("inf"), 5.0]])
    pred = torch.tensor([[3.0, 9.0, float("nan"), 1.0], [2.0, 9.0, 9.0, 6.0]])
    m = depth_metrics(pred, gt)
    # valid: (0,0) e=1, (0,3) e=-3, (1,0) e=1, (1,3) e=1
    assert m.valid == 4
    assert m.l1 == pytest.approx(6 / 4)
    assert m.l2 == pytest.approx(12 / 4)
    assert m.rmse == pytest.approx(math.sqrt(3))
    # With 2 rows the cos-latitude weights are equal, so WS- equals plain.
    assert (m.ws_l1, m.ws_l2, m.ws_rmse) == pytest.approx((m.l1, m.l2, m.rmse))


def test_depth_metrics_mask_and_ws_weighting():
    h, w = 4, 8
    gt = torch.ones(h, w)
    pred = gt.clone()
    pred[0] += 2.0  # error only in the polar row
    pred[1] += 1.0  # and a smaller one near the equator
    mask = torch.ones(h, w, dtype=torch.bool)
    mask[3, :] = False
    m = depth_metrics(pred, gt, mask=mask)
    assert m.valid == 3 * w
    assert m.l1 == pytest.approx((2 * w + w) / (3 * w))
    wr = latitude_weights(h, w)[:3, 0].double()
    e = torch.tensor([2.0, 1.0, 0.0], dtype=torch.float64)
    assert m.ws_l1 == pytest.approx(float((wr * e).sum() / wr.sum()), rel=1e-6)
    assert m.ws_l2 == pytest.approx(float((wr * e**2).sum() / wr.sum()), rel=1e-6)
    assert m.ws_l1 < m.l1  # the polar row counts less


def test_depth_metrics_batch_is_per_image_and_dataclass_frozen():
    gt = 1.0 + _rand(2, 1, 8, 16, seed=3)
    pred = gt.clone()
    pred[1] += 0.5
    ms = depth_metrics_batch(pred, gt)
    assert [m.l1 for m in ms] == pytest.approx([0.0, 0.5])
    assert isinstance(ms[0], DepthMetrics)
    assert set(ms[0].as_dict()) == {"l1", "l2", "rmse", "ws_l1", "ws_l2", "ws_rmse", "valid"}
    with pytest.raises(AttributeError):
        ms[0].l1 = 1.0  # type: ignore[misc]


def test_depth_l1_by_band_hand_values():
    """Six rows, one per 30-degree band: each band's sum and count are its own row's, masked
    pixels left out; two views pool by adding."""
    gt = torch.full((2, 6, 4), 2.0)
    pred = gt + torch.arange(6.0)[None, :, None]  # row r off by r metres
    mask = torch.ones_like(gt, dtype=torch.bool)
    mask[1, 0] = False  # the second view's top row is not counted
    out = depth_l1_by_band(pred, gt, mask)
    assert list(out) == [band_key(b) for b in ELEVATION_BANDS]
    assert out["l1_90_60"] == (0.0, 4)
    for r, band in enumerate(ELEVATION_BANDS[1:], start=1):
        total, count = out[band_key(band)]
        assert count == 8 and total == pytest.approx(8 * r)
    # At 12 rows each band holds two rows.
    out = depth_l1_by_band(torch.ones(12, 2), torch.zeros(12, 2), torch.ones(12, 2, dtype=bool))
    assert all(v == (4.0, 4) for v in out.values())
    with pytest.raises(ValueError, match="shapes differ"):
        depth_l1_by_band(pred, gt[:1], mask)


def test_depth_metrics_errors():
    gt = torch.ones(4, 8)
    with pytest.raises(ValueError, match=r"shapes differ: pred \(4, 7\) vs gt \(4, 8\)"):
        depth_metrics(torch.ones(4, 7), gt)
    with pytest.raises(ValueError, match="no valid ground-truth pixels"):
        depth_metrics(gt, torch.zeros(4, 8))
    bad = gt.clone()
    bad[0, 0] = float("nan")
    with pytest.raises(ValueError, match="pred has 1 NaN/inf"):
        depth_metrics(bad, gt)
    with pytest.raises(ValueError, match="bool mask"):
        depth_metrics(gt, gt, mask=torch.ones(4, 8))
    with pytest.raises(ValueError, match="depth_metrics_batch"):
        depth_metrics(torch.ones(2, 4, 8), torch.ones(2, 4, 8))


def test_ssim_agrees_with_skimage_on_gray_single_channel():
    rng = np.random.default_rng(5)
    a = rng.random((20, 30))
    b = np.clip(a + 0.1 * rng.standard_normal((20, 30)), 0, 1)
    ref = structural_similarity(
        a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1.0
    )
    got = float(ssim(torch.from_numpy(a)[None], torch.from_numpy(b)[None]))
    assert got == pytest.approx(ref, abs=1e-10)
