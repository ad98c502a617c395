"""Prepared scenes kept by their provenance: one store, read and filled in one way.

A prepared scene (its estimated depth and the renderer's feature maps, or `panogrf depth`'s
estimate) is named by its `Provenance`: the pixels, the poses, the weights files' bytes and how
the depth was made. A `Store` maps that name to an `Entry` (tensors and text metadata);
`get_or_compute` is how the app reads it: a valid entry is returned as it is, a missing or
untrustworthy one is computed and put. The store holds tensors only: it never writes into the
renderer's objects; the caller hands what it returns to them.

- `DiskStore`: the cache folder (``$XDG_CACHE_HOME/panogrf`` or ``~/.cache/panogrf``), one
  safetensors file per entry, written to a temporary name and renamed (an interrupted write
  never leaves a broken entry under the real name), with the entry's name and a checksum of
  its tensors inside, checked on every read: a file that cannot be read, belongs to another
  name or was changed is recomputed, never trusted. A full or read-only disk costs the entry
  only.
- `MemoryStore`: a dict (tests; an in-process cache).
"""

from __future__ import annotations

import hashlib
import os
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file
from torch import Tensor

from panogrf.app.files.atomic import save_tensors_atomic
from panogrf.model.depth_config import DepthConfig

#: Format of the entries: part of every name, so a new format never reads an old entry.
#: 6: no exposure balance of the sources; 7: a checksum; 8: one store for scenes and estimates.
FORMAT = "panogrf-scene-cache-8"
#: The depth chain's settings as shipped: the same weights and pixels give other depth when they
#: change (which sources a view is compared with, the sweep's candidates), so they name the
#: entry too.
CHAIN = repr(DepthConfig())

Tensors = dict[str, Tensor]


@dataclass(frozen=True)
class Provenance:
    """What a prepared scene was made from. Its `key` names its entry in a `Store`."""

    pixels: str
    """SHA-256 of the panoramas' shape and their pixels as 8-bit values."""
    poses: str
    """SHA-256 of the poses in double precision."""
    weights: str
    """SHA-256 of the weights files' names and bytes."""
    setting: str = ""
    """How it was made when not by default (a refinement, a nadir mask, another device, an
    estimate of one depth mode)."""

    @property
    def key(self) -> str:
        h = hashlib.sha256(FORMAT.encode())
        h.update(CHAIN.encode())
        if self.setting:
            h.update(self.setting.encode())
        for part in (self.pixels, self.poses, self.weights):
            h.update(part.encode())
        return h.hexdigest()[:32]

    @classmethod
    def of(cls, images: Tensor, c2w: Tensor, weight_files: list[Path], setting: str = ""):
        """The provenance of panoramas ``images`` [V, 3, H, W] in [0, 1] at poses ``c2w``
        [V, 4, 4] prepared with the networks of ``weight_files``."""
        pixels = hashlib.sha256(str(tuple(images.shape)).encode())
        pixels.update((images.clamp(0, 1) * 255).round().to(torch.uint8).cpu().numpy().tobytes())
        poses = hashlib.sha256(c2w.to(torch.float64).cpu().numpy().tobytes())
        weights = hashlib.sha256()
        for path in weight_files:
            weights.update(path.name.encode())
            weights.update(path.read_bytes())
        return cls(pixels.hexdigest(), poses.hexdigest(), weights.hexdigest(), setting)


@dataclass(frozen=True)
class Entry:
    """What a store holds under one name: tensors and text metadata."""

    tensors: Tensors
    meta: dict[str, str] = field(default_factory=dict)
    damaged: str | None = None
    """Why the stored bytes are not what was put (a checksum mismatch), told after the
    contents' own check: None when they are."""


@dataclass(frozen=True)
class Fetched:
    """An entry as `get_or_compute` gave it, with where it lives and what happened: "loaded",
    "built" or "rebuilt: <why the stored one was not trusted>", and " (not saved in <where>:
    <why>)" when it could not be put."""

    entry: Entry
    status: str
    where: Path


class Unusable(Exception):
    """A stored entry that cannot be trusted; the message says why."""


class Store(Protocol):
    def read(self, key: str) -> Entry | None:
        """The entry named ``key``, None when there is none; `Unusable` when it cannot be
        trusted."""
        ...

    def write(self, key: str, entry: Entry) -> None:
        """Put ``entry`` under ``key``; OSError (or the format's own error) when it cannot."""
        ...

    def where(self, key: str) -> Path:
        """Where the entry named ``key`` lives (a path for the user to see)."""
        ...


