"""Estimating a scene's depth and writing it as a scene folder (the library under `panogrf depth`).

The output folder is itself a scene folder (docs/conventions.md): copies of the panoramas in
``images/``, the estimated depth in ``depth/`` (16-bit PNG, millimetres) referenced by each
frame's ``depth_file_path``, colour-mapped previews in ``preview/``, and a ``transforms.json``
with the input's poses and metadata plus a ``panogrf_depth`` key describing the run.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from panogrf.app.errors import UserError
from panogrf.app.files.atomic import parse_json, refuse_foreign_folder
from panogrf.model.depth_config import DepthMode

if TYPE_CHECKING:
    from panogrf.app.scene.folder import Scene
    from panogrf.model.depth import DepthEstimator
    from panogrf.model.metrics import DepthMetrics

#: The depth modes `panogrf depth` offers, in the order its help lists them.
MODES = (DepthMode.FULL, DepthMode.MONO, DepthMode.MVS)
#: Top-level key of the output transforms.json that describes the estimation.
METADATA_KEY = "panogrf_depth"
METRIC_COLUMNS = (("L1", "l1"), ("RMSE", "rmse"), ("WS-L1", "ws_l1"), ("WS-RMSE", "ws_rmse"))


@dataclass(frozen=True)
class DepthRun:
    """What `estimate_scene` did: per-view figures in the order of the scene's frames."""

    out_dir: Path
    mode: DepthMode
    views: tuple[str, ...]
    """Frame names (image file stems)."""
    seconds: float
    """Wall time of the estimation itself (no file reading or writing)."""
    d_max: float
    """Top of the estimator's depth range (metres): depth there is clamped."""
    out_of_range_fraction: tuple[float, ...]
    """Share of pixels clamped at ``d_max``, per view."""
    sources: tuple[tuple[str, ...], ...]
    """Names of the views used as MVS sources, per view (empty: monocular depth)."""
    warnings: tuple[str, ...]
    metrics: tuple[DepthMetrics | None, ...] | None
    """Per view against ground truth on 0 < gt <= d_max (None: view without valid GT);
    None when the scene has no depth maps."""
    cache: str | None = None
    """How the depth cache served the estimate ("loaded", "built", ...; None: not used)."""

    @property
    def mean_metrics(self) -> dict[str, float] | None:
        """Mean over the views with metrics of l1, rmse, ws_l1, ws_rmse; None if none."""
        rows = [m for m in self.metrics or () if m is not None]
        if not rows:
            return None
        return {key: float(np.mean([getattr(m, key) for m in rows])) for _, key in METRIC_COLUMNS}


def _foreign_entry(out_dir: Path, earlier: dict) -> Path | None:
    """The first file or folder in ``out_dir`` that its earlier `panogrf depth` output
    (``earlier``: its transforms.json) did not write, or None."""
    allowed = {"transforms.json", "images", "depth", "preview"}
    frames = earlier.get("frames")
    for frame in frames if isinstance(frames, list) else []:
        image = frame.get("file_path") if isinstance(frame, dict) else None
        if isinstance(image, str):
            allowed |= {image, f"depth/{Path(image).stem}.png", f"preview/{Path(image).stem}.png"}
    for path in sorted(out_dir.rglob("*")):
        if path.relative_to(out_dir).as_posix() not in allowed:
            return path
    return None


