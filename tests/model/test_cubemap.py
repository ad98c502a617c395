"""Cubemap <-> ERP resampling: face orientation, face assignment and round trips."""

from __future__ import annotations

import pytest
import torch

from panogrf.model import cubemap, erp

F64 = torch.float64
AXES = {
    "front": (0.0, 0.0, -1.0),
    "right": (1.0, 0.0, 0.0),
    "back": (0.0, 0.0, 1.0),
    "left": (-1.0, 0.0, 0.0),
    "up": (0.0, 1.0, 0.0),
    "down": (0.0, -1.0, 0.0),
}
# The direction at the top of each face (row 0, centre column).
FACE_UP = {
    "front": (0.0, 1.0, 0.0),
    "right": (0.0, 1.0, 0.0),
    "back": (0.0, 1.0, 0.0),
    "left": (0.0, 1.0, 0.0),
    "up": (0.0, 0.0, 1.0),
    "down": (0.0, 0.0, -1.0),
}


def smooth_field(d: torch.Tensor) -> torch.Tensor:
    """A low-frequency function of the direction [..., 3] -> [..., 2]."""
    x, y, z = d.unbind(-1)
    return torch.stack((x + 0.5 * y * z, torch.sin(2 * y) + 0.3 * x * x - 0.2 * z), -1)


def smooth_panorama(height: int, width: int) -> torch.Tensor:
    dirs = erp.erp_directions(height, width, dtype=F64)
    return smooth_field(dirs).permute(2, 0, 1)[None]  # [1, 2, H, W]


def test_face_rotations_are_rotations_with_named_axes():
    rots = cubemap.face_rotations(F64)
    assert rots.shape == (6, 3, 3)
    torch.testing.assert_close(rots @ rots.transpose(1, 2), torch.eye(3, dtype=F64).expand(6, 3, 3))
    torch.testing.assert_close(torch.linalg.det(rots), torch.ones(6, dtype=F64))
    for k, name in enumerate(cubemap.FACE_NAMES):
        look = rots[k] @ torch.tensor([0.0, 0.0, -1.0], dtype=F64)
        torch.testing.assert_close(look, torch.tensor(AXES[name], dtype=F64))


def test_face_directions_orientation():
    size = 5  # odd: pixel (2, 2) is the exact face centre
    dirs = cubemap.face_directions(size, dtype=F64)
    assert dirs.shape == (6, size, size, 3)
    torch.testing.assert_close(
        torch.linalg.vector_norm(dirs, dim=-1), torch.ones(6, size, size, dtype=F64)
    )
    for k, name in enumerate(cubemap.FACE_NAMES):
        axis = torch.tensor(AXES[name], dtype=F64)
        up = torch.tensor(FACE_UP[name], dtype=F64)
        torch.testing.assert_close(dirs[k, 2, 2], axis)
        # Row 0 is upright: tilted from the axis towards the face's up direction.
        top = dirs[k, 0, 2]
        assert torch.dot(top, up) > 0.5 and abs(torch.dot(top, axis)) > 0.5
        bottom = dirs[k, -1, 2]
        assert torch.dot(bottom, up) < -0.5
    # Right in the image is to the right of the viewer (right = look x up).
    for k, name in enumerate(cubemap.FACE_NAMES):
        right = torch.linalg.cross(
            torch.tensor(AXES[name], dtype=F64), torch.tensor(FACE_UP[name], dtype=F64)
        )
        assert torch.dot(dirs[k, 2, -1], right) > 0.5
    # The front face's right column looks towards +x, the right face's left column towards -z.
    front, right_face = cubemap.FACE_NAMES.index("front"), cubemap.FACE_NAMES.index("right")
    assert dirs[front, 2, -1, 0] > 0.5 and dirs[right_face, 2, 0, 2] < -0.5


