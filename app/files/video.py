"""Writing frames to an H.264 MP4 (imageio-ffmpeg's bundled ffmpeg) or to a folder of PNGs.

Both go to a temporary beside the target (`panogrf.app.files.atomic`) that replaces it only when
complete: a video once ffmpeg has exited cleanly (a full disk makes it fail at the trailer), a
folder once every frame is in it, so an older video or folder is never damaged and a folder
never mixes in stale frames of an earlier, longer render. Videos start fast (index first) and
an equirectangular one carries the 360° metadata players look for (`panogrf.app.files.spherical`).
"""

from __future__ import annotations

import re
import subprocess
import threading
from fractions import Fraction
from pathlib import Path

import numpy as np

from panogrf.app.errors import UserError
from panogrf.app.files.atomic import check_output, commit, discard, sweep_stale, temp_path
from panogrf.app.files.images import write_rgb

#: x264 constant rate factor (lower is better; 10 is visually lossless).
CRF = 10
_FRAME_NAME = re.compile(r"^frame_\d{5}\.png$")


def _check_frames_folder(out: Path) -> None:
    """A frames folder is replaced whole: refuse one that holds anything but our frames."""
    if out.exists() and not out.is_dir():
        raise UserError(f"--out: {out} is a file; a folder of frames or a .mp4 name is expected")
    if out.is_dir():
        others = sorted(p.name for p in out.iterdir() if not _FRAME_NAME.match(p.name))
        if others:
            raise UserError(
                f"--out: folder {out} holds other files than frames ({', '.join(others[:3])}"
                f"{', ...' if len(others) > 3 else ''}); name a new or empty folder"
            )


class FrameSink:
    """Frames in, a video or PNG folder out: ``with FrameSink(out, fps, w, h) as sink:``.

    ``spherical``: the frames are equirectangular panoramas (the MP4 says so to players).
    """

    def __init__(
        self, out: Path, fps: float, width: int, height: int, spherical: bool = False
    ) -> None:
        self.out = Path(out)
        self.fps, self.width, self.height = fps, width, height
        self.spherical = spherical
        self.count = 0
        self.is_video = self.out.suffix.lower() == ".mp4"
        self._proc: subprocess.Popen | None = None
        self._stderr: list[str] = []  # the first lines: the cause comes first
        self._drain: threading.Thread | None = None
        self._tmp: Path | None = None
        self._raw: Path | None = None  # ffmpeg's output before the spherical metadata
        if self.is_video:
            if width % 2 or height % 2:
                raise UserError(
                    f"{self.out}: H.264 needs even frame sizes, got {width}x{height} (the camera "
                    "path's render_width and render_height); make them even, or write the "
                    "frames to a folder (--out without .mp4)"
                )
            check_output(self.out)
        elif self.out.suffix:
            raise UserError(f"--out must be a .mp4 file or a folder, got {self.out}")
        else:
            _check_frames_folder(self.out)

    def __enter__(self) -> FrameSink:
        try:
            self.out.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UserError(f"cannot create {self.out.parent}: {exc.strerror or exc}") from None
        sweep_stale(self.out.parent)
        self._tmp = temp_path(self.out)
        if self.is_video:
            self._raw = temp_path(self.out) if self.spherical else self._tmp
            self._start_ffmpeg(self._raw)
        else:
            try:
                self._tmp.mkdir()
            except OSError as exc:
                raise UserError(f"cannot write in {self.out.parent}: {exc.strerror}") from None
        return self

    def _start_ffmpeg(self, path: Path) -> None:
        import imageio_ffmpeg

        cmd = [
            imageio_ffmpeg.get_ffmpeg_exe(),
            "-hide_banner",
            "-loglevel", "error",
            "-y",
            "-f", "rawvideo",
            "-pix_fmt", "rgb24",
            "-s", f"{self.width}x{self.height}",
            "-r", str(Fraction(self.fps).limit_denominator(1001)),
            "-i", "-",
            "-an",
            "-c:v", "libx264",
            "-pix_fmt", "yuv420p",
            "-crf", str(CRF),
            "-movflags", "+faststart",
            "-f", "mp4",
            str(path),
        ]  # fmt: skip
        self._proc = subprocess.Popen(
            cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
        )
        # Drained in a thread: a full pipe would block ffmpeg, and with it this process.
        self._drain = threading.Thread(target=self._read_stderr, daemon=True)
        self._drain.start()

    def _read_stderr(self) -> None:
        for line in iter(self._proc.stderr.readline, b""):
            if len(self._stderr) < 50:
                self._stderr.append(line.decode(errors="replace").rstrip())

    def _ffmpeg_error(self, rc: int | None) -> UserError:
        if self._drain is not None:
            self._drain.join(timeout=5)
        # The first line is the cause (e.g. "No space left on device"), the rest its effects.
        said = [re.sub(r"^\[[^\]]*\]\s*", "", line) for line in self._stderr if line]
        status = "" if rc is None else f" (exit status {rc})"
        return UserError(f"ffmpeg failed writing {self.out}{status}: {(said or ['?'])[0]}")

    def write(self, frame: np.ndarray) -> None:
        """One RGB uint8 frame [height, width, 3]."""
        if frame.shape != (self.height, self.width, 3) or frame.dtype != np.uint8:
            raise ValueError(
                f"expected a uint8 frame {(self.height, self.width, 3)}, got "
                f"{frame.dtype} {frame.shape}"
            )
        if self.is_video:
            try:
                self._proc.stdin.write(np.ascontiguousarray(frame).tobytes())
            except (BrokenPipeError, OSError):
                raise self._ffmpeg_error(self._proc.wait()) from None
        else:
            write_rgb(self._tmp / f"frame_{self.count:05d}.png", frame)
        self.count += 1

    def _finish_video(self, ok: bool) -> None:
        proc = self._proc
        if not ok:
            proc.kill()
        try:
            proc.stdin.close()
        except OSError:
            pass  # ffmpeg already gone: its exit status says why
        rc = proc.wait()
        if ok and rc != 0:
            raise self._ffmpeg_error(rc)
        if ok and self.spherical:
            from panogrf.app.files.spherical import add_spherical_metadata

            try:
                add_spherical_metadata(self._raw, self._tmp)
            except OSError as exc:
                raise UserError(f"cannot write {self.out}: {exc.strerror or exc}") from None

    def __exit__(self, exc_type, exc, tb) -> None:
        ok = exc_type is None
        try:
            if self.is_video and self._proc is not None:
                self._finish_video(ok)
            if ok and self.count > 0:
                try:
                    commit(self._tmp, self.out)
                except OSError as err:
                    raise UserError(f"cannot write {self.out}: {err.strerror or err}") from None
        finally:
            for tmp in {self._tmp, self._raw} - {None}:
                if tmp.exists():
                    discard(tmp)
