"""Training of the spherical radiance field renderer (`panogrf train renderer`).

The depth networks are frozen (PanoGRF): the estimated depth of every view of every training
scene, for each ordered pair of its views, is computed once and cached beside the dataset,
keyed by the depth weights. Each step takes a few scenes; per scene a target view and two
sources (mostly the middle view from the outer two, as in the evaluation; sometimes an outer
view from the other two, and sometimes a source itself, which teaches reproducing the input),
each view turned by its own random yaw (exact augmentation). Rays of the target are drawn with
probability proportional to cos(latitude) (the panorama's solid angle, as WS-PSNR weighs) and
rendered with both samplings the renderer offers: coarse-to-fine and depth-guided. The loss is
the photometric MSE of the coarse, fine and guided composites.

The depth the renderer trains on is either the depth networks' own estimate of every ordered
pair (``depth="networks"``, fast, every configuration above) or the depth the app renders
with (``depth="shipped"``: mode full with the sweep, the canonical world, the selector and the
preparation's per-scene refinement, `shipped_depths`), a few seconds per scene, so only of the
outer pair: every sample then renders from the outer two views.

On a GPU (``device``) the renderer trains there and the networks' depth is estimated there;
the scenes are drawn, turned and their rays chosen on the CPU with the same generator, so a
run draws the same samples on any device. The data may be a folder of colour-only packs
(`panogrf.app.train.pack`): the true depth is never read.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from pathlib import Path

import torch
from safetensors.torch import load_file
from torch import Tensor
from tqdm import tqdm

from panogrf.app.files.atomic import save_tensors_atomic
from panogrf.app.train.configs import DEPTHS, TrainRendererConfig
from panogrf.app.train.data import TripletSet, load_triplets, yaw_roll
from panogrf.app.train.loop import Steps, held_back, init_from, save_trained
from panogrf.model.depth import DepthEstimator, DepthMode
from panogrf.model.erp import latitude_weights
from panogrf.model.metrics import ws_psnr
from panogrf.model.render_net import PRESETS, RendererNet, RendererPreset
from panogrf.model.splat import proxy_depth
from panogrf.renderer.cache import build_cache
from panogrf.renderer.render import (
    QUALITY,
    Quality,
    Sampling,
    render_panorama,
    render_rays,
    target_rays,
)

PAIRS = ((0, 1), (0, 2), (1, 2))
SAVE_EVERY = 20  # scenes between the shipped depth's partial saves


def _weights_key(estimator: DepthEstimator) -> str:
    h = hashlib.sha256()
    for name, t in sorted(estimator.state_dict().items()):
        h.update(name.encode())
        h.update(t.detach().cpu().float().numpy().tobytes())
    return h.hexdigest()[:16]


@torch.no_grad()
def pair_depths(
    estimator: DepthEstimator, data: TripletSet, root: Path, log=print, device: str = "cpu"
) -> dict[str, Tensor]:
    """Estimated depth of view r with view s as its only source, for every scene and ordered
    pair: {"r{r}s{s}": [N, 1, h, w] float16, on the CPU}, estimated on ``device``. Cached in
    ``root`` keyed by the depth weights and the scenes; the cache is written to a temporary
    file and renamed."""
    # The sweep costs seconds per pair: the renderer trains on the networks' depth alone, in
    # the world as given (the depth its shipped weights were trained on).
    estimator = estimator.configured(sweep=None, canonical=False)
    key = _weights_key(estimator)
    names = hashlib.sha256("\n".join(data.names).encode()).hexdigest()[:8]
    path = root / f".depth_full_{key}_{names}_{estimator.working_height}.safetensors"
    keys = [f"r{r}s{s}" for a, b in PAIRS for r, s in ((a, b), (b, a))]
    if (cached := _read_cache(path, keys, log)) is not None:
        return cached
    out: dict[str, list[Tensor]] = {}
    n = len(data)
    estimator.to(device)
    try:
        for i in tqdm(range(n), desc="estimating depth of the training pairs", unit="scene"):
            imgs = data.images[i].to(device).float() / 255.0
            c2w = data.c2w[i].to(device)
            for a, b in PAIRS:
                depth = estimator(imgs[[a, b]], c2w[[a, b]], DepthMode.FULL).depth.half().cpu()
                out.setdefault(f"r{a}s{b}", []).append(depth[0:1])
                out.setdefault(f"r{b}s{a}", []).append(depth[1:2])
    finally:
        estimator.to("cpu")  # where the caller's estimator was, whatever happened
    result = {k: torch.cat(v) for k, v in out.items()}
    save_tensors_atomic(path, result)
    return result


def _read_cache(path: Path, keys: list[str], log) -> dict[str, Tensor] | None:
    """The cached depths at ``path`` if it holds every key; None if absent or unreadable."""
    if not path.exists():
        return None
    try:
        cached = load_file(str(path))
        if all(k in cached for k in keys):
            return cached
    except Exception as exc:  # a broken cache is rebuilt, never trusted
        log(f"depth cache {path.name} unreadable ({exc}): rebuilding")
    return None


@torch.no_grad()
def shipped_depths(models, data: TripletSet, root: Path, log=print) -> dict[str, Tensor]:
    """The depth the app renders with, of the outer views of every scene, each the other's
    source: {"r0s2", "r2s0": [N, 1, h, w] float16}, h the estimator's working height.

    As `panogrf.renderer.methods.SourceViews` prepares a scene: exposure balanced, mode full
    (sweep, canonical world, selector), then the preparation's refinement. Cached in ``root``
    keyed by every depth weight, the refinement and the scenes (temporary file, renamed)."""
    from panogrf.model.refine import PREPARE_REFINE
    from panogrf.renderer.methods import METHODS, SourceViews

    mode = METHODS["panogrf"].depth_mode
    estimator = models.estimator(mode)
    h = hashlib.sha256(_weights_key(estimator).encode())
    h.update(repr(PREPARE_REFINE).encode())
    names = hashlib.sha256("\n".join(data.names).encode()).hexdigest()[:8]
    height = data.images.shape[-2]
    path = root / f".depth_shipped_{h.hexdigest()[:16]}_{names}_{height}.safetensors"
    keys = ["r0s2", "r2s0"]
    if (cached := _read_cache(path, keys, log)) is not None:
        return cached
    # Minutes of work: every SAVE_EVERY scenes what is done goes to a partial file (written
    # atomically), and a run that was stopped resumes from it.
    partial = path.with_name(path.name.replace(".safetensors", ".partial.safetensors"))
    out: dict[str, list[Tensor]] = {k: [] for k in keys}
    if (done := _read_cache(partial, keys, log)) is not None:
        out = {k: [done[k].clone()] for k in keys}
        log(f"resuming the shipped depth after {len(out['r0s2'][0])} of {len(data)} scenes")
    first = sum(len(t) for t in out["r0s2"])
    for i in tqdm(range(first, len(data)), desc="shipped depth of the outer pairs", unit="scene"):
        imgs = data.images[i, [0, 2]].float() / 255.0
        views = SourceViews(imgs, data.c2w[i, [0, 2]], refine=PREPARE_REFINE)
        depth = views.depth_for(mode, models)
        out["r0s2"].append(depth[0:1].half())
        out["r2s0"].append(depth[1:2].half())
        if (i + 1) % SAVE_EVERY == 0 and i + 1 < len(data):
            save_tensors_atomic(partial, {k: torch.cat(v) for k, v in out.items()})
    result = {k: torch.cat(v) for k, v in out.items()}
    save_tensors_atomic(path, result)
    partial.unlink(missing_ok=True)
    return result


def _row_sampler(height: int, width: int) -> Tensor:
    """Probabilities [H*W] of the target pixels: proportional to cos(latitude)."""
    w = latitude_weights(height, width).reshape(-1)
    return w / w.sum()


def _configuration(gen: torch.Generator, outer_only: bool = False) -> tuple[int, list[int]]:
    """(target view, source views) of one training sample (``outer_only``: the sources are
    always the outer two views)."""
    p = float(torch.rand(1, generator=gen))
    if p < 0.7:
        return 1, [0, 2]
    end = int(torch.randint(2, (1,), generator=gen)) * 2
    if p < 0.9 and not outer_only:
        return end, [v for v in range(3) if v != end]
    return end, [0, 2]


def _scene_sample(data: TripletSet, depths: dict[str, Tensor], i: int, gen: torch.Generator):
    """Target image [3, H, W] and pose, sources' images [2, 3, H, W], poses and depths
    [2, 1, h, w] of scene i, each view turned by its own random yaw."""
    target, sources = _configuration(gen, outer_only="r0s1" not in depths)
    imgs = data.images[i].float() / 255.0  # [3, 3, H, W]
    dep = [depths[f"r{s}s{sources[1 - k]}"][i].float() for k, s in enumerate(sources)]
    ratio = imgs.shape[-1] // dep[0].shape[-1]
    out_imgs, out_c2w, out_dep = [], [], []
    for k, v in enumerate([target, *sources]):
        # A whole number of depth columns, so the image and its depth turn by the same angle.
        small = int(torch.randint(dep[0].shape[-1], (1,), generator=gen))
        img, _, pose = yaw_roll(imgs[v], imgs[v, 0], data.c2w[i, v], small * ratio)
        out_imgs.append(img)
        out_c2w.append(pose)
        if k:
            out_dep.append(torch.roll(dep[k - 1], small, -1))
    return (
        out_imgs[0],
        out_c2w[0],
        torch.stack(out_imgs[1:]),
        torch.stack(out_c2w[1:]),
        torch.stack(out_dep),
    )


@torch.no_grad()
def validate(
    net: RendererNet,
    data: TripletSet,
    depths: dict[str, Tensor],
    height: int,
    device: str = "cpu",
) -> dict:
    """WS-PSNR of the middle view rendered from the outer two: depth-guided sampling on every
    scene, 64 + 64 samples on the first four (slow on a CPU). ``net`` is on ``device``."""
    net.eval()
    scores: dict[Quality, list[float]] = {Quality.FAST: [], Quality.PAPER: []}
    for i in range(len(data)):
        imgs = data.images[i].to(device).float() / 255.0
        c2w = data.c2w[i].to(device)
        dep = torch.stack((depths["r0s2"][i], depths["r2s0"][i])).to(device).float()
        cache = build_cache(net, imgs[[0, 2]], c2w[[0, 2]], dep)
        for q in scores if i < 4 else (Quality.FAST,):
            out = render_panorama(net, cache, c2w[1], height, q)
            gt = torch.nn.functional.interpolate(imgs[1:2], size=(height, 2 * height), mode="area")
            scores[q].append(float(ws_psnr(out.rgb[None], gt)))
    net.train()
    return {f"val_ws_psnr_{q}": sum(v) / len(v) for q, v in scores.items()}


def _describe(mean: Tensor) -> str:
    """The log line's losses: the mean MSE of each term and its PSNR."""
    c, f, g, sf = mean.tolist()
    psnr = [-10 * math.log10(max(x, 1e-10)) for x in (c, f, g, sf)]
    return (
        f"mse coarse {c:.5f} fine {f:.5f} guided {g:.5f} surface {sf:.5f}"
        f"  (PSNR {psnr[0]:.2f}/{psnr[1]:.2f}/{psnr[2]:.2f}/{psnr[3]:.2f})"
    )


