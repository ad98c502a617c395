"""Training of the depth networks on the synthetic train split (`panogrf train depth`).

Stage ``mono`` trains `MonoDepthNet`; stage ``mvs`` trains `MVSNet` with the monocular network
frozen (as in PanoGRF). Both use the L1 loss weighted by cos(latitude) on pixels whose ground
truth lies inside the depth range. A slice of the *train* split is held back for validation;
the test split is never read here. Weights go to safetensors with their config, the command
line and the final figures in the metadata.
"""

from __future__ import annotations

import copy
import json
import math
from dataclasses import replace
from pathlib import Path

import torch
from torch import Tensor

from panogrf.app.train.augment import (
    corrupt_mono,
    out_of_domain,
    photometric,
    room_factors,
    seen_warped,
    wrong_heights,
)
from panogrf.app.train.configs import TrainDepthConfig
from panogrf.app.train.data import TripletSet, load_triplets, yaw_roll
from panogrf.app.train.loop import Steps, held_back, init_from, save_trained
from panogrf.model.erp import latitude_weights
from panogrf.model.mono import MonoDepthConfig, MonoDepthNet, MonoOutput


def weighted_l1(pred: Tensor, gt: Tensor, d_max: float) -> Tensor:
    """cos(latitude)-weighted L1 over pixels with 0 < gt <= d_max; [B, 1, H, W] inputs."""
    w = latitude_weights(*gt.shape[-2:], device=gt.device, dtype=gt.dtype)
    valid = ((gt > 0) & (gt <= d_max)).to(gt.dtype) * w
    return ((pred - gt).abs() * valid).sum() / valid.sum().clamp(min=1.0)


def _mono_batch(
    data: TripletSet, gen: torch.Generator, batch: int, augment: bool = False
) -> tuple[Tensor, Tensor]:
    n = len(data)
    scene = torch.randint(n, (batch,), generator=gen)
    view = torch.randint(3, (batch,), generator=gen)
    img = data.images[scene, view].float() / 255.0
    dep = data.depths[scene, view][:, None]
    width = img.shape[-1]
    shift = int(torch.randint(width, (1,), generator=gen))
    img, dep = torch.roll(img, shift, -1), torch.roll(dep, shift, -1)
    if torch.rand(1, generator=gen) < 0.5:
        img, dep = img.flip(-1), dep.flip(-1)
    if augment:
        return photometric(img, gen), dep
    # Mild photometric jitter: exposure and white balance.
    gain = 1.0 + 0.2 * (torch.rand(batch, 3, 1, 1, generator=gen) - 0.5)
    img = (img * gain * (0.8 + 0.4 * torch.rand(batch, 1, 1, 1, generator=gen))).clamp(0, 1)
    return img, dep


class _DepthErrors:
    """L1 and RMSE over every validation pixel with 0 < gt <= d_max, pooled."""

    def __init__(self, d_max: float) -> None:
        self.d_max, self.abs, self.sq, self.count = d_max, 0.0, 0.0, 0.0

    def add(self, pred: Tensor, gt: Tensor) -> None:
        diff = (pred - gt)[(gt > 0) & (gt <= self.d_max)]
        self.abs += float(diff.abs().sum())
        self.sq += float((diff**2).sum())
        self.count += diff.numel()

    def figures(self) -> dict:
        return {"val_l1": self.abs / self.count, "val_rmse": math.sqrt(self.sq / self.count)}


@torch.no_grad()
def _validate_mono(net: MonoDepthNet, val: TripletSet, device: str = "cpu") -> dict:
    net.eval()
    errors = _DepthErrors(net.config.d_max)
    for i in range(len(val)):
        pred = net(val.images[i].to(device).float() / 255.0).depth.cpu()
        errors.add(pred, val.depths[i][:, None])
    net.train()
    return errors.figures()


