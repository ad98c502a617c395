"""Process-wide settings that make CPU rendering and training faster."""

from __future__ import annotations

import argparse
import ctypes
import ctypes.util
from dataclasses import dataclass
from pathlib import Path

from panogrf.app.options import option, user_path

_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_THRESHOLD, _M_ARENA_MAX = -1, -2, -3, -8
_MB = 1 << 20


def keep_freed_memory() -> bool:
    """Ask glibc's allocator to keep freed memory for reuse instead of returning it to the OS.

    Rendering and training allocate and free tensors of tens of megabytes per chunk of rays;
    by default glibc maps each from the OS afresh and unmaps it on free, so every chunk pays
    page faults on memory it just had (on this 2-core machine, about 30 % of a draft render).
    Large blocks now come from the heap (up to glibc's 32 MB limit) and the heap is trimmed
    only past 512 MB of free space. One arena for all threads: the viewer's render worker
    allocates from its own arena otherwise, whose heaps follow other rules and got slower
    render after render (0.7 -> 1.0 s for the same draft). Returns False off glibc."""
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    ok = mallopt(_M_MMAP_THRESHOLD, 32 * _MB) == 1
    ok &= mallopt(_M_TRIM_THRESHOLD, 512 * _MB) == 1
    ok &= mallopt(_M_TOP_PAD, 64 * _MB) == 1
    ok &= mallopt(_M_ARENA_MAX, 1) == 1
    return bool(ok)


class _MallInfo2(ctypes.Structure):
    _fields_ = [
        (name, ctypes.c_size_t)
        for name in (
            "arena",
            "ordblks",
            "smblks",
            "hblks",
            "hblkhd",
            "usmblks",
            "fsmblks",
            "uordblks",
            "fordblks",
            "keepcost",
        )
    ]


def _mallinfo2():
    name = ctypes.util.find_library("c")
    try:
        fn = ctypes.CDLL(name or "libc.so.6").mallinfo2
    except (OSError, AttributeError):
        return None
    fn.argtypes, fn.restype = (), _MallInfo2
    return fn


_MALLINFO2 = _mallinfo2()


def heap_in_use() -> int | None:
    """Bytes the C allocator has handed out and not had back (glibc's ``mallinfo2``: chunks in
    use in the arenas plus mmapped blocks), or None off glibc 2.33+. Unlike the resident size,
    this falls when tensors are freed even though the allocator keeps the pages
    (`keep_freed_memory`), so its peak over a block is what the block needed at once."""
    if _MALLINFO2 is None:
        return None
    info = _MALLINFO2()
    return int(info.uordblks + info.hblkhd)


def frame_indices(text: str) -> list[int]:
    """``--sources 0,2`` -> [0, 2] (argparse type): comma-separated frame indices, at least one."""
    try:
        values = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated frame indices, got {text!r}"
        ) from None
    if not values:
        raise argparse.ArgumentTypeError("expected at least one frame index")
    return values


def thread_count(text: str) -> int:
    """argparse type of ``--threads``: 0 (torch's default, every core) or a positive count of
    at most four per core (far more threads crash OpenMP's runtime)."""
    import os

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected 0 (all cores) or more, got {value}")
    cores = os.cpu_count() or 1
    if value > 4 * cores:
        raise argparse.ArgumentTypeError(
            f"expected at most {4 * cores} (4 per core; this machine has {cores}), got {value}"
        )
    return value


@dataclass(frozen=True)
class ThreadOptions:
    """``--threads``, of the commands that run torch (`panogrf.app.options`)."""

    threads: int = option(0, "torch threads (default: all)", parse=thread_count)
    """Torch threads (0: torch's default, every core)."""

    def apply(self) -> None:
        """Set torch's threads, if ``threads`` asks for a number."""
        if self.threads:
            import torch

            torch.set_num_threads(self.threads)


def folder_path(text: str) -> Path:
    """argparse type of a folder option: a path, not an empty string (which would be the
    current folder without a word) nor a file that exists."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a folder, got an empty string")
    path = user_path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{path} is a file, expected a folder")
    if path.is_symlink() and not path.exists():  # a cache on a drive that is not mounted
        raise argparse.ArgumentTypeError(
            f"{path} is a link to {path.readlink()}, which does not exist"
        )
    return path


def number(kind=float, low=None, high=None, low_open: bool = False):
    """argparse type of a numeric option: ``kind`` (float or int), finite, at least ``low``
    (above it when ``low_open``) and at most ``high`` (None: no bound). One line when not."""
    import math

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            what = "a whole number" if kind is int else "a number"
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
        if low is not None and (value <= low if low_open else value < low):
            bound = f"more than {low}" if low_open else f"at least {low}"
            raise argparse.ArgumentTypeError(f"expected {bound}, got {value}")
        if high is not None and value > high:
            raise argparse.ArgumentTypeError(f"expected at most {high}, got {value}")
        return value

    parse.__name__ = kind.__name__  # argparse names the type in its messages
    return parse


def metres_list(text: str) -> tuple[float, ...]:
    """argparse type of a comma-separated list of baselines in metres, each 0.05-5 m (an empty
    text gives an empty tuple)."""
    import argparse

    try:
        values = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated metres, got {text!r}") from None
    if any(not 0.05 <= v <= 5.0 for v in values):
        raise argparse.ArgumentTypeError(f"baselines must be between 0.05 and 5 m, got {text!r}")
    return values


@dataclass(frozen=True)
class RefineOptions:
    """``--refine-depth`` / ``--no-refine-depth``, of the commands that prepare a scene for
    rendering (`panogrf.app.options`; see `refine_setting`)."""

    refine_depth: bool = option(
        True,
        "refine the sources' depth per scene at preparation by photometric consistency between "
        "them (default: on; a few seconds per view on 2 cores, once per scene and cached with "
        "it; the viewer opens on the unrefined scene and switches when the refinement is "
        "done). --no-refine-depth: the networks' depth only",
        negatable=True,
    )
    """Refine the sources' depth per scene at preparation."""


