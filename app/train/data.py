"""Synthetic triplets in memory, at the networks' working resolution, for training and evaluation.

A dataset folder (from `panogrf dataset make`) is loaded once: images as uint8, depths as
float32 metres, poses as float32. Depth is downsampled by averaging 2x2 blocks whose depths
agree (within 5 %) and marked unknown (0) where they do not, so depth edges never become
averaged "flying" values.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import Tensor
from tqdm import tqdm

from panogrf.app.errors import UserError
from panogrf.app.files.images import read_depth, read_rgb
from panogrf.app.scene.datasets import read_index_data
from panogrf.app.train.pack import is_pack, read_packs


def downsample_depth(depth: np.ndarray, factor: int) -> np.ndarray:
    """[H, W] metres -> [H/f, W/f]: block means where the block agrees within 5 %, else 0."""
    if factor == 1:
        return depth
    h, w = depth.shape
    blocks = depth.reshape(h // factor, factor, w // factor, factor).transpose(0, 2, 1, 3)
    blocks = blocks.reshape(h // factor, w // factor, -1)
    lo, hi = blocks.min(-1), blocks.max(-1)
    ok = (lo > 0) & (hi <= lo * 1.05)
    return np.where(ok, blocks.mean(-1), 0.0).astype(np.float32)


@dataclass
class TripletSet:
    """Scenes of three views each: images [N, 3, 3, H, W] uint8, depths [N, 3, H, W], c2w."""

    images: Tensor  # uint8 [N, 3, 3, H, W]
    depths: Tensor  # float32 [N, 3, H, W], 0 = unknown
    c2w: Tensor  # float32 [N, 3, 4, 4]
    baselines: Tensor  # float32 [N] first-to-last distance
    names: list[str]

    def __len__(self) -> int:
        return self.images.shape[0]

    def subset(self, idx) -> TripletSet:
        idx = torch.as_tensor(idx)
        return TripletSet(
            self.images[idx],
            self.depths[idx],
            self.c2w[idx],
            self.baselines[idx],
            [self.names[int(i)] for i in idx],
        )


def load_triplets(
    root: str | Path,
    height: int,
    limit: int | None = None,
    start: int = 0,
    depth: bool = True,
) -> TripletSet:
    """Load every scene folder listed in ``root/dataset.json`` at ``height`` x ``2 height``, or
    the scenes of a pack file or a folder of packs (`panogrf.app.train.pack`). ``start`` and
    ``limit``: the scenes from index ``start`` on, at most ``limit`` of them. ``depth`` False:
    the caller never reads the true depth, so colour-only packs are accepted (their depth is
    zeros, unknown)."""
    root = Path(root)
    if is_pack(root):
        if start:
            raise UserError(f"{root}: a pack is read from its first scene")
        return read_packs(root, height, limit, depth)
    index_path = root / "dataset.json"
    if not index_path.exists():
        raise UserError(f"{root}: no dataset.json (make one with `panogrf dataset make`)")
    entries = read_index_data(index_path)["scenes"][start:][:limit]
    if not entries:
        raise UserError(f"{index_path}: lists no scenes")
    imgs, deps, poses, base, names = [], [], [], [], []
    for entry in tqdm(entries, desc=f"loading {root.name}", unit="scene", leave=False):
        folder = root / entry["folder"]
        meta = _transforms(folder / "transforms.json")
        frames = meta["frames"]
        if len(frames) != 3:
            raise UserError(f"{folder}: expected three views, found {len(frames)}")
        src_h = int(meta["h"])
        if src_h % height:
            raise UserError(
                f"{folder}: its {src_h} rows cannot be averaged to --height {height} (the "
                "scenes' rows must be a multiple of it)"
            )
        f = src_h // height
        view_imgs, view_deps = [], []
        for frame in frames:
            rgb = read_rgb(folder / frame["file_path"])
            if f > 1:
                rgb = cv2.resize(rgb, (2 * height, height), interpolation=cv2.INTER_AREA)
            view_imgs.append(rgb.transpose(2, 0, 1))
            view_deps.append(downsample_depth(read_depth(folder / frame["depth_file_path"]), f))
        imgs.append(np.stack(view_imgs))
        deps.append(np.stack(view_deps))
        poses.append(np.array([fr["transform_matrix"] for fr in frames], np.float32))
        base.append(float(np.linalg.norm(poses[-1][2, :3, 3] - poses[-1][0, :3, 3])))
        names.append(entry["folder"])
    return TripletSet(
        torch.from_numpy(np.stack(imgs)),
        torch.from_numpy(np.stack(deps)),
        torch.from_numpy(np.stack(poses)),
        torch.tensor(base),
        names,
    )


def yaw_roll(images: Tensor, depths: Tensor, c2w: Tensor, shift: int) -> tuple:
    """Rotate panoramas about the camera's y axis by ``shift`` columns, adjusting the poses.

    images [..., C, H, W], depths [..., H, W], c2w [..., 4, 4]; the scene stays the same (a
    column shift of s is a yaw of 2 pi s / W), so this is free, exact augmentation.
    """
    width = images.shape[-1]
    angle = 2 * np.pi * shift / width
    c, s = np.cos(angle), np.sin(angle)
    # Pixel u now shows what u - shift showed: lon_new = lon_old + angle. A rotation R_y(a)
    # maps a direction at longitude lon to lon - a, so R_new = R_old R_y(angle).
    rot = torch.tensor([[c, 0, s], [0, 1, 0], [-s, 0, c]], dtype=c2w.dtype)
    new = c2w.clone()
    new[..., :3, :3] = c2w[..., :3, :3] @ rot
    return torch.roll(images, shift, -1), torch.roll(depths, shift, -1), new


def _transforms(path: Path) -> dict:
    """A training scene's transforms.json; a `UserError` naming it when it cannot be read."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise UserError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UserError(f"{path}: not JSON ({exc})") from None
