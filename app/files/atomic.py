"""The one way panogrf writes a file or a folder: to a temporary name beside it, then a rename.

A reader, a crash, a kill -9 or a full disk never leaves a half-written file under the real
name, and never damages the older file there: the temporary is renamed over it only once it
is complete (and synced). Temporaries carry one recognisable name,
``.NAME.PID-XXXXXXXX.panogrf-tmp[.SUFFIX]`` (the suffix keeps the format for writers that go
by it, such as ffmpeg), so that the next write into the same folder sweeps those whose process
has died. Permissions follow the umask, as for a plain ``open()``.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import json
import math
import os
import re
import shutil
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from panogrf.app.errors import UserError

TMP_TAG = "panogrf-tmp"
_OURS = re.compile(rf"^\..+\.(?P<pid>\d+)-[0-9a-f]{{8}}\.{TMP_TAG}(\.[A-Za-z0-9]+)?$")
# Names of earlier versions' temporaries (no process id): swept once they are an hour old.
_LEGACY = re.compile(r"^\..+\.([A-Za-z0-9_]{8}\.partial\.mp4|[a-z0-9_]{8}\.tmp|[0-9a-f]{12}\.tmp)$")
_LEGACY_AGE_S = 3600.0
_STALE_AGE_S = 24 * 3600.0  # a live process holding a temporary this long is not ours


def temp_path(path: str | os.PathLike[str]) -> Path:
    """A fresh temporary name in ``path``'s folder (os.replace is atomic within one file system)."""
    path = Path(path)
    tag = f"{os.getpid()}-{uuid.uuid4().hex[:8]}"
    return path.with_name(f".{path.name}.{tag}.{TMP_TAG}{path.suffix}")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # EPERM: exists, another user's
        return True
    return True


def _remove(path: Path) -> None:
    try:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
    except OSError:
        pass


def sweep_stale(
    folder: str | os.PathLike[str], foreign: re.Pattern[str] | None = None
) -> list[Path]:
    """Remove the temporaries of our own naming in ``folder`` left by dead processes, and
    those named as ``foreign`` says (another library's, which carry no process id) once they
    are an hour old."""
    folder = Path(folder)
    removed: list[Path] = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    now = time.time()
    for entry in entries:
        if not entry.name.startswith("."):
            continue
        try:
            age = now - entry.stat(follow_symlinks=False).st_mtime
        except OSError:
            continue
        m = _OURS.match(entry.name)
        if m is not None:
            pid = int(m["pid"])
            stale = pid != os.getpid() and (not _alive(pid) or age > _STALE_AGE_S)
        else:
            other = _LEGACY.match(entry.name) or (foreign is not None and foreign.match(entry.name))
            stale = bool(other) and age > _LEGACY_AGE_S
        if stale:
            _remove(Path(entry.path))
            removed.append(Path(entry.path))
    return removed


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


_RENAME_EXCHANGE = 2


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux renameat2); False where the system cannot."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd = -100
    ok = renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), _RENAME_EXCHANGE)
    if ok == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def _commit_dir(tmp: Path, path: Path) -> None:
    if not os.path.lexists(path):
        os.rename(tmp, path)
        return
    if not path.is_dir():
        raise IsADirectoryError(errno.ENOTDIR, "not a folder", str(path))
    if _exchange(tmp, path):
        _remove(tmp)  # now holds the older folder
        return
    # No atomic swap here: for a moment the real name is missing, never half-written.
    old = temp_path(path)
    os.rename(path, old)
    os.rename(tmp, path)
    _remove(old)


def commit(tmp: Path, path: str | os.PathLike[str]) -> None:
    """Put the finished temporary ``tmp`` (a file or a folder) in place of ``path``."""
    path = Path(path)
    if tmp.is_dir():
        _commit_dir(tmp, path)
    else:
        _fsync(tmp)
        os.replace(tmp, path)


def discard(tmp: Path) -> None:
    """Remove a temporary (file or folder) that will not be committed."""
    _remove(tmp)


@contextmanager
def atomic_output(
    path: str | os.PathLike[str], directory: bool = False, foreign: re.Pattern[str] | None = None
) -> Iterator[Path]:
    """``with atomic_output(out) as tmp:`` write ``tmp`` (a file, or with ``directory`` a new
    empty folder); on a clean exit it replaces ``out``, on any error it is removed and ``out``
    is untouched. ``foreign``: other temporaries the writer leaves, swept (`sweep_stale`)."""
    path = Path(os.path.abspath(path))  # "." and "a/.." have no name of their own
    sweep_stale(path.parent, foreign)
    tmp = temp_path(path)
    try:
        if directory:
            tmp.mkdir()
        yield tmp
        commit(tmp, path)
    except BaseException:
        _remove(tmp)
        raise