def prepare_out_dir(scene_root: Path, out_dir: Path) -> None:
    """Check ``out_dir``: one-line errors for a missing scene or an output folder that cannot
    or must not be written (the input itself, another scene)."""
    from panogrf.app.scene.folder import TRANSFORMS

    if not scene_root.is_dir():
        raise UserError(f"scene folder not found: {scene_root}")
    if not (scene_root / TRANSFORMS).is_file():
        raise UserError(f"{scene_root}: not a scene folder (no {TRANSFORMS})")
    if out_dir.resolve() == scene_root.resolve():
        raise UserError(
            f"--out {out_dir} is the input scene folder: refusing to overwrite it, choose another"
        )
    if out_dir.exists() and not out_dir.is_dir():
        raise UserError(f"--out {out_dir} exists and is not a folder")
    if out_dir.resolve() in scene_root.resolve().parents:
        raise UserError(
            f"--out {out_dir} holds the input scene folder: it would be replaced, choose another"
        )
    # The output replaces the folder whole: only an earlier output of this command may be there.
    existing = out_dir / TRANSFORMS
    if existing.is_file():
        try:
            earlier = json.loads(existing.read_text(encoding="utf-8"))
            ours = isinstance(earlier, dict) and METADATA_KEY in earlier
        except (ValueError, TypeError, OSError):
            ours = False
        if not ours:
            raise UserError(
                f"{existing} exists and was not written by `panogrf depth`: refusing to overwrite "
                "another scene, choose an empty folder"
            )
        foreign = _foreign_entry(out_dir, earlier)
        if foreign is not None:
            raise UserError(
                f"--out {out_dir} holds {foreign}, which no `panogrf depth` output has: "
                "refusing to replace the folder, move it or choose another"
            )
    else:
        refuse_foreign_folder(out_dir, "panogrf depth", lambda _: False)
    # Nothing is created until the output is written: a run refused later (a scene image
    # missing) or stopped leaves no empty folders behind.
    there = next(p for p in (out_dir, *out_dir.parents) if p.exists())
    if not there.is_dir() or not os.access(there, os.W_OK | os.X_OK):
        raise UserError(f"cannot write to {out_dir}: {there} is not a writable folder")


def _unique_stems(names: list[str]) -> list[str]:
    """Frame names as output file stems; a repeated stem (a/x.png, b/x.png) gets the index, a
    name that is not text (bytes of another encoding) ``view_NNN``: JSON cannot hold it."""
    seen: set[str] = set()
    out = []
    for i, name in enumerate(names):
        name = name if name.isprintable() else f"view_{i:03d}"
        stem = name if name not in seen else f"{name}_{i:03d}"
        seen.add(stem)
        out.append(stem)
    return out


def _metrics(
    depth: torch.Tensor, gt: torch.Tensor | None, d_max: float
) -> tuple[DepthMetrics | None, ...] | None:
    """Per-view metrics of depth [V, 1, H, W] vs gt on 0 < gt <= d_max (metres)."""
    from panogrf.model.metrics import depth_metrics

    if gt is None:
        return None
    rows: list[DepthMetrics | None] = []
    for i in range(depth.shape[0]):
        in_range = gt[i] <= d_max
        if not bool((in_range & (gt[i] > 0)).any()):
            rows.append(None)  # a view without depth map, or only beyond the range
            continue
        rows.append(depth_metrics(depth[i], gt[i], in_range))
    return tuple(rows)


