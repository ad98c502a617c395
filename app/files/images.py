"""Reading and writing panoramas and depth maps on disk, with atomic writes.

- Colour images come back as RGB ``uint8`` ``[H, W, 3]``. Grayscale, opaque RGBA and 16-bit
  files are converted (the conversion is reported as a note); a non-opaque alpha channel is
  refused, since a transparent panorama is not a photograph of a place.
- Depth maps are single-channel 16-bit PNGs holding spherical depth (distance from the camera
  centre) in millimetres; 0 means unknown. In memory they are ``float32`` metres, 0.0 unknown.
- Every write goes through `panogrf.app.files.atomic` (a temporary beside the destination, then a
  rename), so a reader never sees a half-written file.
"""

from __future__ import annotations

import io
import os
import re
import sys
import tempfile
import threading
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import torch

from panogrf.app.errors import UserError
from panogrf.app.files.atomic import write_bytes_atomic, write_json_atomic  # noqa: F401 (re-exported)

# Every image that cannot be read is reported once, by the caller, naming the file: OpenCV's
# own warnings (a timestamped "[ WARN:0@0.61] ..." per corrupt file) would be a second, unnamed
# report.
cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)

#: Largest depth a 16-bit millimetre PNG can hold, in metres.
MAX_DEPTH_M = 65.535


