"""ERP geometry: conventions, round trips, nerfstudio agreement, projection and seam sampling."""

from __future__ import annotations

import math

import pytest
import torch

from panogrf.model import erp

H, W = 16, 32
F64 = torch.float64


def _gen(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def random_rotations(n: int, gen: torch.Generator, dtype=F64) -> torch.Tensor:
    """Uniform random rotations [n, 3, 3] (QR of a Gaussian matrix, determinant +1)."""
    q, r = torch.linalg.qr(torch.randn(n, 3, 3, generator=gen, dtype=F64))
    q = q * torch.sign(torch.diagonal(r, dim1=-2, dim2=-1))[:, None, :]
    q[torch.linalg.det(q) < 0, :, 0] *= -1
    return q.to(dtype)


def random_poses(n: int, gen: torch.Generator, dtype=F64, scale: float = 2.0) -> torch.Tensor:
    """Random rigid camera-to-world transforms [n, 4, 4]."""
    c2w = torch.eye(4, dtype=F64).repeat(n, 1, 1)
    c2w[:, :3, :3] = random_rotations(n, gen)
    c2w[:, :3, 3] = scale * torch.randn(n, 3, generator=gen, dtype=F64)
    return c2w.to(dtype)


def all_pixels(height: int, width: int, dtype=F64) -> tuple[torch.Tensor, torch.Tensor]:
    v, u = torch.meshgrid(
        torch.arange(height, dtype=dtype), torch.arange(width, dtype=dtype), indexing="ij"
    )
    return u, v


# --- conventions ------------------------------------------------------------------------------


def test_erp_directions_shape_dtype_unit_length():
    d = erp.erp_directions(H, W)
    assert d.shape == (H, W, 3) and d.dtype == torch.float32
    d64 = erp.erp_directions(H, W, dtype=F64)
    torch.testing.assert_close(torch.linalg.vector_norm(d64, dim=-1), torch.ones(H, W, dtype=F64))


def test_centre_column_looks_along_minus_z():
    # Column W/2 has its centre at lon = pi/W, column W/2 - 0.5 (between two pixels) at 0.
    d = erp.pixel_to_direction(
        torch.tensor(W / 2 - 0.5, dtype=F64), torch.tensor(H / 2 - 0.5, dtype=F64), H, W
    )
    torch.testing.assert_close(d, torch.tensor([0.0, 0.0, -1.0], dtype=F64))
    centre = erp.erp_directions(H, W, dtype=F64)[H // 2, W // 2]
    assert centre[2] < -0.95 and abs(centre[0]) < 0.2


def test_three_quarter_column_looks_along_plus_x():
    d = erp.pixel_to_direction(
        torch.tensor(0.75 * W - 0.5, dtype=F64), torch.tensor(H / 2 - 0.5, dtype=F64), H, W
    )
    torch.testing.assert_close(d, torch.tensor([1.0, 0.0, 0.0], dtype=F64))
    quarter = erp.pixel_to_direction(
        torch.tensor(0.25 * W - 0.5, dtype=F64), torch.tensor(H / 2 - 0.5, dtype=F64), H, W
    )
    torch.testing.assert_close(quarter, torch.tensor([-1.0, 0.0, 0.0], dtype=F64))
    # The pixel in column 3W/4 (just right of that edge) looks along +x to within a pixel.
    column = erp.erp_directions(H, W, dtype=F64)[H // 2, 3 * W // 4]
    assert column[0] > 0.98 and column[2] > 0 and abs(column[2]) < 2 * math.pi / W


def test_top_row_is_up_bottom_row_is_down():
    d = erp.erp_directions(H, W, dtype=F64)
    assert (d[0, :, 1] > 0.98).all()
    assert (d[-1, :, 1] < -0.98).all()
    # The top edge (v = -0.5) is exactly +y, the bottom edge (v = H - 0.5) exactly -y.
    up = erp.pixel_to_direction(torch.tensor(3.0, dtype=F64), torch.tensor(-0.5, dtype=F64), H, W)
    down = erp.pixel_to_direction(
        torch.tensor(3.0, dtype=F64), torch.tensor(H - 0.5, dtype=F64), H, W
    )
    torch.testing.assert_close(up, torch.tensor([0.0, 1.0, 0.0], dtype=F64))
    torch.testing.assert_close(down, torch.tensor([0.0, -1.0, 0.0], dtype=F64))


def test_left_and_right_edges_are_neighbours_across_the_seam():
    d = erp.erp_directions(H, W, dtype=F64)
    # The left edge of column 0 and the right edge of column W-1 are the same direction (+z).
    v = torch.arange(H, dtype=F64)
    left = erp.pixel_to_direction(torch.full_like(v, -0.5), v, H, W)
    right = erp.pixel_to_direction(torch.full_like(v, W - 0.5), v, H, W)
    torch.testing.assert_close(left, right)
    assert (left[:, 2] >= 0).all() and left[:, 0].abs().max() < 1e-12
    # Column 0 and column W-1 are as close as any two horizontally adjacent columns.
    across = (d[:, 0] * d[:, -1]).sum(-1)
    adjacent = (d[:, 0] * d[:, 1]).sum(-1)
    torch.testing.assert_close(across, adjacent)


def test_latitude_weights():
    w = erp.latitude_weights(H, W, dtype=F64)
    assert w.shape == (H, W)
    d = erp.erp_directions(H, W, dtype=F64)
    torch.testing.assert_close(w, torch.sqrt(d[..., 0] ** 2 + d[..., 2] ** 2))
    torch.testing.assert_close(w[0], w[-1])


# --- nerfstudio agreement ---------------------------------------------------------------------


def nerfstudio_equirect_directions(height: int, width: int) -> torch.Tensor:
    """Camera-frame ray directions of nerfstudio's EQUIRECTANGULAR camera, re-implemented.

    Formula from nerfstudio-project/nerfstudio, nerfstudio/cameras/cameras.py,
    `Cameras._generate_rays_from_coords`, EQUIRECTANGULAR branch:
        coord = ((x - cx) / fx, (y - cy) / fy); coord[..., 1] *= -1   (OpenCV -> OpenGL)
        theta = -pi * coord[..., 0]; phi = pi * (0.5 - coord[..., 1])
        d = (-sin(theta) sin(phi), cos(phi), -cos(theta) sin(phi))
    with the pixel coordinates of `Cameras.get_image_coords` (pixel_offset = 0.5, so centres at
    +0.5) and the intrinsics nerfstudio gives an equirectangular camera of size H x W
    (nerfstudio/cameras/camera_paths.py `get_path_from_json`): fx = W / 2, fy = H, cx = W / 2,
    cy = H / 2.
    """
    fx, fy, cx, cy = width / 2, float(height), width / 2, height / 2
    y, x = torch.meshgrid(
        torch.arange(height, dtype=F64) + 0.5, torch.arange(width, dtype=F64) + 0.5, indexing="ij"
    )
    c0 = (x - cx) / fx
    c1 = -((y - cy) / fy)
    theta = -math.pi * c0
    phi = math.pi * (0.5 - c1)
    return torch.stack(
        (-torch.sin(theta) * torch.sin(phi), torch.cos(phi), -torch.cos(theta) * torch.sin(phi)), -1
    )


@pytest.mark.parametrize(("height", "width"), [(16, 32), (7, 14), (64, 128)])
def test_matches_nerfstudio_equirectangular_camera(height, width):
    ours = erp.erp_directions(height, width, dtype=F64)
    torch.testing.assert_close(
        ours, nerfstudio_equirect_directions(height, width), atol=1e-12, rtol=0
    )


# --- round trips ------------------------------------------------------------------------------


def _wrapped_diff(a: torch.Tensor, b: torch.Tensor, period: float) -> torch.Tensor:
    return torch.remainder(a - b + period / 2, period) - period / 2


def test_pixel_direction_pixel_round_trip_all_pixels():
    u, v = all_pixels(H, W)
    uv = erp.direction_to_pixel(erp.pixel_to_direction(u, v, H, W), H, W)
    torch.testing.assert_close(uv[..., 0], u, atol=1e-9, rtol=0)
    torch.testing.assert_close(uv[..., 1], v, atol=1e-9, rtol=0)


def test_pixel_direction_pixel_round_trip_random_coords():
    gen = _gen(1)
    u = torch.rand(1000, generator=gen, dtype=F64) * W - 0.5
    v = torch.rand(1000, generator=gen, dtype=F64) * (H - 0.02) - 0.49  # away from the poles
    d = erp.pixel_to_direction(u, v, H, W)
    torch.testing.assert_close(torch.linalg.vector_norm(d, dim=-1), torch.ones_like(u))
    uv = erp.direction_to_pixel(d, H, W)
    # u = -0.5 and u = W - 0.5 are the same column edge: compare modulo W.
    assert _wrapped_diff(uv[..., 0], u, W).abs().max() < 1e-9
    torch.testing.assert_close(uv[..., 1], v, atol=1e-9, rtol=0)


def test_direction_pixel_direction_round_trip_any_length():
    gen = _gen(2)
    d = torch.randn(500, 3, generator=gen, dtype=F64)
    scale = torch.rand(500, 1, generator=gen, dtype=F64) * 10 + 0.01
    uv = erp.direction_to_pixel(d * scale, H, W)
    back = erp.pixel_to_direction(uv[..., 0], uv[..., 1], H, W)
    torch.testing.assert_close(back, d / torch.linalg.vector_norm(d, dim=-1, keepdim=True))
    assert (uv[..., 0] >= -0.5).all() and (uv[..., 0] <= W - 0.5).all()
    assert (uv[..., 1] >= -0.5).all() and (uv[..., 1] <= H - 0.5).all()


def test_lonlat_ranges_and_round_trip():
    gen = _gen(3)
    lon = (torch.rand(200, generator=gen, dtype=F64) * 2 - 1) * math.pi * 0.999
    lat = (torch.rand(200, generator=gen, dtype=F64) * 2 - 1) * math.pi / 2 * 0.999
    lon2, lat2 = erp.direction_to_lonlat(erp.lonlat_to_direction(lon, lat))
    torch.testing.assert_close(lon2, lon)
    torch.testing.assert_close(lat2, lat)


def test_poles_and_seam_are_finite_with_finite_gradients():
    d = torch.tensor(
        [
            [0.0, 1.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.0, 3.0, 0.0],
            [0.0, 0.0, 1.0],  # the seam (lon = pi)
            [0.0, 0.0, -1.0],
            [-0.0, 0.0, 1.0],
            [1e-30, 1.0, -1e-30],
            [1.0, 0.0, 0.0],
        ],
        requires_grad=True,
    )
    uv = erp.direction_to_pixel(d, H, W)
    assert torch.isfinite(uv).all()
    torch.testing.assert_close(uv[:3, 1], torch.tensor([-0.5, H - 0.5, -0.5]))
    torch.testing.assert_close(uv[3, 0], torch.tensor(W - 0.5))
    uv.sum().backward()
    assert torch.isfinite(d.grad).all()


# --- rigid transforms and projection ----------------------------------------------------------


def test_invert_rigid_matches_inverse_and_is_batched():
    c2w = random_poses(5, _gen(4))
    inv = erp.invert_rigid(c2w)
    assert inv.shape == (5, 4, 4)
    torch.testing.assert_close(inv, torch.linalg.inv(c2w))
    torch.testing.assert_close(inv @ c2w, torch.eye(4, dtype=F64).expand(5, 4, 4))
    torch.testing.assert_close(erp.invert_rigid(c2w[0]), torch.linalg.inv(c2w[0]))


def test_transform_points_batched():
    gen = _gen(5)
    c2w = random_poses(3, gen)
    pts = torch.randn(3, 7, 3, generator=gen, dtype=F64)
    homo = torch.cat((pts, torch.ones(3, 7, 1, dtype=F64)), -1)
    expected = (homo @ c2w.transpose(1, 2))[..., :3]
    torch.testing.assert_close(erp.transform_points(pts, c2w), expected)


def test_world_to_erp_depth_is_euclidean_distance():
    gen = _gen(6)
    c2w = random_poses(4, gen)
    pts = 3 * torch.randn(4, 50, 3, generator=gen, dtype=F64)
    uv, depth = erp.world_to_erp(pts, c2w, H, W)
    assert uv.shape == (4, 50, 2) and depth.shape == (4, 50)
    torch.testing.assert_close(depth, torch.linalg.vector_norm(pts - c2w[:, None, :3, 3], dim=-1))


def test_world_to_erp_identity_pose_uses_camera_directions():
    d = erp.erp_directions(H, W, dtype=F64).reshape(-1, 3)
    uv, depth = erp.world_to_erp(2.5 * d, torch.eye(4, dtype=F64), H, W)
    u, v = all_pixels(H, W)
    torch.testing.assert_close(uv, torch.stack((u, v), -1).reshape(-1, 2), atol=1e-9, rtol=0)
    torch.testing.assert_close(depth, torch.full_like(depth, 2.5))


def test_erp_to_world_world_to_erp_round_trip_random_poses():
    gen = _gen(7)
    views = 3
    c2w = random_poses(views, gen)
    depth = torch.rand(views, H, W, generator=gen, dtype=F64) * 9 + 0.5
    pts = erp.erp_to_world(depth, c2w)
    assert pts.shape == (views, H * W, 3)
    uv, dist = erp.world_to_erp(pts, c2w, H, W)
    u, v = all_pixels(H, W)
    torch.testing.assert_close(dist, depth.reshape(views, -1))
    torch.testing.assert_close(uv[..., 0], u.reshape(1, -1).expand(views, -1), atol=1e-9, rtol=0)
    torch.testing.assert_close(uv[..., 1], v.reshape(1, -1).expand(views, -1), atol=1e-9, rtol=0)
    # The lifted points sit at the pixel directions rotated into the world.
    dirs = erp.erp_directions(H, W, dtype=F64).reshape(-1, 3)
    expected = (dirs @ c2w[:, :3, :3].transpose(1, 2)) * depth.reshape(views, -1, 1)
    torch.testing.assert_close(pts, expected + c2w[:, None, :3, 3])


def test_world_to_erp_projects_into_another_camera():
    """A point lifted in camera A and projected into camera B lands where B's ray meets it."""
    gen = _gen(8)
    c2w = random_poses(2, gen)
    depth = torch.rand(1, H, W, generator=gen, dtype=F64) * 4 + 1
    pts = erp.erp_to_world(depth, c2w[:1])[0]
    uv_b, dist_b = erp.world_to_erp(pts, c2w[1], H, W)
    ray = erp.pixel_to_direction(uv_b[:, 0], uv_b[:, 1], H, W) @ c2w[1, :3, :3].T
    torch.testing.assert_close(c2w[1, :3, 3] + ray * dist_b[:, None], pts)


def test_rotation_about():
    half = math.pi / 2
    torch.testing.assert_close(
        erp.rotation_about("y", -half) @ torch.tensor([0.0, 0.0, -1.0], dtype=F64),
        torch.tensor([1.0, 0.0, 0.0], dtype=F64),
    )
    torch.testing.assert_close(
        erp.rotation_about("x", half) @ torch.tensor([0.0, 0.0, -1.0], dtype=F64),
        torch.tensor([0.0, 1.0, 0.0], dtype=F64),
    )
    for axis in "xyz":
        r = erp.rotation_about(axis, 0.3)
        torch.testing.assert_close(r @ r.T, torch.eye(3, dtype=F64))
        assert torch.linalg.det(r) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="axis"):
        erp.rotation_about("w", 0.1)


# --- sampling ---------------------------------------------------------------------------------


def _image(seed: int = 9, channels: int = 3, dtype=torch.float32) -> torch.Tensor:
    return torch.randn(2, channels, H, W, generator=_gen(seed), dtype=dtype)


@pytest.mark.parametrize(("dtype", "atol"), [(F64, 1e-12), (torch.float32, 1e-5)])
def test_sample_erp_exact_at_pixel_centres(dtype, atol):
    img = _image(dtype=dtype)
    u, v = all_pixels(H, W, dtype=dtype)
    uv = torch.stack((u, v), -1).reshape(1, -1, 2).expand(2, -1, -1)
    for mode in ("bilinear", "nearest"):
        out = erp.sample_erp(img, uv, mode=mode)
        assert out.shape == (2, 3, H * W) and out.dtype == dtype
        torch.testing.assert_close(out.reshape(img.shape), img, atol=atol, rtol=0)


def test_sample_erp_wraps_across_the_seam():
    img = _image(dtype=F64)
    v = torch.arange(H, dtype=F64)
    average = 0.5 * (img[..., 0] + img[..., -1])  # [B, C, H]
    for u0 in (-0.5, W - 0.5):
        uv = torch.stack((torch.full_like(v, u0), v), -1)[None].expand(2, -1, -1)
        torch.testing.assert_close(erp.sample_erp(img, uv), average, atol=1e-12, rtol=0)
    # A quarter of the way from the last column to the first, through the seam.
    uv = torch.stack((torch.full_like(v, W - 0.75), v), -1)[None].expand(2, -1, -1)
    expected = 0.75 * img[..., -1] + 0.25 * img[..., 0]
    torch.testing.assert_close(erp.sample_erp(img, uv), expected, atol=1e-12, rtol=0)


def test_sample_erp_is_periodic_in_u():
    gen = _gen(10)
    img = _image(dtype=F64)
    uv = torch.stack(
        (
            torch.rand(2, 300, generator=gen, dtype=F64) * W - 0.5,
            torch.rand(2, 300, generator=gen, dtype=F64) * H - 0.5,
        ),
        -1,
    )
    base = erp.sample_erp(img, uv)
    for shift in (W, -W, 3 * W, -5 * W):
        moved = uv + torch.tensor([shift, 0.0], dtype=F64)
        torch.testing.assert_close(erp.sample_erp(img, moved), base, atol=1e-10, rtol=0)
    # float32: the same up to rounding of the coordinates.
    moved = (uv + torch.tensor([W, 0.0], dtype=F64)).float()
    torch.testing.assert_close(erp.sample_erp(img.float(), moved), base.float(), atol=1e-4, rtol=0)


def test_sample_erp_clamps_at_the_poles_and_does_not_wrap_vertically():
    img = _image(dtype=F64)
    u = torch.arange(W, dtype=F64)
    for v0, row in ((-0.5, 0), (-3.0, 0), (H - 0.5, -1), (H + 2.0, -1)):
        uv = torch.stack((u, torch.full_like(u, v0)), -1)[None].expand(2, -1, -1)
        torch.testing.assert_close(erp.sample_erp(img, uv), img[:, :, row], atol=1e-12, rtol=0)
    # Half a pixel inside the top edge: a blend of rows 0 and 1 of the same column only.
    uv = torch.stack((u, torch.full_like(u, 0.5)), -1)[None].expand(2, -1, -1)
    expected = 0.5 * (img[:, :, 0] + img[:, :, 1])
    torch.testing.assert_close(erp.sample_erp(img, uv), expected, atol=1e-12, rtol=0)


def test_sample_erp_bilinear_between_pixels():
    img = _image()
    uv = torch.tensor([[[3.25, 5.5]]]).expand(2, -1, -1)
    top = 0.75 * img[..., 5, 3] + 0.25 * img[..., 5, 4]
    bottom = 0.75 * img[..., 6, 3] + 0.25 * img[..., 6, 4]
    torch.testing.assert_close(erp.sample_erp(img, uv)[..., 0], 0.5 * (top + bottom))


def test_bicubic_sampling_is_exact_at_pixel_centres_and_wraps_across_the_seam():
    img = _image(dtype=F64)
    padded = erp.pad_seam(img, 2)
    assert padded.shape[-1] == W + 4
    u, v = all_pixels(H, W, dtype=F64)
    uv = torch.stack((u, v), -1).reshape(1, -1, 2).expand(2, -1, -1)
    out = erp.sample_padded(padded, uv, "bicubic", pad=2)
    torch.testing.assert_close(out.reshape(img.shape), img, atol=1e-10, rtol=0)
    # Across the seam: the panorama rolled by half its width, sampled at the rolled position,
    # gives the same values (both reads use two real neighbours on each side).
    gen = _gen(11)
    uv = torch.stack(
        (
            torch.rand(2, 200, generator=gen, dtype=F64) * 3 - 1.5,  # around u = 0 (the seam)
            torch.rand(2, 200, generator=gen, dtype=F64) * (H - 5) + 2,
        ),
        -1,
    )
    rolled = torch.roll(img, W // 2, -1)
    moved = uv + torch.tensor([W // 2, 0.0], dtype=F64)
    torch.testing.assert_close(
        erp.sample_padded(padded, uv, "bicubic", pad=2),
        erp.sample_padded(erp.pad_seam(rolled, 2), moved, "bicubic", pad=2),
        atol=1e-10,
        rtol=0,
    )


def test_sample_erp_directions_any_direction_is_finite():
    img = _image()
    special = torch.tensor(
        [[0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1e-30, 1.0, 0.0]]
    )
    dirs = torch.cat((special, torch.randn(500, 3, generator=_gen(11))))[None].expand(2, -1, -1)
    out = erp.sample_erp_directions(img, dirs)
    assert out.shape == (2, 3, dirs.shape[1]) and torch.isfinite(out).all()
    # Along -z: between the two centre columns at the equator; along +z: across the seam.
    mid = 0.25 * img[..., H // 2 - 1 : H // 2 + 1, W // 2 - 1 : W // 2 + 1].sum((-1, -2))
    torch.testing.assert_close(out[..., 3], mid, atol=1e-5, rtol=0)
    seam = 0.25 * (
        img[..., H // 2 - 1 : H // 2 + 1, 0] + img[..., H // 2 - 1 : H // 2 + 1, -1]
    ).sum(-1)
    torch.testing.assert_close(out[..., 2], seam, atol=1e-5, rtol=0)


def test_sample_erp_directions_matches_pixel_directions():
    img = _image(dtype=F64)
    d = erp.erp_directions(H, W, dtype=F64).reshape(1, -1, 3).expand(2, -1, -1)
    out = erp.sample_erp_directions(img, d * 3.0)
    torch.testing.assert_close(out.reshape(img.shape), img)


def test_sample_erp_gradcheck():
    img = torch.randn(1, 2, 4, 8, generator=_gen(12), dtype=F64, requires_grad=True)
    uv = torch.tensor([[[-0.3, 1.2], [7.4, 2.6], [3.1, -0.2], [15.2, 0.7]]], dtype=F64)
    assert torch.autograd.gradcheck(lambda x: erp.sample_erp(x, uv), (img,))


def test_directions_are_made_once_per_size_and_stay_plain_tensors():
    a = erp.erp_directions(6, 12)
    assert erp.erp_directions(6, 12) is a
    assert erp.erp_directions(6, 12, dtype=torch.float64) is not a
    with torch.inference_mode():
        erp.erp_directions(7, 14)
    b = erp.erp_directions(7, 14)  # first made in inference mode, usable under autograd after
    depth = torch.ones(7, 14, 1, requires_grad=True)
    (b * depth).sum().backward()
    assert not b.is_inference() and depth.grad is not None
