"""The capture rig at the nadir: a per-source mask of the tripod, hand or selfie stick.

A real 360-degree capture sees whatever holds the camera straight below it, at the bottom of
every source panorama. Rendered as it is, every source paints its tripod onto the floor of the
novel view. This module finds that region per source (`nadir_masks`), or takes a cap the user
sets, and makes the sources forget it:

- the renderer gives a source's sample that falls in that source's mask no weight (it is
  treated as not visible, `mask_factor`), so another source fills it in;
- where every source is masked, the sources' own colours there were filled in first
  (`inpaint_masked`: from the surrounding floor, in a nadir-centred view), so the fill is
  floor, not tripod;
- the source's own depth in its mask comes from the floor plane fitted to the ring around it
  (`fill_floor_depth`), not from the tripod.

The detector works on a nadir-centred (azimuthal equidistant) view of the bottom cap, half a
degree per pixel: the floor is modelled as colour linear in floor coordinates, fitted on the
ring between `SEARCH_DEG` and `SEARCH_DEG + RING_DEG` from the nadir; the region connected to
the nadir whose colour is unlike that model (by `MIN_CONTRAST` or three times the ring's own
spread) is the rig. No such region at the nadir: nothing is masked. A region that fills most
of the search cap (the whole bottom is unlike the ring: the ring is no floor, or the capture
stands on a mat) is no answer: a cap of `FALLBACK_DEG` is masked instead. The mask is
widened by `MARGIN_DEG` (the rig's soft, stitched edge and its shadow).

Settings (`parse_nadir`): ``"auto"`` (detection), a number of degrees (a cap of that radius
from the nadir; 0: none), ``"off"`` / None (none). A scene folder may set it in its
transforms.json as ``"nadir_mask_deg"`` (a number or "auto"); a command's ``--nadir-cap``
overrides it (`nadir_setting`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

#: The detector looks for the rig within this many degrees of the nadir ...
SEARCH_DEG = 35.0
#: ... and models the floor on the ring this many degrees wide just outside it.
RING_DEG = 10.0
#: Smallest colour difference (RGB in [0, 1], Euclidean) from the floor model that counts as
#: "unlike the floor"; the ring's own spread (3 x its median residual) raises it.
MIN_CONTRAST = 0.12
#: The rig must cover this fraction of the disc within `CENTRE_DEG` of the nadir.
CENTRE_DEG, CENTRE_FRACTION = 3.0, 0.5
#: A region covering more than this fraction of the search cap is ambiguous: `FALLBACK_DEG`.
AMBIGUOUS_FRACTION = 0.6
#: The cap masked when detection is ambiguous (a tripod seen from 1.5 m reaches 10-20 deg).
FALLBACK_DEG = 20.0
#: The detected region is widened by this much (its soft edge, its shadow).
MARGIN_DEG = 2.0
#: The detector's nadir-centred view: degrees per pixel.
STEP_DEG = 0.5
#: transforms.json key of a scene's setting.
METADATA_KEY = "nadir_mask_deg"

NadirSetting = str | float | None


def parse_nadir(value: Any) -> NadirSetting:
    """A setting from a command line or transforms.json: None / "off" -> None, "auto" ->
    "auto", a number of degrees in [0, 90) -> that float (0 -> None). ValueError otherwise."""
    if value is None or isinstance(value, bool):
        if value is None:
            return None
        raise ValueError(f"nadir mask: expected 'auto', 'off' or degrees, got {value!r}")
    if isinstance(value, str):
        text = value.strip().lower()
        if text in ("off", "none", "no"):
            return None
        if text == "auto":
            return "auto"
        try:
            value = float(text)
        except ValueError:
            raise ValueError(
                f"nadir mask: expected 'auto', 'off' or degrees, got {value!r}"
            ) from None
    if not isinstance(value, int | float) or not math.isfinite(value) or not 0 <= value < 90:
        raise ValueError(f"nadir mask: degrees must be in [0, 90), got {value!r}")
    return float(value) or None


def nadir_setting(metadata: Mapping[str, Any] | None, cli: Any = None) -> NadirSetting:
    """The setting a command uses: its ``--nadir-cap`` value ``cli`` when given, else the
    scene's transforms.json ``"nadir_mask_deg"``, else "auto". Raises `UserError` naming the
    field for a bad value."""
    from panogrf.app.errors import UserError

    if cli is not None:
        try:
            return parse_nadir(cli)
        except ValueError as exc:
            raise UserError(f"--nadir-cap: {exc}") from None
    if metadata is not None and METADATA_KEY in metadata:
        try:
            return parse_nadir(metadata[METADATA_KEY])
        except ValueError as exc:
            raise UserError(f"transforms.json {METADATA_KEY!r}: {exc}") from None
    return "auto"


# --- the nadir-centred view ----------------------------------------------------------------


def _polar_grid(radius_deg: float, step_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Colatitude from the nadir (deg) and azimuth (rad) of the pixels of a nadir-centred
    view of ``radius_deg`` at ``step_deg`` per pixel: [N, N] each."""
    c = int(math.ceil(radius_deg / step_deg))
    x = (np.arange(2 * c + 1, dtype=np.float64) - c) * step_deg
    xx, yy = np.meshgrid(x, x)
    return np.hypot(xx, yy), np.arctan2(yy, xx)