class ImageReadError(UserError):
    """An image or depth file that cannot be used; ``reason`` says why without the path."""

    def __init__(self, path: str | os.PathLike[str], reason: str) -> None:
        self.path = Path(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")


def read_pixels(path: Path) -> np.ndarray:
    """Decode any image file unchanged (channels, bit depth); errors name the file."""
    if not path.exists():
        raise ImageReadError(path, "file not found")
    if not path.is_file():
        raise ImageReadError(path, "not a file")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ImageReadError(path, f"cannot read: {exc.strerror or exc}") from None
    if not data:
        raise ImageReadError(path, "empty file (0 bytes)")
    if problem := _header_problem(data):
        raise ImageReadError(path, problem)
    # libjpeg decodes a truncated file with a warning only, its lost part flat grey.
    if data[:2] == b"\xff\xd8" and _jpeg_truncated(data):
        if data.rstrip(b"\x00").endswith(b"\xff\xd9"):  # all there, but not well formed
            raise ImageReadError(path, "corrupt JPEG (its data is damaged)")
        raise ImageReadError(path, "truncated JPEG (the file ends before the image does)")
    with _libpng_lines() as said:  # its own lines, naming no file: said here once, named
        try:
            pixels = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        except cv2.error:  # OpenCV asserts on some inputs instead of returning None
            pixels = None
    if pixels is None:
        png = data[:8] == b"\x89PNG\r\n\x1a\n"  # libpng's lines are about this file only then
        errors = [x.removeprefix("libpng error: ") for x in said if x.startswith("libpng error")]
        errors = errors if png else []
        if errors:
            raise ImageReadError(path, f"corrupt PNG ({errors[0]})")
        raise ImageReadError(path, "not a readable image (unknown format or corrupt file)")
    return pixels


class _Capture:
    """The process's stderr taken into a temporary file while any thread decodes (`_libpng_lines`):
    the first to come redirects it, the last to leave puts it back and passes on all that was
    not libpng's. libpng's lines go to the block that was alone while they were printed;
    where blocks overlapped (threads decoding side by side) nobody can tell whose they are and
    they are dropped (the caller names the file that failed anyway)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.inside = 0
        self.shared = False
        self.saved = -1
        self.file: io.BufferedRandom | None = None

    def enter(self) -> bool:
        """Whether stderr is being caught now (False: it could not be, decode as it is)."""
        with self.lock:
            if self.inside:
                self.inside += 1
                self.shared = True
                return True
            try:
                if sys.stderr is not None:
                    sys.stderr.flush()
                caught = tempfile.TemporaryFile()
            except OSError:  # no temporary folder, a full disk under stderr: not caught
                return False
            try:
                saved = os.dup(2)
            except OSError:
                caught.close()
                return False
            os.dup2(caught.fileno(), 2)
            self.file, self.saved, self.inside = caught, saved, 1
            return True

    def leave(self, said: list[str]) -> None:
        with self.lock:
            if self.inside > 1:
                self.inside -= 1
                return
            os.dup2(self.saved, 2)  # put back first: nothing after it is lost
            os.close(self.saved)
            self.inside = 0
            caught, shared, self.shared = self.file, self.shared, False
            self.file = None
            assert caught is not None
            with caught:
                caught.seek(0)
                kept, lines = _split_libpng(caught.read())
            _write_all(2, kept)  # under the lock: before anything printed after it
        if not shared:
            said.extend(lines)


def _write_all(fd: int, data: bytes) -> None:
    """``data`` to ``fd``, all of it; a stderr that cannot take it loses it, not the decode."""
    try:
        while data:
            data = data[os.write(fd, data) :]
    except OSError:
        pass


def _split_libpng(text: bytes) -> tuple[bytes, list[str]]:
    """(``text`` without libpng's lines, those lines); a line of libpng's may follow a progress
    bar's carriage return on the same line."""
    kept, lines = [], []
    for part in text.split(b"\n"):
        at = part.find(b"libpng ")
        if at >= 0:
            lines.append(part[at:].decode(errors="replace"))
            part = part[:at]
            if not part:
                continue
        kept.append(part)
    return b"\n".join(kept), lines


_CAPTURE = _Capture()


@contextmanager
def _libpng_lines() -> Iterator[list[str]]:
    """The lines libpng prints on the process's stderr while the block decodes (a warning for
    harmless extra data, an error before OpenCV gives up), off stderr and in the list once the
    block ends (`_Capture`)."""
    said: list[str] = []
    if not _CAPTURE.enter():
        yield said
        return
    try:
        yield said
    finally:
        _CAPTURE.leave(said)


def turned_note(path: Path) -> str:
    """`` (...)`` where the file's EXIF orientation tag turns it by 90 degrees (viewers show
    it turned; its pixels are stored as they are and read so), else ``""``."""
    try:
        from PIL import Image

        with Image.open(path) as img:
            tag = img.getexif().get(0x0112)
    except Exception:  # noqa: BLE001 - no tag to tell of
        return ""
    if tag not in (5, 6, 7, 8):
        return ""
    return " (its EXIF orientation tag turns it by 90 degrees for viewers: save it turned)"


#: Largest image decoded (a 16K panorama): a header can declare a size its few compressed
#: bytes expand to (a 40000x20000 PNG of 2 MB took 30 s and 5 GB to decode).
MAX_SIDE = 16384
MAX_PIXELS = MAX_SIDE * MAX_SIDE // 2


def _header_problem(data: bytes) -> str | None:
    """What Pillow finds wrong with an image before anything is decoded: a size over
    `MAX_PIXELS`, or a PNG whose chunks are cut short or fail their checksums (libpng would
    print a line of its own, naming no file, before OpenCV gives up). None where Pillow finds
    nothing or cannot read the format (OpenCV then decides)."""
    from PIL import Image

    too_large = (
        f"too large: more than {MAX_PIXELS // 1_000_000} million pixels "
        f"({MAX_SIDE}x{MAX_SIDE // 2} at most); resize it first"
    )
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # Pillow's own warning over 89 million pixels
            with Image.open(io.BytesIO(data)) as im:
                width, height = im.size
                if width * height > MAX_PIXELS:
                    return too_large
                if im.format == "PNG":
                    im.verify()  # every chunk there and its CRC right; decodes nothing
    except Image.DecompressionBombError:  # over twice Pillow's limit: 179 million pixels
        return too_large
    except Exception as exc:  # noqa: BLE001 (any format Pillow does not read: OpenCV's to judge)
        if data[:8] == b"\x89PNG\r\n\x1a\n":
            return f"corrupt or truncated PNG ({exc})"
    return None


# A marker inside entropy-coded data: 0xFF not followed by a stuffed 0x00, a restart marker
# (0xD0-0xD7, part of the data) or another fill byte.
_JPEG_MARKER = re.compile(rb"\xff[^\x00\xd0-\xd7\xff]")


def _jpeg_truncated(data: bytes) -> bool:
    """True when a JPEG stream ends before its end-of-image marker (walks the segments, so an
    EXIF thumbnail's own end marker does not count)."""
    pos, n = 2, len(data)
    while pos + 2 <= n:
        if data[pos] != 0xFF:
            return True  # lost sync: not a well-formed stream
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker == 0xD9:
            return False
        if 0xD0 <= marker <= 0xD7 or marker == 0x01:
            pos += 2
            continue
        if pos + 4 > n:
            return True
        pos += 2 + int.from_bytes(data[pos + 2 : pos + 4], "big")
        if marker == 0xDA:  # start of scan: entropy-coded data up to the next marker
            found = _JPEG_MARKER.search(data, pos)
            if found is None:
                return True
            pos = found.start()
    return True


def _channels(pixels: np.ndarray) -> int:
    return 1 if pixels.ndim == 2 else pixels.shape[2]


def read_rgb_with_notes(path: str | os.PathLike[str]) -> tuple[np.ndarray, list[str]]:
    """Read a colour image as RGB ``uint8`` ``[H, W, 3]``, and notes on any conversion made.

    Accepts 8- or 16-bit gray, gray+alpha, BGR and BGRA files. 16-bit values are mapped to 8
    bits with rounding (65535 -> 255). Raises `ImageReadError` for a missing or unreadable file,
    another pixel type, or an alpha channel that is not fully opaque.
    """
    path = Path(path)
    pixels = read_pixels(path)
    notes: list[str] = []
    if pixels.dtype == np.uint16:
        full = 65535
    elif pixels.dtype == np.uint8:
        full = 255
    else:
        raise ImageReadError(path, f"unsupported pixel type {pixels.dtype}; expected 8 or 16 bit")
    channels = _channels(pixels)
    if channels not in (1, 2, 3, 4):
        raise ImageReadError(path, f"unsupported image with {channels} channels")
    if channels in (2, 4):
        alpha = pixels[..., -1]
        if (alpha != full).any():
            share = float((alpha != full).mean())
            raise ImageReadError(
                path,
                f"alpha channel is not fully opaque ({share:.1%} of pixels are transparent); "
                "a panorama must be an opaque photo: flatten it onto a background first",
            )
        pixels = pixels[..., :-1]
        notes.append("opaque alpha channel dropped")
    if pixels.ndim == 3 and pixels.shape[2] == 1:
        pixels = pixels[..., 0]
    if pixels.ndim == 2:
        pixels = np.repeat(pixels[..., None], 3, axis=2)
        notes.append("grayscale converted to RGB")
    else:
        pixels = pixels[..., ::-1]  # OpenCV decodes to BGR order
    if full == 65535:
        pixels = np.round(pixels.astype(np.float32) * (255.0 / 65535.0)).astype(np.uint8)
        notes.append("16-bit converted to 8-bit")
    if (turn := _orientation(path)) is not None:
        notes.append(f"its EXIF orientation (viewers show it {turn}) is not applied")
    return np.ascontiguousarray(pixels, dtype=np.uint8), notes


#: EXIF orientation tag -> how a viewer shows the stored pixels.
_TURNS = {2: "mirrored", 3: "turned 180 degrees", 4: "upside down", 5: "turned 90 degrees",
          6: "turned 90 degrees", 7: "turned 90 degrees", 8: "turned 90 degrees"}  # fmt: skip


def _orientation(path: Path) -> str | None:
    """How the file's EXIF orientation tag turns it for viewers (a JPEG, TIFF or WebP), or
    None where it has none or the identity."""
    if path.suffix.lower() not in (".jpg", ".jpeg", ".tif", ".tiff", ".webp"):
        return None
    try:
        from PIL import Image

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # Pillow's own warning over 89 million pixels
            with Image.open(path) as img:
                tag = img.getexif().get(0x0112)
    except Exception:  # noqa: BLE001 - no tag to tell of
        return None
    return _TURNS.get(tag)


def read_rgb(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a colour image as RGB ``uint8`` ``[H, W, 3]`` (see `read_rgb_with_notes`)."""
    return read_rgb_with_notes(path)[0]


def _encode(path: Path, pixels: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(path.suffix or ".png", pixels)
    if not ok:
        raise ValueError(f"{path}: OpenCV cannot encode an image with suffix {path.suffix!r}")
    return buf.tobytes()


def write_rgb(path: str | os.PathLike[str], img: np.ndarray) -> None:
    """Write an RGB image atomically; the format follows the suffix (``.png`` is lossless).

    img: ``[H, W, 3]`` ``uint8``, or floating point in [0, 1] (rounded to 8 bits, clipped).
    """
    path = Path(path)
    img = np.asarray(img)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"{path}: expected an RGB image [H, W, 3], got shape {img.shape}")
    if np.issubdtype(img.dtype, np.floating):
        img = np.round(np.clip(img, 0.0, 1.0) * 255.0).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise ValueError(f"{path}: expected uint8 or float pixels, got {img.dtype}")
    write_bytes_atomic(path, _encode(path, np.ascontiguousarray(img[..., ::-1])))


def to_uint8(images: torch.Tensor) -> np.ndarray:
    """Colours in [0, 1], channels first ([3, H, W] or [V, 3, H, W]) -> uint8, channels last."""
    moved = images.detach().cpu().clamp(0, 1).movedim(-3, -1).numpy()
    return (moved * 255.0 + 0.5).astype(np.uint8)


def read_depth(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a spherical depth map: 16-bit single-channel PNG in mm -> ``float32 [H, W]`` metres.

    0 stays 0.0 (unknown). Raises `ImageReadError` for any other kind of file, so an 8-bit
    visualisation or a colour image is never mistaken for depth.
    """
    path = Path(path)
    pixels = read_pixels(path)
    if pixels.dtype != np.uint16 or pixels.ndim != 2:
        raise ImageReadError(
            path,
            f"expected a single-channel 16-bit PNG (depth in millimetres), got "
            f"{_channels(pixels)}-channel {pixels.dtype}",
        )
    return pixels.astype(np.float32) / np.float32(1000.0)


def write_depth(path: str | os.PathLike[str], depth_m: np.ndarray) -> None:
    """Write spherical depth ``[H, W]`` in metres as a 16-bit PNG in millimetres, atomically.

    Values are rounded to the millimetre and clipped to 65535 mm (`MAX_DEPTH_M`); non-finite
    and non-positive values become 0 (unknown).
    """
    path = Path(path)
    depth = np.asarray(depth_m, dtype=np.float64)
    if depth.ndim != 2:
        raise ValueError(f"{path}: expected a depth map [H, W], got shape {depth.shape}")
    if path.suffix.lower() != ".png":
        raise ValueError(f"{path}: depth maps are written as 16-bit PNG; use a .png name")
    valid = np.isfinite(depth) & (depth > 0)
    mm = np.where(valid, np.round(np.where(valid, depth, 0.0) * 1000.0), 0.0)
    write_bytes_atomic(path, _encode(path, np.clip(mm, 0, 65535).astype(np.uint16)))
