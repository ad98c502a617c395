"""Training scenes packed into one small file, for a machine the dataset folders cannot reach.

A dataset folder holds 256-row PNGs (about 0.7 MB a scene); the networks train at 128 rows.
A pack holds the scenes already at the working height: each panorama as a JPEG, each depth
map as a 16-bit PNG in steps of ``DEPTH_STEP_M``, and the poses, in one safetensors file
(about 60 kB a scene). The colour is lossy (JPEG quality ``JPEG_QUALITY``, milder than the
training's own corruptions); the depth is within half a step of the folder's, downsampled the
same way (`downsample_depth`). `load_triplets` reads a pack, or a folder of packs, as it
reads a dataset folder.

    panogrf dataset pack --out packs/lit.safetensors --height 128 data/train_pbr data/train_trim_pbr

A colour-only pack (``depth=False``, `panogrf dataset pack --colour-only`) leaves the true
depth out, about two thirds of a pack: the renderer's training never reads it (it renders from
the depth networks' estimates), so at its 256 rows three times the scenes travel in the same
bytes. Read with ``depth=False`` its scenes have no depth (zeros: unknown); a depth training
asks for depth and gets a clear error.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import torch
from safetensors import SafetensorError, safe_open

from panogrf.app.errors import UserError
from panogrf.app.files.atomic import save_tensors_atomic
from panogrf.app.scene.datasets import read_index_data

JPEG_QUALITY = 90
DEPTH_STEP_M = 0.005
FORMAT = "panogrf triplet pack 1"


def _encode(ext: str, pixels: np.ndarray, params: list[int]) -> np.ndarray:
    ok, buf = cv2.imencode(ext, pixels, params)
    if not ok:
        raise ValueError(f"OpenCV cannot encode {ext}")
    return buf.reshape(-1)


def _decode(buf: np.ndarray, flags: int, what: str, height: int | None = None) -> np.ndarray:
    """An encoded image, checked to be ``height`` x 2 ``height`` when given."""
    pixels = cv2.imdecode(buf, flags)
    if pixels is None:
        raise UserError(f"{what}: corrupt image data")
    if height is not None and pixels.shape[:2] != (height, 2 * height):
        raise UserError(f"{what}: size {pixels.shape[:2]}, not {height} rows")
    return pixels


def pack_scenes(
    sources: list[tuple[Path, int, int]], out: Path, height: int, depth: bool = True
) -> dict:
    """Pack scenes of dataset folders into ``out``. ``sources``: (folder, first, count) with
    count -1 for all from first on; ``depth`` False: colour and poses only. Returns a summary
    (scenes, bytes)."""
    from panogrf.app.train.data import load_triplets

    blobs: dict[str, list[np.ndarray]] = {"jpeg": [], "depth": []} if depth else {"jpeg": []}
    c2w, names = [], []
    taken: dict[Path, set[int]] = {}
    for folder, first, count in sources:
        index = Path(folder) / "dataset.json"
        if not index.exists():
            raise UserError(f"{folder}: no dataset.json (make one with `panogrf dataset make`)")
        entries = read_index_data(index)["scenes"]
        stop = len(entries) if count < 0 else first + count
        if first < 0 or stop > len(entries) or first >= stop:
            raise UserError(f"{folder}: has {len(entries)} scenes; cannot take [{first}, {stop})")
        done = taken.setdefault(Path(folder).resolve(), set())
        if again := done & set(range(first, stop)):
            raise UserError(
                f"{folder}: scene {min(again)} listed twice (a training would see it twice, and "
                "a held-back scene among its training scenes); give each scene once"
            )
        done.update(range(first, stop))
        data = load_triplets(folder, height, limit=stop - first, start=first)
        for i in range(len(data)):
            for v in range(3):
                rgb = data.images[i, v].permute(1, 2, 0).numpy()
                blobs["jpeg"].append(
                    _encode(".jpg", rgb[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
                )
                if not depth:
                    continue
                steps = np.round(data.depths[i, v].numpy() / DEPTH_STEP_M)
                blobs["depth"].append(
                    _encode(
                        ".png",
                        steps.clip(0, 65535).astype(np.uint16),
                        [cv2.IMWRITE_PNG_COMPRESSION, 9],
                    )
                )
            c2w.append(data.c2w[i])
            names.append(f"{Path(folder).name}/{data.names[i]}")
    if not names:
        raise UserError("no scenes to pack")
    tensors = {"c2w": torch.stack(c2w)}
    for key, parts in blobs.items():
        tensors[key] = torch.from_numpy(np.concatenate(parts))
        tensors[f"{key}_ends"] = torch.tensor(np.cumsum([len(p) for p in parts]), dtype=torch.int64)
    meta = {
        "format": FORMAT,
        "height": str(height),
        "depth_step_m": str(DEPTH_STEP_M),
        "jpeg_quality": str(JPEG_QUALITY),
        "depth": "yes" if depth else "none",
        "names": json.dumps(names),
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    save_tensors_atomic(out, tensors, meta)
    return {"scenes": len(names), "bytes": out.stat().st_size}


def is_pack(path: Path) -> bool:
    """A pack file, or a folder of packs (``*.safetensors``, no dataset.json)."""
    path = Path(path)
    if path.is_file():
        return path.suffix == ".safetensors"
    return path.is_dir() and not (path / "dataset.json").exists() and bool(_pack_files(path))


def _pack_files(path: Path) -> list[Path]:
    """The packs of a pack file or folder. Hidden files are not packs: the trainings cache
    what they compute from the data beside it (e.g. ``.depth_full_*.safetensors``)."""
    if path.is_file():
        return [path]
    return sorted(p for p in path.glob("*.safetensors") if not p.name.startswith("."))


def read_packs(path: Path, height: int, limit: int | None = None, depth: bool = True):
    """A pack file or a folder of packs as a `TripletSet` (packs in name order). ``depth``
    False: the depth is not read (zeros, unknown), and colour-only packs are accepted."""
    from panogrf.app.train.data import TripletSet

    images, depths, c2w, names = [], [], [], []
    for file in _pack_files(Path(path)):
        if limit is not None and len(names) >= limit:
            break  # the packs after the limit are not read at all
        try:
            with safe_open(str(file), "pt") as f:
                meta = f.metadata() or {}
                tensors = {k: f.get_tensor(k) for k in f.keys()}
        except (SafetensorError, OSError) as exc:
            raise UserError(f"{file}: not a readable pack ({exc})") from None
        if meta.get("format") != FORMAT:
            raise UserError(f"{file}: not a triplet pack (format {meta.get('format')!r})")
        if int(meta["height"]) != height:
            raise UserError(f"{file}: packed at {meta['height']} rows, training asks {height}")
        step = float(meta["depth_step_m"])
        file_names = json.loads(meta["names"])
        n = len(file_names)
        has_depth = meta.get("depth", "yes") != "none"
        if depth and not has_depth:
            raise UserError(
                f"{file}: a colour-only pack (--colour-only), without the true depth this "
                "training needs"
            )
        blobs = {}
        for key in ("jpeg", "depth") if depth else ("jpeg",):
            ends = tensors[f"{key}_ends"].tolist()
            if len(ends) != 3 * n:
                raise UserError(f"{file}: {len(ends)} {key} images for {n} scenes")
            flat = tensors[key].numpy()
            blobs[key] = [flat[a:b] for a, b in zip([0] + ends[:-1], ends, strict=True)]
        for i in range(n):
            if limit is not None and len(names) >= limit:
                break
            views_rgb, views_depth = [], []
            for v in range(3):
                what = f"{file} scene {file_names[i]} view {v}"
                bgr = _decode(blobs["jpeg"][3 * i + v], cv2.IMREAD_COLOR, what, height)
                views_rgb.append(bgr[..., ::-1].transpose(2, 0, 1))
                if depth:
                    dep = _decode(blobs["depth"][3 * i + v], cv2.IMREAD_UNCHANGED, what, height)
                    views_depth.append(dep.astype(np.float32) * step)
            images.append(np.stack(views_rgb))
            if depth:
                depths.append(np.stack(views_depth))
            c2w.append(tensors["c2w"][i])
            names.append(file_names[i])
    if not names:
        raise UserError(f"{path}: holds no packed scenes")
    poses = torch.stack(c2w)
    n = len(names)
    # Without depth, zeros (unknown) that take no memory: one value seen at every index.
    no_depth = torch.zeros(()).expand(n, 3, height, 2 * height)
    return TripletSet(
        torch.from_numpy(np.ascontiguousarray(np.stack(images))),
        torch.from_numpy(np.stack(depths)) if depth else no_depth,
        poses,
        torch.linalg.norm(poses[:, 2, :3, 3] - poses[:, 0, :3, 3], dim=-1),
        names,
    )