def get_or_compute(
    store: Store,
    key: str,
    compute: Callable[[], Entry],
    check: Callable[[Entry], str | None] = lambda entry: None,
) -> Fetched:
    """The entry named ``key``: read from ``store`` when there and valid (``check`` returns
    None), else computed by ``compute`` and put."""
    why = None
    try:
        stored = store.read(key)
        if stored is not None:
            why = check(stored) or stored.damaged
            if why is None:
                return Fetched(stored, "loaded", store.where(key))
    except Unusable as exc:
        why = str(exc)
    entry = compute()
    status = "built" if why is None else f"rebuilt: {why}"
    try:
        store.write(key, entry)
    # A read-only or full disk (safetensors reports it as its own error) costs the entry only.
    except (OSError, SafetensorError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
        status += f" (not saved in {store.where(key)}: {reason})"
    return Fetched(entry, status, store.where(key))


def read_valid(
    store: Store, key: str, check: Callable[[Entry], str | None] = lambda entry: None
) -> tuple[Entry | None, str | None]:
    """(the entry named ``key``, None) when the store holds a valid one, else (None, why not:
    None when there is none)."""
    try:
        stored = store.read(key)
    except Unusable as exc:
        return None, str(exc)
    if stored is None:
        return None, None
    why = check(stored) or stored.damaged
    return (stored, None) if why is None else (None, why)


class MemoryStore:
    """A store in a dict (``entries``: key -> `Entry`)."""

    def __init__(self, entries: dict[str, Entry] | None = None) -> None:
        self.entries = {} if entries is None else entries

    def read(self, key: str) -> Entry | None:
        return self.entries.get(key)

    def write(self, key: str, entry: Entry) -> None:
        self.entries[key] = entry

    def where(self, key: str) -> Path:
        return Path(f"memory:{key}")


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/panogrf`` or ``~/.cache/panogrf``."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "panogrf"


class DiskStore:
    """A store in a folder: one safetensors file per entry (``<key>.safetensors``)."""

    def __init__(self, folder: Path | None = None) -> None:
        self.folder = Path(folder) if folder is not None else default_cache_dir()

    def where(self, key: str) -> Path:
        return self.folder / f"{key}.safetensors"

    def read(self, key: str) -> Entry | None:
        path = self.where(key)
        if not path.exists():
            return None
        if not path.is_file():  # a pipe would block the read for good
            raise Unusable("not a regular file")
        if not os.access(path, os.R_OK):  # safetensors would call it a missing file
            raise Unusable("unreadable (no permission to read it)")
        try:
            tensors = load_file(str(path))
            meta = _metadata(path)
        except (SafetensorError, OSError, ValueError, RuntimeError) as exc:
            raise Unusable(f"unreadable ({type(exc).__name__})") from None
        stored = tensors.pop("__key__", None)
        if stored is None or stored.dtype != torch.uint8 or stored.ndim != 1:
            raise Unusable("no key")
        if bytes(stored.tolist()).decode(errors="replace") != key:
            raise Unusable("stale (another scene or other weights)")
        damaged = None
        if meta.pop("sha256", None) != checksum(tensors):
            damaged = "checksum mismatch (the file was changed)"
        meta.pop("format", None)
        return Entry(tensors, meta, damaged)

    def write(self, key: str, entry: Entry) -> None:
        tensors = {name: t.detach().cpu().contiguous() for name, t in entry.tensors.items()}
        meta = {**entry.meta, "format": FORMAT, "sha256": checksum(tensors)}
        tensors["__key__"] = torch.tensor(list(key.encode()), dtype=torch.uint8)
        path = self.where(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        save_tensors_atomic(path, tensors, meta, foreign=_SAFETENSORS_TMP)


#: safetensors writes through a temporary of its own (``.tmpXXXXXX``, renamed when complete):
#: one a killed process left in the cache folder is removed once it is an hour old.
_SAFETENSORS_TMP = re.compile(r"^\.tmp[A-Za-z0-9]{6}$")


def checksum(tensors: Tensors) -> str:
    """SHA-256 of the tensors' names, shapes, dtypes and bytes (in name order)."""
    h = hashlib.sha256()
    for name in sorted(tensors):
        t = tensors[name].detach().cpu().contiguous()
        h.update(f"{name} {tuple(t.shape)} {t.dtype}".encode())
        h.update(t.view(torch.uint8).numpy().tobytes() if t.numel() else b"")
    return h.hexdigest()


def _metadata(path: Path) -> dict[str, str]:
    from safetensors import safe_open

    with safe_open(str(path), framework="pt") as f:
        return dict(f.metadata() or {})