def train_renderer(
    cfg: TrainRendererConfig,
    estimator: DepthEstimator | None = None,
    models=None,
    log=print,
) -> dict:
    """Train the renderer (preset cfg.preset) with the depth networks frozen: ``estimator``
    (the mono-guided network alone) gives ``cfg.depth == "networks"``, ``models`` (a
    `panogrf.renderer.methods.Models`; default: the shipped ones) "shipped"."""
    if cfg.depth not in DEPTHS:
        raise ValueError(f"depth must be one of {DEPTHS}, got {cfg.depth!r}")
    torch.manual_seed(cfg.seed)
    # The true depth is never read: colour-only packs will do.
    data = load_triplets(cfg.data, cfg.height, cfg.limit_scenes, depth=False)
    if cfg.depth == "shipped":
        if models is None:
            from panogrf.app.scene.session import default_models

            models = default_models()
        # At the estimator's working height, whatever the images' (as the app renders).
        depths = shipped_depths(models, data, Path(cfg.data), log)
    else:
        if estimator is None:
            raise ValueError('depth "networks" needs the estimator')
        small = _at_height(data, cfg.depth_height)
        depths = pair_depths(estimator, small, Path(cfg.data), log, cfg.device)
    train_idx, val_idx = held_back(len(data), cfg.val_scenes)
    net = RendererNet(PRESETS[RendererPreset(cfg.preset)])
    init_from(net, cfg.init, log)
    net.to(cfg.device)
    log(
        f"renderer ({cfg.preset}, {sum(p.numel() for p in net.parameters())} parameters): "
        f"{len(train_idx)} train scenes, {len(val_idx)} validation"
        + (f", training on {cfg.device}" if cfg.device != "cpu" else "")
    )
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    gen = torch.Generator().manual_seed(cfg.seed)
    probs = _row_sampler(cfg.height, 2 * cfg.height)
    train_sampling = Sampling(n_coarse=cfg.coarse, n_fine=cfg.fine)
    fast = dataclasses.replace(QUALITY[Quality.FAST], surface=cfg.surface_loss)
    steps = Steps(opt, cfg.steps, cfg.lr, cfg.log_every, log, _describe, tuple(net.parameters()))
    for _ in steps:
        losses = torch.zeros(4)
        total = 0.0
        for _ in range(cfg.scenes_per_step):
            i = int(train_idx[int(torch.randint(len(train_idx), (1,), generator=gen))])
            sample = _scene_sample(data, depths, i, gen)
            tgt, tgt_c2w, src, src_c2w, src_dep = (t.to(cfg.device) for t in sample)
            cache = build_cache(net, src, src_c2w, src_dep)
            pix = torch.multinomial(probs, cfg.rays, replacement=False, generator=gen)
            pix = pix.to(cfg.device)
            o, d = target_rays(tgt_c2w, cfg.height, 2 * cfg.height)
            o, d = o[pix], d[pix]
            gt = tgt.reshape(3, -1)[:, pix].T  # [R, 3]
            px = proxy_depth(src_dep, src_c2w, tgt_c2w, cfg.height, 2 * cfg.height)
            paper = render_rays(net, cache, o, d, train_sampling, generator=gen)
            guided = render_rays(
                net, cache, o, d, fast, (px.near.reshape(-1)[pix], px.far.reshape(-1)[pix])
            )
            blended = guided.blended if guided.blended is not None else guided.final
            parts = torch.stack(
                [
                    ((paper.coarse.rgb - gt) ** 2).mean(),
                    ((paper.final.rgb - gt) ** 2).mean(),
                    ((blended.rgb - gt) ** 2).mean(),
                    ((guided.final.rgb - gt) ** 2).mean() if cfg.surface_loss else gt.new_zeros(()),
                ]
            )
            total = total + parts.sum() / cfg.scenes_per_step
            losses += parts.detach().cpu() / cfg.scenes_per_step
        steps.update(total, losses)
    val = data.subset(val_idx)
    val_depths = {k: v[val_idx] for k, v in depths.items()}
    figures = validate(net, val, val_depths, cfg.depth_height, cfg.device)
    figures.update({"steps": cfg.steps, "seconds": steps.seconds})
    rows = cfg.depth_height
    log(f"final (validation scenes of the train split, {rows} rows): {json.dumps(figures)}")
    save_trained(net, cfg, figures, preset=cfg.preset)
    return figures


def _at_height(data: TripletSet, height: int) -> TripletSet:
    """The same scenes with images area-resized to ``height`` (for the depth networks)."""
    if data.images.shape[-2] == height:
        return data
    n, v = data.images.shape[:2]
    imgs = data.images.flatten(0, 1).float()
    small = torch.nn.functional.interpolate(imgs, size=(height, 2 * height), mode="area")
    small = small.round().clamp(0, 255).to(torch.uint8).unflatten(0, (n, v))
    return TripletSet(small, data.depths, data.c2w, data.baselines, data.names)
