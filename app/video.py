"""Writing frames to an H.264 MP4 (imageio-ffmpeg's bundled ffmpeg) or to a folder of PNGs.

The video goes to a temporary file beside the target and is renamed when complete, so an
interrupted render never leaves a half-written video under the final name.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from panogrf.app.errors import UserError
from panogrf.app.images import write_rgb


class FrameSink:
    """Frames in, a video or PNG folder out: ``with FrameSink(out, fps, w, h) as sink:``."""

    def __init__(self, out: Path, fps: float, width: int, height: int) -> None:
        self.out = Path(out)
        self.fps, self.width, self.height = fps, width, height
        self.count = 0
        self.is_video = self.out.suffix.lower() == ".mp4"
        self._writer = None
        self._tmp: Path | None = None
        if self.is_video:
            if width % 2 or height % 2:
                raise UserError(f"H.264 needs even frame sizes, got {width}x{height}")
            if not self.out.parent.is_dir():
                raise UserError(f"--out: folder {self.out.parent} does not exist")
        elif self.out.suffix:
            raise UserError(f"--out must be a .mp4 file or a folder, got {self.out}")

    def __enter__(self) -> FrameSink:
        if self.is_video:
            import imageio_ffmpeg

            fd, tmp = tempfile.mkstemp(
                dir=self.out.parent, prefix=f".{self.out.stem}.", suffix=".partial.mp4"
            )
            os.close(fd)
            self._tmp = Path(tmp)
            self._writer = imageio_ffmpeg.write_frames(
                str(self._tmp),
                (self.width, self.height),
                fps=self.fps,
                codec="libx264",
                pix_fmt_out="yuv420p",
                quality=8,
                macro_block_size=1,
                ffmpeg_log_level="error",
            )
            self._writer.send(None)  # start ffmpeg
        else:
            try:
                self.out.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise UserError(f"cannot create {self.out}: {exc.strerror or exc}") from None
        return self

    def write(self, frame: np.ndarray) -> None:
        """One RGB uint8 frame [height, width, 3]."""
        if frame.shape != (self.height, self.width, 3) or frame.dtype != np.uint8:
            raise ValueError(
                f"expected a uint8 frame {(self.height, self.width, 3)}, got "
                f"{frame.dtype} {frame.shape}"
            )
        if self.is_video:
            self._writer.send(np.ascontiguousarray(frame))
        else:
            write_rgb(self.out / f"frame_{self.count:05d}.png", frame)
        self.count += 1

    def __exit__(self, exc_type, exc, tb) -> None:
        if not self.is_video:
            return
        try:
            self._writer.close()
        finally:
            if exc_type is None and self.count > 0:
                os.replace(self._tmp, self.out)
            elif self._tmp is not None and self._tmp.exists():
                self._tmp.unlink()
