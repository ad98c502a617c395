"""`panogrf compare A.png B.png [--json]`: PSNR, WS-PSNR, SSIM and LPIPS of two images.

The options are declared once, on the fields of `CompareConfig` (`panogrf.app.options`).
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from panogrf.app.errors import UserError
from panogrf.app.files.images import ImageReadError, read_pixels
from panogrf.app.options import add_options, from_args, option
from panogrf.app.runtime import resolve_device
from panogrf.model.lpips import MIN_SIZE as LPIPS_MIN_SIZE
from panogrf.model.metrics import psnr, ssim, ws_psnr

_DESCRIPTION = """\
Compare two images of the same size with the metrics of the evaluation protocol:
PSNR, WS-PSNR (cos-latitude weighted, for 2:1 equirectangular panoramas), SSIM (Gaussian
11x11 window) and LPIPS (AlexNet v0.1, bundled pretrained weights). Higher is better for
PSNR, WS-PSNR and SSIM; lower is better for LPIPS.

8-bit and 16-bit PNG/JPEG/TIFF/... images, grayscale, RGB or RGBA, are converted to RGB in
[0, 1]; an alpha channel is dropped (and reported). WS-PSNR is reported as null/n.a. for
images that are not 2:1.
"""


@dataclass(frozen=True)
class LoadedImage:
    """An image file as float RGB plus what was done to it."""

    rgb: np.ndarray
    """[H, W, 3] float32 in [0, 1]."""
    description: str
    """e.g. '1024x512, 16-bit RGBA'."""
    notes: tuple[str, ...]
    """Conversions worth telling the user about."""
    path: Path | None = None
    """The file it was read from."""


@dataclass(frozen=True)
class CompareConfig:
    """What `panogrf compare` compares and how it reports. A field made with `option` is also
    an option of the command; the device is checked as it is built (`UserError`, one line)."""

    a: Path = option(help="first image (e.g. the rendering)", positional=True, metavar="A")
    """The first image."""
    b: Path = option(help="second image (e.g. the ground truth)", positional=True, metavar="B")
    """The second image."""
    json: bool = option(False, "print one JSON object instead")
    """Print one JSON object instead of lines of text."""
    device: str = option("cpu", "device for LPIPS: auto, cpu, cuda or cuda:N (default: cpu)")
    """The torch device LPIPS runs on."""

    def __post_init__(self) -> None:
        """Refuse a device torch does not know or cannot use here (`torch_device`)."""
        self.torch_device()

    def torch_device(self) -> str:
        """The device LPIPS runs on, if this tool can use it here (as every command's
        ``--device``: `panogrf.app.runtime.resolve_device`); `UserError` otherwise."""
        return str(resolve_device(self.device))


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "compare",
        help="PSNR, WS-PSNR, SSIM and LPIPS of two images",
        description=_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_options(parser, CompareConfig)
    parser.set_defaults(func=run)


def load_image(path: Path) -> LoadedImage:
    """Read an image with OpenCV as RGB float32 in [0, 1]; UserError if that is not possible."""
    try:
        raw = read_pixels(path)  # names a folder, a missing file, a truncated JPEG, ...
    except ImageReadError as exc:
        raise UserError(f"{path}: {exc.reason}") from None
    if raw.dtype == np.uint8:
        depth, scale = "8-bit", 255.0
    elif raw.dtype == np.uint16:
        depth, scale = "16-bit", 65535.0
    else:
        raise UserError(f"{path}: expected an 8-bit or 16-bit image, got pixel type {raw.dtype}")

    if raw.ndim == 3 and raw.shape[2] == 1:
        raw = raw[:, :, 0]
    notes = []
    if raw.ndim == 2:
        kind, rgb = "gray", cv2.cvtColor(raw, cv2.COLOR_GRAY2RGB)
    elif raw.shape[2] == 3:
        kind, rgb = "RGB", cv2.cvtColor(raw, cv2.COLOR_BGR2RGB)
    elif raw.shape[2] == 4:
        kind, rgb = "RGBA", cv2.cvtColor(raw, cv2.COLOR_BGRA2RGB)
        notes.append(f"{path.name}: alpha channel dropped (colours compared as stored)")
    else:
        raise UserError(f"{path}: expected 1, 3 or 4 channels, got {raw.shape[2]}")
    h, w = rgb.shape[:2]
    return LoadedImage(
        rgb=rgb.astype(np.float32) / scale,
        description=f"{w}x{h}, {depth} {kind}",
        notes=tuple(notes),
        path=path,
    )


def _lpips(x: torch.Tensor, y: torch.Tensor, device: str) -> float:
    from panogrf.app.weights.lpips import load_lpips

    try:
        net = load_lpips(device)
    except FileNotFoundError as exc:
        raise UserError(str(exc)) from exc
    with torch.no_grad():
        return float(net(x.to(device), y.to(device)))


def compare(a: LoadedImage, b: LoadedImage, device: str = "cpu") -> dict:
    """Metrics of two loaded images of equal size.

    Returns {"width", "height", "psnr", "ws_psnr", "ssim", "lpips", "notes"}; a metric is None
    where it is undefined for these images (said in a note), PSNRs are inf for equal images.
    """
    if a.rgb.shape != b.rgb.shape:
        (ha, wa), (hb, wb) = a.rgb.shape[:2], b.rgb.shape[:2]
        name_a, name_b = a.path or "the first", b.path or "the second"
        raise UserError(f"images differ in size: {name_a} is {wa}x{ha}, {name_b} is {wb}x{hb}")
    h, w = a.rgb.shape[:2]
    x = torch.from_numpy(a.rgb).permute(2, 0, 1)  # [3, H, W]
    y = torch.from_numpy(b.rgb).permute(2, 0, 1)
    notes = [*a.notes, *b.notes]

    values: dict[str, float | None] = {"psnr": float(psnr(x, y))}
    if w == 2 * h:
        values["ws_psnr"] = float(ws_psnr(x, y))
    else:
        values["ws_psnr"] = None
        notes.append(f"WS-PSNR needs a 2:1 equirectangular image, these are {w}x{h}")
    if min(h, w) >= 11:
        values["ssim"] = float(ssim(x, y))
    else:
        values["ssim"] = None
        notes.append(f"SSIM needs at least 11x11 pixels, these are {w}x{h}")
    if min(h, w) >= LPIPS_MIN_SIZE:
        values["lpips"] = _lpips(x, y, device)
    else:
        values["lpips"] = None
        notes.append(f"LPIPS needs at least {LPIPS_MIN_SIZE}x{LPIPS_MIN_SIZE} pixels")
    if math.isinf(values["psnr"]):
        which = "PSNR and WS-PSNR are" if values["ws_psnr"] is not None else "PSNR is"
        notes.append(f"the images are identical: {which} infinite")
    return {"width": w, "height": h, **values, "notes": notes}


def _format_text(path_a: Path, path_b: Path, a: LoadedImage, b: LoadedImage, result: dict) -> str:
    def show(key: str, fmt: str, unit: str = "") -> str:
        value = result[key]
        return "n/a" if value is None else format(value, fmt) + unit  # inf prints as "inf"

    lines = [
        f"A        {path_a} ({a.description})",
        f"B        {path_b} ({b.description})",
        f"PSNR     {show('psnr', '.2f', ' dB')}",
        f"WS-PSNR  {show('ws_psnr', '.2f', ' dB')}",
        f"SSIM     {show('ssim', '.4f')}",
        f"LPIPS    {show('lpips', '.4f')}  (AlexNet v0.1, lower is closer)",
    ]
    lines += [f"note: {n}" for n in result["notes"]]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    cfg = from_args(CompareConfig, args)
    a, b = load_image(cfg.a), load_image(cfg.b)
    result = compare(a, b, device=cfg.torch_device())
    if cfg.json:
        # JSON has no inf: infinite PSNRs become null, and the notes say why.
        finite = {
            k: None if isinstance(v, float) and not math.isfinite(v) else v
            for k, v in result.items()
        }
        print(json.dumps({"a": str(cfg.a), "b": str(cfg.b), **finite}, allow_nan=False))
    else:
        print(_format_text(cfg.a, cfg.b, a, b, result))
    return 0