def _erp_coords(
    rho_deg: np.ndarray, theta: np.ndarray, h: int, w: int
) -> tuple[np.ndarray, np.ndarray]:
    """ERP pixel coordinates (col, row; centres at integers) of the directions at colatitude
    ``rho_deg`` from the nadir and longitude ``theta`` (rad)."""
    lat = np.radians(rho_deg - 90.0)
    col = (theta / (2 * np.pi) + 0.5) * w - 0.5
    row = (0.5 - lat / np.pi) * h - 0.5
    return col.astype(np.float32), row.astype(np.float32)


def to_polar(
    erp: np.ndarray, radius_deg: float, step_deg: float, nearest: bool = False
) -> np.ndarray:
    """An ERP image [H, W, C] seen from the nadir: [N, N, C] (``radius_deg`` around it)."""
    import cv2

    h, w = erp.shape[:2]
    rho, theta = _polar_grid(radius_deg, step_deg)
    col, row = _erp_coords(rho, theta, h, w)
    padded = np.concatenate((erp[:, -2:], erp, erp[:, :2]), 1)  # the seam, wrapped
    mode = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
    out = cv2.remap(padded, col + 2, row, mode, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(*rho.shape, -1) if out.ndim == 2 else out


def _polar_pixels_of_erp(
    h: int, w: int, radius_deg: float, step_deg: float
) -> tuple[int, np.ndarray, np.ndarray]:
    """For the ERP rows within ``radius_deg`` of the nadir: (first such row, the polar view's
    (x, y) pixel coordinates of those rows' pixels [rows, W] each)."""
    rows = np.arange(h)
    lat = np.degrees(np.pi * (0.5 - (rows + 0.5) / h))
    first = int(np.searchsorted(-(lat + 90.0), -radius_deg, side="left"))
    first = min(first, h - 1)
    lon = 2 * np.pi * ((np.arange(w) + 0.5) / w - 0.5)
    rho = (lat[first:] + 90.0)[:, None]
    c = math.ceil(radius_deg / step_deg)
    x = c + rho * np.cos(lon)[None] / step_deg
    y = c + rho * np.sin(lon)[None] / step_deg
    return first, x.astype(np.float32), y.astype(np.float32)


def from_polar(polar: np.ndarray, h: int, w: int, radius_deg: float, step_deg: float) -> np.ndarray:
    """A nadir-centred view [N, N] (float) back on the bottom rows of an H x W ERP: [H, W]
    (0 above ``radius_deg``)."""
    import cv2

    out = np.zeros((h, w), np.float32)
    first, x, y = _polar_pixels_of_erp(h, w, radius_deg, step_deg)
    out[first:] = cv2.remap(
        polar.astype(np.float32), x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT
    )
    rho = np.degrees(np.pi * ((np.arange(h) + 0.5) / h))  # colatitude from the zenith
    out[180.0 - rho > radius_deg] = 0.0
    return out


# --- detection -----------------------------------------------------------------------------


def cap_mask(
    height: int, width: int, degrees: float, device: torch.device | str | None = None
) -> Tensor:
    """[1, H, W] bool: the ERP pixels within ``degrees`` of the nadir."""
    lat = 90.0 - 180.0 * (torch.arange(height, dtype=torch.float64, device=device) + 0.5) / height
    return (lat < degrees - 90.0).view(1, height, 1).expand(1, height, width).clone()


def _floor_model(
    polar: np.ndarray, rho: np.ndarray, theta: np.ndarray, ring: np.ndarray
) -> tuple[np.ndarray, float]:
    """Colour linear in floor coordinates (tan(rho) cos, sin), fitted on ``ring`` (twice, the
    second time without the first fit's outliers): the model's colours [N, N, 3] and the
    ring's spread (median residual)."""
    t = np.tan(np.radians(np.minimum(rho, 80.0)))
    design = np.stack((np.ones_like(t), t * np.cos(theta), t * np.sin(theta)), -1)
    a, b = design[ring], polar[ring]
    keep = np.ones(len(a), bool)
    for _ in range(2):
        coef, *_ = np.linalg.lstsq(a[keep], b[keep], rcond=None)
        res = np.linalg.norm(a @ coef - b, axis=-1)
        spread = float(np.median(res[keep]))
        keep = res <= max(2.5 * spread, 1e-3)
    return design @ coef, spread


def detect_nadir(image: Tensor | np.ndarray) -> tuple[Tensor, str, float]:
    """The rig at the nadir of one panorama [3, H, W] (RGB in [0, 1]): (mask [1, H, W] bool,
    how it was found: "none", "detected" or "fallback", its largest radius in degrees)."""
    import cv2

    rgb = image.detach().cpu().float().numpy() if isinstance(image, Tensor) else image
    rgb = np.ascontiguousarray(np.transpose(rgb, (1, 2, 0)), np.float32)
    h, w = rgb.shape[:2]
    outer = SEARCH_DEG + RING_DEG
    rows = int(round(180.0 / STEP_DEG))
    small = cv2.resize(rgb, (2 * rows, rows), interpolation=cv2.INTER_AREA) if h > rows else rgb
    polar = to_polar(small, outer, STEP_DEG)  # (from at most STEP_DEG per row: no aliasing)
    polar = cv2.GaussianBlur(polar, (5, 5), 1.0)  # texture and noise, not the rig's edge
    rho, theta = _polar_grid(outer, STEP_DEG)
    ring = rho >= SEARCH_DEG
    model, spread = _floor_model(polar, rho, theta, ring)
    unlike = (np.linalg.norm(polar - model, axis=-1) > max(MIN_CONTRAST, 3.0 * spread)) & ~ring
    centre = rho <= CENTRE_DEG
    if unlike[centre].mean() < CENTRE_FRACTION:
        return torch.zeros(1, h, w, dtype=torch.bool, device="cpu"), "none", 0.0
    _, labels = cv2.connectedComponents(unlike.astype(np.uint8), connectivity=8)
    ids, counts = np.unique(labels[centre & unlike], return_counts=True)
    region = labels == ids[np.argmax(counts)]
    if region.sum() > AMBIGUOUS_FRACTION * (rho < SEARCH_DEG).sum():
        return cap_mask(h, w, FALLBACK_DEG, "cpu"), "fallback", FALLBACK_DEG
    # Holes (floor seen between a tripod's legs stays; specks inside the rig do not) and the
    # margin, in the nadir-centred view where the rig is a compact shape.
    k = 2 * int(round(MARGIN_DEG / STEP_DEG)) + 1
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    grown = cv2.morphologyEx(region.astype(np.uint8), cv2.MORPH_CLOSE, kernel)
    grown = cv2.dilate(grown, kernel)
    radius = float(rho[grown > 0].max()) + STEP_DEG
    erp = from_polar(grown.astype(np.float32), h, w, outer, STEP_DEG) > 0.25
    erp |= cap_mask(h, w, 180.0 / h, "cpu")[0].numpy()  # the bottom row: the nadir itself
    return torch.from_numpy(erp)[None], "detected", radius


def nadir_masks(images: Tensor, setting: NadirSetting) -> tuple[Tensor | None, list[str]]:
    """Per-source masks [V, 1, H, W] bool of sources [V, 3, H, W] for a `parse_nadir` setting
    (None: no masking), and how each was found ("cap 15", "detected 12.5 deg", "none",
    "fallback 20")."""
    v, _, h, w = images.shape
    if setting is None:
        return None, ["off"] * v
    if setting != "auto":
        deg = float(setting)
        mask = cap_mask(h, w, deg, images.device)[None].expand(v, 1, h, w).clone()
        return mask, [f"cap {deg:g}"] * v
    masks, notes = [], []
    for img in images:
        m, how, radius = detect_nadir(img)
        masks.append(m)
        notes.append(how if how == "none" else f"{how} {radius:.1f} deg")
    return torch.stack(masks).to(images.device), notes


# --- making the sources forget the rig -----------------------------------------------------


def inpaint_masked(images: Tensor, masks: Tensor) -> Tensor:
    """Sources [V, 3, H, W] in [0, 1] with each one's masked pixels ([V, 1, H, W]) filled from
    the surrounding ones (OpenCV's Telea inpainting in a nadir-centred view at the panorama's
    own angular resolution, where the cap is a disc and not the ERP's stretched rows)."""
    import cv2

    out = images.clone()
    h, w = images.shape[-2:]
    step = 180.0 / h
    for i in range(images.shape[0]):
        m = masks[i, 0].cpu().numpy()
        if not m.any():
            continue
        rows = np.nonzero(m.any(1))[0]
        radius = 180.0 * (h - rows[0]) / h + 3 * step  # the mask's reach, and a ring
        rgb = images[i].permute(1, 2, 0).cpu().numpy()
        pol = to_polar(np.ascontiguousarray((rgb * 255).round().astype(np.uint8)), radius, step)
        pm = to_polar(np.ascontiguousarray(m.astype(np.uint8)), radius, step, nearest=True)
        pm = cv2.dilate(pm[..., 0] if pm.ndim == 3 else pm, np.ones((3, 3), np.uint8))
        filled = cv2.inpaint(pol, pm, 3, cv2.INPAINT_TELEA).astype(np.float32) / 255.0
        back = np.stack([from_polar(filled[..., c], h, w, radius, step) for c in range(3)])
        sel = torch.from_numpy(m).to(out.device)
        out[i][:, sel] = torch.from_numpy(back).to(out)[:, sel]
    return out


def fill_floor_depth(depth: Tensor, masks: Tensor, ring_deg: float = 8.0) -> Tensor:
    """Depth [V, 1, h, w] (metres, camera frame spherical) with each source's masked pixels
    (``masks`` [V, 1, H, W], any resolution) at the floor plane fitted (least squares, the
    depth points of the ring ``ring_deg`` wide around the mask, below the horizon). A source
    whose ring is no floor (too few points, a plane not facing up) keeps its depth."""
    from panogrf.model.erp import erp_directions

    v, _, h, w = depth.shape
    small = F.interpolate(masks.float(), size=(h, w), mode="area") > 0  # any overlap
    dirs = erp_directions(h, w, device=depth.device, dtype=torch.float64).reshape(-1, 3)
    lat = 90.0 - 180.0 * (torch.arange(h, dtype=torch.float64, device=depth.device) + 0.5) / h
    out = depth.clone()
    for i in range(v):
        m = small[i, 0]
        if not m.any():
            continue
        reach = float((lat[m.any(1)] + 90.0).max())  # colatitude of the mask's top row
        band = ((lat + 90.0) > reach) & ((lat + 90.0) <= reach + ring_deg) & (lat < -10.0)
        ring = band.view(h, 1).expand(h, w).reshape(-1)
        d = depth[i, 0].reshape(-1).double()
        ok = ring & (d > 0) & torch.isfinite(d)
        if ok.sum() < 16:
            continue
        pts = dirs[ok] * d[ok, None]
        a = torch.linalg.lstsq(pts, torch.ones_like(pts[:, :1])).solution[:, 0]
        normal = a / torch.linalg.vector_norm(a).clamp(min=1e-12)
        if float(normal[1]) > -math.cos(math.radians(30.0)):  # the plane must be below, level
            continue
        denom = dirs @ a  # 1 / depth along each direction on the plane
        sel = m.reshape(-1) & (denom > 1e-6)
        flat = out[i, 0].reshape(-1)
        flat[sel] = (1.0 / denom[sel]).to(out.dtype)
        out[i, 0] = flat.view(h, w)
    return out


def mask_factor(masked: Tensor) -> Tensor:
    """Weight factors [V, ...] for sources' samples whose masked fraction is ``masked`` [V,
    ...] (in [0, 1]): 1 - (max over views of the unmasked fraction - this view's). A masked
    sample gets 0 where another source sees the point unmasked; where every source is masked,
    all keep their weight (their colours there were inpainted)."""
    free = 1.0 - masked.clamp(0, 1)
    return 1.0 - (free.amax(0, keepdim=True) - free)