def train_mono(cfg: TrainDepthConfig, log=print) -> dict:
    """Train the 360-degree monocular depth network; returns the final figures."""
    torch.manual_seed(cfg.seed)
    data = load_triplets(cfg.data, cfg.height, cfg.limit_scenes)
    train_idx, val_idx = held_back(len(data), cfg.val_scenes)
    train, val = data.subset(train_idx.tolist()), data.subset(val_idx.tolist())
    log(f"mono: {len(train)} train scenes ({3 * len(train)} panoramas), {len(val)} validation")
    net = MonoDepthNet(MonoDepthConfig(trunk=cfg.trunk))
    init_from(net, cfg.init, log, new=("trunk.", "from_trunk."))
    if cfg.trunk:
        _fill_trunk(net, log)
    net.to(cfg.device)
    if cfg.device != "cpu":
        log(f"training on {cfg.device}")
    opt = torch.optim.Adam([p for p in net.parameters() if p.requires_grad], lr=cfg.lr)
    gen = torch.Generator().manual_seed(cfg.seed)
    steps = Steps(opt, cfg.steps, cfg.lr, cfg.log_every, log)
    for _ in steps:
        img, gt = _mono_batch(train, gen, cfg.batch, cfg.augment)
        img, gt = img.to(cfg.device), gt.to(cfg.device)
        steps.update(weighted_l1(net(img).depth, gt, net.config.d_max))
    figures = _validate_mono(net, val, cfg.device)
    figures.update({"steps": cfg.steps, "seconds": steps.seconds})
    log(f"final (validation scenes of the train split): {json.dumps(figures)}")
    save_trained(net, cfg, figures)
    return figures


def _fill_trunk(net: torch.nn.Module, log) -> None:
    """Copy the bundled ImageNet AlexNet convolutions (LPIPS asset) into the frozen trunk."""
    from panogrf.app.weights.lpips import ASSET_NAME
    from panogrf.app.weights.networks import trunk_tensors

    net.load_state_dict(trunk_tensors(net), strict=False)
    log(f"trunk: {len(net.trunk.convs)} ImageNet AlexNet convolutions from {ASSET_NAME}, frozen")


def _mvs_batch(data: TripletSet, gen: torch.Generator, batch: int, augment: bool = False):
    """Random reference/source pairs of the same scene, each view turned by its own yaw, the
    whole world mirrored half of the time, and mild photometric jitter per view."""
    n = len(data)
    scene = torch.randint(n, (batch,), generator=gen)
    ref = torch.randint(3, (batch,), generator=gen)
    src = (ref + torch.randint(1, 3, (batch,), generator=gen)) % 3
    imgs, deps, poses = [], [], []
    for view in (ref, src):
        img = data.images[scene, view].float() / 255.0
        dep = data.depths[scene, view]
        c2w = data.c2w[scene, view]
        shift = int(torch.randint(img.shape[-1], (1,), generator=gen))
        img, dep, c2w = yaw_roll(img, dep, c2w, shift)
        if augment:
            imgs.append(photometric(img, gen))
        else:
            gain = 1.0 + 0.2 * (torch.rand(batch, 3, 1, 1, generator=gen) - 0.5)
            imgs.append((img * gain).clamp(0, 1))
        deps.append(dep[:, None])
        poses.append(c2w)
    if torch.rand(1, generator=gen) < 0.5:
        # Mirror the world in x: images flip left-right and c2w -> M c2w M, M = diag(-1, 1, 1, 1).
        m = torch.diag(torch.tensor([-1.0, 1.0, 1.0, 1.0]))
        imgs = [i.flip(-1) for i in imgs]
        deps = [d.flip(-1) for d in deps]
        poses = [m @ p @ m for p in poses]
    return imgs[0], imgs[1][:, None], poses[0], poses[1][:, None], deps[0]


class _OnDevice:
    """The frozen monocular network run on ``device`` for CPU inputs, its outputs back on the
    CPU, where the batches are corrupted (a copy of it; the network itself stays put)."""

    def __init__(self, mono: MonoDepthNet, device: str) -> None:
        self.device = device
        self.net = mono if device == "cpu" else copy.deepcopy(mono).to(device)

    def __call__(self, images: Tensor) -> MonoOutput:
        out = self.net(images.to(self.device))
        return MonoOutput(out.depth.cpu(), out.features.cpu())


def load_mono(path: Path) -> MonoDepthNet:
    """The trained monocular network from safetensors, frozen, in eval mode."""
    from panogrf.app.weights.networks import load_mono_weights

    return load_mono_weights(path)


