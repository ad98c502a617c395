"""Panorama convolutions: circular padding in width, zero padding in height."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from panogrf.model.layers import CircularConv2d, circular_pad

F64 = torch.float64


def _gen(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def test_circular_pad_wraps_width_and_zeros_height():
    x = torch.arange(2 * 3 * 4, dtype=F64).reshape(1, 2, 3, 4)
    out = circular_pad(x, pad_w=2, pad_h=1)
    assert out.shape == (1, 2, 5, 8)
    torch.testing.assert_close(out[..., 1:-1, :2], x[..., -2:])
    torch.testing.assert_close(out[..., 1:-1, -2:], x[..., :2])
    torch.testing.assert_close(out[..., 1:-1, 2:-2], x)
    assert (out[..., 0, :] == 0).all() and (out[..., -1, :] == 0).all()
    torch.testing.assert_close(circular_pad(x, 0, 0), x)


def _explicit_reference(conv: CircularConv2d, x: torch.Tensor) -> torch.Tensor:
    """The same convolution on a hand-wrapped, hand-zero-padded copy of the input."""
    ph, pw = conv.pad_hw
    wrapped = torch.cat((x[..., x.shape[-1] - pw :], x, x[..., :pw]), dim=-1) if pw else x
    zeros = wrapped.new_zeros(*wrapped.shape[:-2], ph, wrapped.shape[-1])
    padded = torch.cat((zeros, wrapped, zeros), dim=-2)
    return F.conv2d(padded, conv.weight, conv.bias, conv.stride, 0, conv.dilation, conv.groups)


@pytest.mark.parametrize(
    ("kernel", "padding", "stride"),
    [(3, 1, 1), (5, 2, 1), ((3, 5), (1, 2), 1), (3, 1, 2), (1, 0, 1)],
)
def test_matches_explicitly_wrapped_convolution(kernel, padding, stride):
    torch.manual_seed(0)
    conv = CircularConv2d(3, 4, kernel, stride=stride, padding=padding).double()
    x = torch.randn(2, 3, 8, 16, generator=_gen(1), dtype=F64)
    out = conv(x)
    torch.testing.assert_close(out, _explicit_reference(conv, x))


def test_column_zero_sees_the_last_column():
    torch.manual_seed(0)
    conv = CircularConv2d(2, 3, 3, padding=1).double()
    x = torch.randn(1, 2, 6, 10, generator=_gen(2), dtype=F64)
    out = conv(x)
    # Column 0 of the output is the kernel applied to input columns (W-1, 0, 1).
    window = torch.cat((x[..., -1:], x[..., :2]), dim=-1)
    expected = F.conv2d(window, conv.weight, conv.bias, padding=(1, 0))[..., 0]
    torch.testing.assert_close(out[..., 0], expected)
    # Changing the last column changes output column 0; a plain zero-padded conv would not.
    x2 = x.clone()
    x2[..., -1] += 1.0
    assert not torch.allclose(conv(x2)[..., 0], out[..., 0])
    plain = F.conv2d(x, conv.weight, conv.bias, padding=1)
    assert not torch.allclose(plain[..., 0], out[..., 0])
    torch.testing.assert_close(plain[..., 1:-1], out[..., 1:-1])


def test_zero_padding_in_height():
    torch.manual_seed(0)
    conv = CircularConv2d(1, 1, 3, padding=1, bias=False).double()
    with torch.no_grad():
        conv.weight.zero_()
        conv.weight[0, 0, 0, 1] = 1.0  # reads the pixel one row above
    x = torch.randn(1, 1, 5, 8, generator=_gen(3), dtype=F64)
    out = conv(x)
    assert (out[..., 0, :] == 0).all(), "the row above the top must be zeros, not wrapped"
    torch.testing.assert_close(out[..., 1:, :], x[..., :-1, :])


def test_shapes():
    x = torch.randn(2, 3, 16, 32, generator=_gen(4))
    assert CircularConv2d(3, 8, 3, padding=1)(x).shape == (2, 8, 16, 32)
    assert CircularConv2d(3, 8, 3, stride=2, padding=1)(x).shape == (2, 8, 8, 16)
    assert CircularConv2d(3, 8, (3, 5), padding=(1, 2))(x).shape == (2, 8, 16, 32)
    assert CircularConv2d(3, 8, 3, padding=2, dilation=2)(x).shape == (2, 8, 16, 32)
    assert CircularConv2d(3, 8, 3)(x).shape == (2, 8, 14, 30)
    # Positional arguments in nn.Conv2d's order: in, out, kernel, stride, padding, dilation, ...
    conv = CircularConv2d(3, 6, 3, 1, 1, 1, 3, False)
    assert conv.pad_hw == (1, 1) and conv.groups == 3 and conv.bias is None
    assert conv(x).shape == (2, 6, 16, 32)
    assert "circular" in repr(conv)


def test_bad_padding_is_an_error():
    for bad in ("same", (1,), (1, 2, 3), -1, (1.0, 1), 1.5):
        with pytest.raises(ValueError, match="padding"):
            CircularConv2d(3, 4, 3, padding=bad)
    with pytest.raises(TypeError, match="circular"):
        CircularConv2d(3, 4, 3, padding=1, padding_mode="zeros")


def test_gradcheck():
    torch.manual_seed(0)
    conv = CircularConv2d(2, 2, 3, padding=1).double()
    x = torch.randn(1, 2, 4, 6, generator=_gen(5), dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(conv, (x,))
    weight = conv.weight.detach().clone().requires_grad_(True)
    bias = conv.bias.detach().clone().requires_grad_(True)

    def with_params(w, b):
        return torch.func.functional_call(conv, {"weight": w, "bias": b}, (x.detach(),))

    assert torch.autograd.gradcheck(with_params, (weight, bias))