def refine_setting(args):
    """The `RefineConfig` that ``--refine-depth`` (the default) asks for, or None."""
    if not getattr(args, "refine_depth", False):
        return None
    from panogrf.model.refine import PREPARE_REFINE

    return PREPARE_REFINE


@dataclass(frozen=True)
class PrepareOptions:
    """``--cache-dir``, ``--quiet`` and ``--device`` (`resolve_device`): the options of every
    command that prepares a scene (its depth and feature maps,
    `panogrf.app.scene.session.prepare_views`); see `prepare_options` for the others."""

    cache_dir: Path | None = option(
        None,
        "the prepared scenes' cache folder, shared by view, render, eval, bench, demo, "
        "depth and scene prepare (default: $XDG_CACHE_HOME/panogrf or ~/.cache/panogrf)",
        parse=folder_path,
    )
    """The cache folder (None: the user's cache folder)."""
    quiet: bool = option(False, "no progress of the preparation's stages on stderr")
    """No progress of the preparation's stages on stderr."""
    device: str = option(
        "auto",
        "where the networks run: auto (a CUDA GPU when there is one, else the CPU), cpu, "
        "cuda or cuda:N (default {default})",
    )
    """Where the networks and the whole depth chain run (`resolve_device`)."""


@dataclass(frozen=True)
class NoCacheOptions:
    """``--no-cache``, of the commands that prepare a scene to use it at once."""

    no_cache: bool = option(False, "prepare the scene afresh and write no cache")
    """Prepare the scene afresh and write no cache."""


#: Help of ``--nadir-cap``; "nadir_mask_deg" is `panogrf.renderer.nadir.METADATA_KEY`, written
#: out so that this module imports no torch (`keep_freed_memory` runs before it).
NADIR_HELP = (
    "mask the tripod / hand at the bottom of every source: a cap of DEG degrees "
    "around the nadir, 'auto' (detected per source; the default, or the scene's "
    "transforms.json 'nadir_mask_deg') or 'off'"
)


@dataclass(frozen=True)
class NadirOptions:
    """``--nadir-cap``, of the commands that render the scene's own sources (read with
    `panogrf.renderer.nadir.nadir_setting`)."""

    nadir_cap: str | None = option(None, NADIR_HELP, metavar="DEG|auto|off")
    """The cap masked around the nadir: degrees, "auto" or "off" (None: the scene's)."""


def prepare_options(no_cache: bool = True, nadir: bool = True) -> tuple[type, ...]:
    """The option classes of a command that prepares a scene, for `add_options`:
    `PrepareOptions`, `NoCacheOptions` (unless ``no_cache`` is False) and `NadirOptions`
    (unless ``nadir`` is False)."""
    return (
        PrepareOptions,
        *((NoCacheOptions,) if no_cache else ()),
        *((NadirOptions,) if nadir else ()),
    )


def refuse_scene_inputs(out: Path, scene, option: str = "--out", folder: bool = False) -> None:
    """Refuse, before any work, an output that would replace one of ``scene``'s own files
    (a source panorama, a depth map, its transforms.json) or, for a folder output
    (``folder``), the scene folder or a folder holding its files: a render or a report must
    never overwrite what it was made from."""
    from panogrf.app.errors import UserError

    inputs = [scene.root / "transforms.json"]
    for f in scene.frames:
        inputs.append(f.image_path)
        if f.depth_path is not None:
            inputs.append(f.depth_path)
    target = Path(out).resolve()
    for path in inputs:
        if path.resolve() == target:
            raise UserError(
                f"{option} {out}: is the scene's own {path.name}; refusing to overwrite an input, "
                "choose another"
            )
    if folder:
        folders = {scene.root.resolve()} | {p.resolve().parent for p in inputs}
        if target in folders:
            raise UserError(
                f"{option} {out}: holds the scene's own files; refusing to write over them, "
                "choose another folder"
            )


def resolve_device(name: str):
    """The torch device ``--device name`` asks for ("auto": the first CUDA GPU when torch
    sees one, else the CPU); a `UserError` in one line for one this machine does not have."""
    import torch

    from panogrf.app.errors import UserError

    text = str(name).strip().lower()
    if text == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(text)
    except (RuntimeError, ValueError):
        raise UserError(f"--device {name!r}: not a device (auto, cpu, cuda or cuda:N)") from None
    if device.type not in ("cpu", "cuda"):
        raise UserError(f"--device {name!r}: this tool runs on cpu or cuda")
    if device.type == "cuda":
        if not torch.cuda.is_available():
            why = "this torch is a CPU build" if torch.version.cuda is None else "no CUDA GPU seen"
            raise UserError(f"--device {name}: CUDA is not available here ({why})")
        count = torch.cuda.device_count()
        if device.index is not None and device.index >= count:
            raise UserError(f"--device {name}: this machine has {count} CUDA device(s)")
    return device