@torch.no_grad()
def _validate_mvs(net, mono, val: TripletSet) -> dict:
    net.eval()
    errors = _DepthErrors(net.config.d_max)
    for i in range(len(val)):
        img, c2w, gt = val.images[i].float() / 255.0, val.c2w[i], val.depths[i][:, None]
        for r, s in ((0, 2), (2, 0)):
            kw = {}
            if net.config.use_mono or net.config.n_mono:
                m = mono(img[r : r + 1])
                kw = {"mono_depth": m.depth, "mono_features": m.features}
            out = net(
                img[r : r + 1], img[s : s + 1][None], c2w[r : r + 1], c2w[s : s + 1][None], **kw
            )
            errors.add(out.depth[0], gt[r])
    net.train()
    return errors.figures()


def train_mvs(cfg: TrainDepthConfig, log=print) -> dict:
    """Train the 360-degree MVS (preset cfg.mvs_preset) with the monocular network frozen."""
    from panogrf.model.depth_config import DepthMode
    from panogrf.model.mvs import PRESETS, MVSNet

    torch.manual_seed(cfg.seed)
    data = load_triplets(cfg.data, cfg.height, cfg.limit_scenes)
    train_idx, val_idx = held_back(len(data), cfg.val_scenes)
    train, val = data.subset(train_idx.tolist()), data.subset(val_idx.tolist())
    mvs_cfg = replace(PRESETS[DepthMode(cfg.mvs_preset)], trunk=cfg.trunk)
    needs_mono = mvs_cfg.use_mono or mvs_cfg.n_mono > 0
    mono = load_mono(cfg.mono_weights) if needs_mono else None
    log(
        f"mvs ({cfg.mvs_preset}: N_mono={mvs_cfg.n_mono}, N_uni={mvs_cfg.n_uni}, "
        f"mono input={mvs_cfg.use_mono}): {len(train)} train scenes, {len(val)} validation"
    )
    net = MVSNet(mvs_cfg)
    init_from(net, cfg.init, log, new=("trunk.", "from_trunk."))
    if cfg.trunk:
        _fill_trunk(net, log)
    dev = cfg.device
    net.to(dev)
    if dev != "cpu":
        log(f"training on {dev}")
    mono_on = _OnDevice(mono, dev) if mono is not None else None
    opt = torch.optim.Adam([p for p in net.parameters() if p.requires_grad], lr=cfg.lr)
    gen = torch.Generator().manual_seed(cfg.seed)
    steps = Steps(opt, cfg.steps, cfg.lr, cfg.log_every, log)
    for _ in steps:
        ref, src, ref_c2w, src_c2w, gt = _mvs_batch(train, gen, cfg.batch, cfg.augment)
        kw = {}
        if mono_on is not None:
            mono_in = ref
            if cfg.mono_shift:
                hit = torch.rand(len(ref), 1, 1, 1, generator=gen) < cfg.mono_shift
                mono_in = torch.where(hit, out_of_domain(ref, gen), ref)
            with torch.no_grad():
                if cfg.mono_warp:
                    up, down = room_factors(gen, len(ref), cfg.mono_warp)
                    m = seen_warped(mono_on, mono_in, up, down)
                else:
                    m = mono_on(mono_in)
            features = m.features
            if cfg.mono_features_shift:
                hit = torch.rand(len(ref), 1, 1, 1, generator=gen) < cfg.mono_features_shift
                with torch.no_grad():
                    other = mono_on(out_of_domain(mono_in, gen)).features
                features = torch.where(hit, other, features)
            mono_depth = corrupt_mono(m.depth, gen, cfg.mono_noise) if cfg.mono_noise else m.depth
            if cfg.mono_heights:
                hit = torch.rand(len(ref), 1, 1, 1, generator=gen) < cfg.mono_heights
                mono_depth = torch.where(hit, wrong_heights(mono_depth, gen), mono_depth)
            kw = {"mono_depth": mono_depth, "mono_features": features}
        kw = {k: t.to(dev) for k, t in kw.items()}
        out = net(ref.to(dev), src.to(dev), ref_c2w.to(dev), src_c2w.to(dev), **kw)
        d_max, gt = mvs_cfg.d_max, gt.to(dev)
        steps.update(weighted_l1(out.depth, gt, d_max) + 0.5 * weighted_l1(out.expected, gt, d_max))
    net.cpu()
    figures = _validate_mvs(net, mono, val)
    figures.update({"steps": cfg.steps, "seconds": steps.seconds})
    log(f"final (validation scenes of the train split): {json.dumps(figures)}")
    save_trained(net, cfg, figures, preset=cfg.mvs_preset)
    return figures