def write_bytes_atomic(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_output(path) as tmp:
        # O_EXCL: the name is ours alone; mode 0o666 lets the umask decide, as for open().
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        with os.fdopen(fd, "wb") as f:
            f.write(data)


def write_text_atomic(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    write_bytes_atomic(path, text.encode("utf-8"))


def save_tensors_atomic(
    path: str | os.PathLike[str],
    tensors: dict,
    metadata: dict[str, str] | None = None,
    foreign: re.Pattern[str] | None = None,
) -> None:
    """Write a safetensors file atomically, its mode following the umask as for ``open()``
    (safetensors writes through a private temporary of its own, mode 0600, which a shared
    pack or cache could not be read from). A full disk raises OSError (safetensors reports
    it as its own error type, which callers would otherwise have to know). ``foreign``: as
    for `atomic_output` (the names of safetensors' own temporaries, swept when stale)."""
    from safetensors import SafetensorError
    from safetensors.torch import save_file

    with atomic_output(path, foreign=foreign) as tmp:
        Path(tmp).touch()  # made as open() makes a file: its mode follows the umask
        mode = os.stat(tmp).st_mode & 0o777
        try:
            save_file(tensors, str(tmp), metadata=metadata)
        except SafetensorError as exc:
            raise OSError(f"cannot write {path}: {exc}") from exc
        with contextlib.suppress(OSError):  # a file system without modes keeps its own
            os.chmod(tmp, mode)


# An innermost JSON list of plain scalars, as json.dumps indents it. The raw newline after "["
# never occurs inside a JSON string (dumps escapes it), so string contents are never touched.
_FLAT_LIST = re.compile(r"\[\n\s*([^\[\]{}\"]*?)\n\s*\]")


def nan_to_null(data: object) -> object:
    """``data`` with every NaN or infinite float replaced by None (JSON null)."""
    if isinstance(data, float):
        return data if math.isfinite(data) else None
    if isinstance(data, dict):
        return {k: nan_to_null(v) for k, v in data.items()}
    if isinstance(data, (list, tuple)):
        return [nan_to_null(v) for v in data]
    return data


def _valid_text(data: object) -> object:
    """``data`` with every string that holds bytes of a file name that are not UTF-8 (lone
    surrogates, which JSON readers refuse) showing them as ``\\xff``."""
    if isinstance(data, str):
        if data.isprintable() or data.isascii():
            return data
        try:
            return data.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
        except UnicodeEncodeError:  # a surrogate no file name's byte gives
            return data.encode("utf-8", "backslashreplace").decode("utf-8")
    if isinstance(data, dict):
        return {_valid_text(k): _valid_text(v) for k, v in data.items()}
    if isinstance(data, (list, tuple)):
        return [_valid_text(v) for v in data]
    return data


def json_text(data: object) -> str:
    """Indented JSON with number lists on one line (a pose's matrix rows read well)."""
    text = json.dumps(_valid_text(data), indent=2, allow_nan=False)
    return _FLAT_LIST.sub(lambda m: "[" + ", ".join(x.strip() for x in m[1].split(",")) + "]", text)


#: Digits beyond which a JSON integer is read as an infinity (of its sign): Python refuses to
#: convert more than 4300 with a ValueError, and no count, size or coordinate needs them; the
#: readers' own checks then name the field as not finite.
MAX_INT_DIGITS = 100


def _bounded_int(text: str) -> int | float:
    if len(text.lstrip("-")) > MAX_INT_DIGITS:
        return -math.inf if text.startswith("-") else math.inf
    return int(text)


def parse_json(text: str) -> object:
    """``json.loads`` for files a user hands over: an integer of more than `MAX_INT_DIGITS`
    digits is an infinity instead of Python's int-conversion error."""
    return json.loads(text, parse_int=_bounded_int)


def write_json_atomic(path: str | os.PathLike[str], data: object) -> None:
    """Write ``data`` as indented JSON (UTF-8), atomically; number lists stay on one line.

    NaN and infinity are refused (they are not JSON): pass ``nan_to_null(data)`` where a
    missing value is meant.
    """
    write_bytes_atomic(path, (json_text(data) + "\n").encode("utf-8"))


def check_writable(path: str | os.PathLike[str], option: str = "--out") -> Path:
    """`check_output`, then a probe: a file created and removed beside ``path`` (a folder the
    permission bits call writable may still refuse files: /proc, a read-only mount)."""
    path = check_output(path, option)
    probe = path.parent / f".panogrf-probe-{os.getpid()}"
    try:
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise UserError(
            f"{option}: cannot write in {path.parent} ({exc.strerror or exc})"
        ) from None
    return path


def check_output(path: str | os.PathLike[str], option: str = "--out", folder: bool = False) -> Path:
    """Refuse, before any work, an output that cannot be written: a missing or read-only
    folder, or a folder where a file is wanted (and a file where a folder is wanted)."""
    path = Path(path)
    parent = path.parent
    try:
        path.exists()  # a name too long for the file system: said here, not as a traceback
    except OSError as exc:
        raise UserError(f"{option} {path}: {exc.strerror or exc}") from None
    if not parent.is_dir():
        what = "is a file, not a folder" if parent.exists() else "does not exist"
        raise UserError(f"{option}: folder {parent} {what}")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UserError(f"{option}: folder {parent} is not writable")
    if folder and path.exists() and not path.is_dir():
        raise UserError(f"{option}: {path} is a file, expected a folder")
    if not folder and path.is_dir():
        raise UserError(f"{option}: {path} is a folder, expected a file name")
    if path.exists() and not (path.is_dir() or path.is_file()):  # it would replace the node
        raise UserError(f"{option}: {path} is not a regular file (a device, pipe or socket)")
    return path


def refuse_foreign_folder(
    out: str | os.PathLike[str],
    command: str,
    earlier: Callable[[Path], bool],
    option: str = "--out",
) -> None:
    """Refuse, before any work, an output folder that is not empty and holds no earlier output
    of ``command`` (``earlier(out)`` says whether it does): a scene folder, a folder of the
    user's photos or another command's output, whose files the command would mix its own with
    or write over. The message names a few of the files there; our temporaries don't count."""
    out = Path(out)
    if not out.is_dir():
        return
    try:
        names = sorted(p.name for p in out.iterdir() if not _OURS.match(p.name))
    except OSError as exc:
        raise UserError(f"{option} {out}: cannot be read ({exc.strerror or exc})") from None
    if names and not earlier(out):
        shown = ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")
        raise UserError(
            f"{option} {out} is not empty ({shown}) and holds no earlier `{command}` output: "
            "refusing to write into it, choose an empty or new folder"
        )