def estimate_scene(
    scene: str | Path | Scene,
    out_dir: str | Path,
    estimator: DepthEstimator,
    mode: DepthMode = DepthMode.FULL,
    *,
    weights: dict[str, str] | None = None,
    cache_dir: str | Path | None = None,
    use_cache: bool = False,
) -> DepthRun:
    """Estimate depth for every view of a scene and write the scene ``out_dir``.

    ``scene`` is a scene folder or a `Scene` loaded with its images (``load_images=True``).
    ``estimator`` must hold the networks of ``mode`` and sits on the device it runs on;
    ``weights`` (network -> file name) is recorded in the output's metadata. ``use_cache``:
    the estimate is read from (or written to) the scene cache in ``cache_dir`` when the
    estimator was loaded from the weights files (`panogrf.app.scene.cache.estimate_cached`).
    Raises `UserError`
    for an invalid scene or an output folder that cannot or must not be written.
    """
    from panogrf.app.files.atomic import atomic_output
    from panogrf.app.files.images import write_depth, write_json_atomic, write_rgb
    from panogrf.app.scene.folder import TRANSFORMS, Scene, load_scene
    from panogrf.app.visualize import colorize_depth

    if mode not in MODES:
        raise ValueError(f"mode must be one of {tuple(map(str, MODES))}, got {mode!r}")
    mode = DepthMode(mode)
    out_dir = Path(out_dir)
    if not isinstance(scene, Scene):
        prepare_out_dir(Path(scene), out_dir)
        scene = load_scene(scene, load_images=True)
    elif scene.images is None:
        raise ValueError("estimate_scene needs a scene loaded with load_images=True")
    else:
        prepare_out_dir(scene.root, out_dir)
    scene_root, data = scene.root, scene.images
    names = [f.name for f in scene.frames]

    device = next(estimator.parameters()).device
    start = time.perf_counter()
    images, c2w = data.images.to(device), data.c2w.to(device)
    cache = None
    if use_cache:
        from panogrf.app.scene.cache import estimate_cached

        est, result = estimate_cached(estimator, images, c2w, mode, cache_dir)
        cache = result.status
    else:
        est = estimator(images, c2w, mode)
    depth = est.depth.float().cpu()  # [V, 1, H, W] metres
    out_of_range = est.out_of_range.cpu()
    seconds = time.perf_counter() - start

    d_max = float(estimator.d_max)
    clamped = [float(x) for x in out_of_range.flatten(1).float().mean(dim=1)]
    sources = [[names[j] for j in src] for src in est.sources]
    stems = _unique_stems(names)
    raw = parse_json((scene_root / TRANSFORMS).read_text(encoding="utf-8-sig"))
    meta = {
        "mode": mode,
        "weights": dict(weights or {}),
        "clamped_at_m": d_max,
        "out_of_range_fraction": dict(zip(names, clamped, strict=True)),
        "sources": dict(zip(names, sources, strict=True)),
        "warnings": list(est.warnings),
    }
    preview_max = float(depth.max())
    frames = []
    try:
        # The whole output is written beside it and swapped in at once: a full disk or a kill
        # leaves the earlier output whole, never views of two runs (issue 57, D1).
        out_dir.parent.mkdir(parents=True, exist_ok=True)
        with atomic_output(out_dir, directory=True) as tmp:
            for sub in ("images", "depth", "preview"):
                (tmp / sub).mkdir()
            for i, (frame, stem) in enumerate(zip(scene.frames, stems, strict=True)):
                image_file = f"images/{stem}{frame.image_path.suffix.lower()}"
                (tmp / image_file).write_bytes(frame.image_path.read_bytes())
                depth_file = f"depth/{stem}.png"
                write_depth(tmp / depth_file, depth[i, 0].cpu().numpy())
                write_rgb(
                    tmp / f"preview/{stem}.png",
                    colorize_depth(depth[i, 0].cpu().numpy(), preview_max),
                )
                # Keep the frame's own extra keys (nerfstudio intrinsics, ...), repoint files.
                frames.append(
                    {**raw["frames"][i], "file_path": image_file, "depth_file_path": depth_file}
                )
            top = {k: v for k, v in raw.items() if k != "frames"}
            write_json_atomic(tmp / TRANSFORMS, {**top, METADATA_KEY: meta, "frames": frames})
    except OSError as exc:
        raise UserError(f"cannot write to {out_dir}: {exc.strerror or exc}") from None

    return DepthRun(
        out_dir=out_dir,
        mode=mode,
        views=tuple(names),
        seconds=seconds,
        d_max=d_max,
        out_of_range_fraction=tuple(clamped),
        sources=tuple(tuple(s) for s in sources),
        warnings=tuple(est.warnings),
        metrics=_metrics(depth, data.depths, d_max),
        cache=cache,
    )


__all__ = [
    "METADATA_KEY",
    "METRIC_COLUMNS",
    "MODES",
    "DepthRun",
    "estimate_scene",
    "prepare_out_dir",
]
