"""360° metadata for equirectangular MP4s: the Spherical Video V1 ``uuid`` box.

Players (YouTube, VLC, ffmpeg's demuxer) recognise a panorama video by a ``uuid`` box in its
video track holding the Google Spatial Media V1 XML (github.com/google/spatial-media,
docs/spherical-video-rfc.md). ffmpeg's muxer cannot write it, so it is added after the mux:
the ``moov`` box is rebuilt with the box in each video ``trak`` and, when ``moov`` comes
before the media data (fast start), every chunk offset (``stco``/``co64``) is moved by the
size added.
"""

from __future__ import annotations

import shutil
import struct
from pathlib import Path

SPHERICAL_UUID = bytes.fromhex("ffcc8263f8554a938814587a02521fdd")
SPHERICAL_XML = (
    '<?xml version="1.0"?>'
    '<rdf:SphericalVideo xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#" '
    'xmlns:GSpherical="http://ns.google.com/videos/1.0/spherical/">'
    "<GSpherical:Spherical>true</GSpherical:Spherical>"
    "<GSpherical:Stitched>true</GSpherical:Stitched>"
    "<GSpherical:StitchingSoftware>panogrf</GSpherical:StitchingSoftware>"
    "<GSpherical:ProjectionType>equirectangular</GSpherical:ProjectionType>"
    "</rdf:SphericalVideo>"
)
_CONTAINERS = {b"moov", b"trak", b"mdia", b"minf", b"stbl"}


class Mp4Error(ValueError):
    """A file whose box structure is not the MP4 expected."""


def _boxes(data: bytes, start: int, end: int):
    """(type, header size, start, end) of each box in ``data[start:end]``."""
    pos = start
    while pos < end:
        if pos + 8 > end:
            raise Mp4Error("box header past its parent's end")
        size, kind = struct.unpack_from(">I4s", data, pos)
        header = 8
        if size == 1:
            (size,) = struct.unpack_from(">Q", data, pos + 8)
            header = 16
        elif size == 0:
            size = end - pos
        if size < header or pos + size > end:
            raise Mp4Error(f"box {kind!r} of {size} bytes does not fit")
        yield kind, header, pos, pos + size
        pos += size


def _box(kind: bytes, payload: bytes) -> bytes:
    if 8 + len(payload) >= 1 << 32:
        raise Mp4Error("box too large")
    return struct.pack(">I4s", 8 + len(payload), kind) + payload


def _is_video(data: bytes, trak_start: int, trak_end: int, header: int) -> bool:
    for kind, h, s, e in _boxes(data, trak_start + header, trak_end):
        if kind == b"mdia":
            for k2, h2, s2, _ in _boxes(data, s + h, e):
                if k2 == b"hdlr":
                    return data[s2 + h2 + 8 : s2 + h2 + 12] == b"vide"
    return False


def _rebuild(data: bytes, kind: bytes, header: int, start: int, end: int, shift: int) -> bytes:
    body = data[start + header : end]
    if kind in (b"stco", b"co64") and shift:
        fmt = ">I" if kind == b"stco" else ">Q"
        width = struct.calcsize(fmt)
        (count,) = struct.unpack_from(">I", body, 4)
        offsets = [struct.unpack_from(fmt, body, 8 + i * width)[0] + shift for i in range(count)]
        if kind == b"stco" and offsets and max(offsets) >= 1 << 32:
            raise Mp4Error("chunk offsets overflow 32 bits")
        body = body[:8] + b"".join(struct.pack(fmt, o) for o in offsets) + body[8 + count * width :]
    elif kind in _CONTAINERS:
        parts = []
        for k, h, s, e in _boxes(data, start + header, end):
            if k == b"uuid" and data[s + h : s + h + 16] == SPHERICAL_UUID:
                continue  # replaced below
            parts.append(_rebuild(data, k, h, s, e, shift))
        if kind == b"trak" and _is_video(data, start, end, header):
            parts.append(_box(b"uuid", SPHERICAL_UUID + SPHERICAL_XML.encode("utf-8")))
        body = b"".join(parts)
    return _box(kind, body)


def add_spherical_metadata(src: Path, dst: Path) -> None:
    """Copy MP4 ``src`` to ``dst`` with the V1 spherical box in its video track(s)."""
    with open(src, "rb") as f:
        f.seek(0, 2)
        size = f.tell()
        top = []
        pos = 0
        while pos < size:
            f.seek(pos)
            head = f.read(16)
            if len(head) < 8:
                raise Mp4Error("truncated box header")
            n, kind = struct.unpack_from(">I4s", head)
            if n == 1:
                (n,) = struct.unpack_from(">Q", head, 8)
            elif n == 0:
                n = size - pos
            if n < 8 or pos + n > size:
                raise Mp4Error(f"top-level box {kind!r} does not fit the file")
            top.append((kind, pos, pos + n))
            pos += n
        moov = [(s, e) for k, s, e in top if k == b"moov"]
        mdat = [s for k, s, _ in top if k == b"mdat"]
        if len(moov) != 1:
            raise Mp4Error(f"expected one moov box, found {len(moov)}")
        m_start, m_end = moov[0]
        f.seek(m_start)
        data = f.read(m_end - m_start)
        header = 16 if struct.unpack_from(">I", data)[0] == 1 else 8
        new = _rebuild(data, b"moov", header, 0, len(data), 0)
        if mdat and m_start < min(mdat):  # media data moves by the growth of moov
            new = _rebuild(data, b"moov", header, 0, len(data), len(new) - len(data))
        with open(dst, "wb") as out:
            f.seek(0)
            _copy(f, out, m_start)
            out.write(new)
            f.seek(m_end)
            shutil.copyfileobj(f, out, 1 << 20)


def _copy(src, dst, count: int) -> None:
    while count > 0:
        chunk = src.read(min(count, 1 << 20))
        if not chunk:
            raise Mp4Error("file shorter than its boxes")
        dst.write(chunk)
        count -= len(chunk)