def test_side_faces_are_upright_in_the_erp():
    """Row 0 of every side face shows what the ERP shows above the face's centre."""
    pano = erp.erp_directions(16, 32, dtype=F64)[..., 1][None, None]  # height (y) as an image
    faces = cubemap.erp_to_cubemap(pano, 8)
    for k in range(4):
        column = faces[0, k, 0, :, 4]
        assert (column[:-1] > column[1:]).all(), "y must decrease down the rows of a side face"


def test_face_centre_equals_erp_sample_along_the_axis():
    gen = torch.Generator().manual_seed(0)
    pano = torch.randn(2, 3, 16, 32, generator=gen, dtype=F64)
    size = 7
    faces = cubemap.erp_to_cubemap(pano, size)
    assert faces.shape == (2, 6, 3, size, size)
    axes = torch.tensor([AXES[n] for n in cubemap.FACE_NAMES], dtype=F64)[None].expand(2, -1, -1)
    expected = erp.sample_erp_directions(pano, axes)  # [2, 3, 6]
    torch.testing.assert_close(faces[:, :, :, 3, 3], expected.permute(0, 2, 1))


def test_erp_to_cubemap_of_a_direction_field():
    """Each face pixel samples the panorama along its own direction."""
    pano = smooth_panorama(64, 128)
    size = 8
    faces = cubemap.erp_to_cubemap(pano, size)
    expected = smooth_field(cubemap.face_directions(size, dtype=F64)).permute(0, 3, 1, 2)[None]
    assert (faces - expected).abs().max() < 5e-3


def test_cubemap_to_erp_assigns_the_dominant_axis_face():
    height, width, size = 16, 32, 4
    # Face k filled with the constant k: the ERP must show the index of its dominant axis.
    faces = torch.arange(6, dtype=F64).reshape(1, 6, 1, 1, 1).expand(1, 6, 1, size, size)
    out = cubemap.cubemap_to_erp(faces, height, width)
    assert out.shape == (1, 1, height, width)
    d = erp.erp_directions(height, width, dtype=F64)
    axes = torch.tensor([AXES[n] for n in cubemap.FACE_NAMES], dtype=F64)
    expected = (d @ axes.T).argmax(-1).to(F64)
    torch.testing.assert_close(out[0, 0], expected)


def test_cubemap_to_erp_of_a_direction_field():
    """Faces filled analytically (independently of erp_to_cubemap) resample to the ERP field."""
    size = 32
    faces = smooth_field(cubemap.face_directions(size, dtype=F64)).permute(0, 3, 1, 2)[None]
    out = cubemap.cubemap_to_erp(faces, 32, 64)
    err = (out - smooth_panorama(32, 64)).abs()
    assert err.mean() < 2e-3 and err.max() < 0.05


@pytest.mark.parametrize(("height", "width", "size"), [(32, 64, 16), (64, 128, 32)])
def test_erp_cube_erp_round_trip_smooth(height, width, size):
    pano = smooth_panorama(height, width)
    back = cubemap.cubemap_to_erp(cubemap.erp_to_cubemap(pano, size), height, width)
    assert back.shape == pano.shape
    err = (back - pano).abs()  # the field spans about [-1.5, 1.5]
    assert err.mean() < 5e-3 and err.max() < 0.06


def test_round_trip_float32_batched_and_nearest():
    pano = smooth_panorama(32, 64).float().expand(3, -1, -1, -1).contiguous()
    faces = cubemap.erp_to_cubemap(pano, 16, mode="nearest")
    assert faces.dtype == torch.float32 and faces.shape == (3, 6, 2, 16, 16)
    back = cubemap.cubemap_to_erp(faces, 32, 64, mode="nearest")
    assert torch.isfinite(back).all() and (back - pano).abs().mean() < 0.03
    torch.testing.assert_close(back[0], back[2])


def test_cubemap_to_erp_gradients_reach_the_faces():
    faces = torch.randn(1, 6, 1, 3, 3, generator=torch.Generator().manual_seed(1), dtype=F64)
    faces.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda f: cubemap.cubemap_to_erp(f, 6, 12), (faces,))
