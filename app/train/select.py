"""Training of the fusion's hypothesis selector (`panogrf train select`).

The depth networks are frozen and shipped. For a seeded sample of the training scenes, mode
"full" runs on the first and last views (each the other's source) exactly as at preparation
(canonical world, both MVS networks, the photometric sweep), and records per view what the
selector sees (`panogrf.model.select.selection_features`) and where the sweep's search from
each hypothesis ends. On a fraction of the scenes (``shift``) the monocular network sees its
input out of its domain (`out_of_domain`: blended with another scene's panoramas), so that its
prior, and the mono-guided depth with it, is wrong as on a real capture; when asked, on a
fraction of the others (``features_shift``) only its features are those of the input out of
its domain, its depth right, which leads the mono-guided network astray as a real image's
features do; on some the views are put through `photometric` (as a real capture's
exposure changes). The records are cached beside the data, keyed by the depth weights, the scenes
and these settings.

The label of a pixel is which search end is nearer the truth (in the canonical world), its
weight how much nearer (metres, capped): the loss is the weighted binary cross-entropy, so the
pixels where the choice matters most count most. The log reports, on held-back scenes, the L1
of the chosen end (at the selector's 128 rows, before the median) by the photometric rule, by
the selector and by the truth.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import torch
import torch.nn.functional as F
from safetensors.torch import load_file
from torch import Tensor
from tqdm import tqdm

from panogrf.app.errors import UserError
from panogrf.app.files.atomic import save_tensors_atomic
from panogrf.app.train.augment import mono_out_of_domain, mono_wrong_heights, photometric
from panogrf.app.train.configs import FusionRecordingConfig, TrainSelectConfig
from panogrf.app.train.data import load_triplets
from panogrf.app.train.loop import Steps, held_back, save_trained
from panogrf.app.train.renderer import _weights_key
from panogrf.model.depth import DepthEstimator, DepthMode
from panogrf.model.select import CONSISTENCY, FEATURES, HypothesisSelector, SelectorConfig

#: What `record_scenes` returns (and caches).
RECORD_KEYS = ("features", "ends", "truth", "rule")
#: Channels per pixel of a record's features: the selection features, then the consistency.
RECORD_CHANNELS = FEATURES + CONSISTENCY


def recording_path(
    data_folder: Path, prefix: str, estimator: DepthEstimator, names: list[str], settings: list
) -> Path:
    """Where a recording of the fusion is cached in the data folder: ``.PREFIX_KEY.safetensors``,
    KEY hashing the depth weights, the scenes ``names`` and the recording's ``settings``."""
    h = hashlib.sha256(_weights_key(estimator).encode())
    h.update("\n".join(names).encode())
    h.update(json.dumps(settings).encode())
    return Path(data_folder) / f".{prefix}_{h.hexdigest()[:16]}.safetensors"


@torch.no_grad()
def record_scenes(
    estimator: DepthEstimator, data, indices: list[int], cfg: TrainSelectConfig, log=print
) -> dict[str, Tensor]:
    """Selector inputs and labels for the first and last views of the scenes ``indices``:
    {"features": [N, C, h, w] float16, "ends": [N, 2, h, w], "truth": [N, h, w] log metres in
    the canonical world (nan: unknown), "rule": [N, h, w] the share of each pooled pixel the
    photometric rule gives the unguided depth}. Cached in the data folder."""
    settings = [cfg.shift, cfg.photometric, cfg.height, cfg.seed, RECORD_CHANNELS]
    settings += [cfg.heights] if cfg.heights else []
    settings += cfg.extra_key
    path = recording_path(cfg.data, "select", estimator, [data.names[i] for i in indices], settings)
    cached = cached_record(path, RECORD_KEYS, RECORD_CHANNELS, "selector", log)
    if cached is not None:
        return cached
    feats, ends, truth, rules = [], [], [], []
    for i, records in fusion_runs(estimator, data, indices, cfg, "record"):
        for entry in records:
            f = entry["features"]
            feats.append(f.half())
            ends.append(entry["ends"])
            rules.append(entry["rule"])
            truth.append(canonical_truth(estimator, data, i, entry, f.shape[-2:]))
    if not feats:
        raise UserError(f"{cfg.data}: no scene has two views far enough apart to fuse")
    out = {
        "features": torch.stack(feats),
        "ends": torch.stack(ends),
        "truth": torch.stack(truth),
        "rule": torch.stack(rules),
    }
    save_tensors_atomic(path, out)
    return out


def cached_record(path: Path, keys, channels: int, what: str, log) -> dict[str, Tensor] | None:
    """The recording cached in ``path`` when it holds exactly ``keys`` with features of
    ``channels``; None (and a log line) when it is absent, of another format or unreadable:
    a broken cache is rebuilt, never trusted."""
    if not path.exists():
        return None
    try:
        cached = load_file(str(path))
        if set(cached) == set(keys) and cached["features"].shape[1] == channels:
            return cached
        log(f"{what} cache {path.name} holds {sorted(cached)}: rebuilding")
    except Exception as exc:
        log(f"{what} cache {path.name} unreadable ({exc}): rebuilding")
    return None


def canonical_truth(estimator: DepthEstimator, data, i: int, entry: dict, size) -> Tensor:
    """The true depth [h, w] of the view of scene ``i`` that the record ``entry`` is of (its
    "view": 0 the first, 1 the last), at ``size``, in log metres of the canonical world
    (``entry["scale"]``); nan where unknown or beyond the depth range."""
    v = (0, 2)[entry["view"]]
    gt = F.interpolate(data.depths[i, v][None, None], size=size, mode="nearest")
    gt = gt[0, 0] * entry["scale"]
    ok = (gt > 0) & (gt <= estimator.d_max * entry["scale"])
    return torch.where(ok, torch.log(gt.clamp(min=1e-3)), float("nan"))


def fusion_runs(
    estimator: DepthEstimator, data, indices: list[int], cfg: FusionRecordingConfig, attr: str
):
    """Mode "full" on the first and last views of each scene of ``indices`` recording into
    a new list as the estimator's tap ``attr`` ("record": the selector's, "blend_record": the
    blend's), under ``cfg``'s seeded conditions (``photometric``, ``shift``,
    ``heights`` and ``features_shift`` fractions, ``seed``): yields (scene index, the
    records)."""
    gen = torch.Generator().manual_seed(cfg.seed)
    for n, i in enumerate(tqdm(indices, desc="recording the fusion", unit="scene")):
        images = data.images[i, [0, 2]].float() / 255.0
        if float(torch.rand(1, generator=gen)) < cfg.photometric:
            images = photometric(images, gen)
        c2w = data.c2w[i, [0, 2]]
        shifted = float(torch.rand(1, generator=gen)) < cfg.shift
        # Drawn only when asked for, so that runs without them record what they always did.
        heights = cfg.heights > 0 and float(torch.rand(1, generator=gen)) < cfg.heights
        features = (
            cfg.features_shift > 0 and float(torch.rand(1, generator=gen)) < cfg.features_shift
        )
        partner = data.images[indices[(n + 1) % len(indices)], [0, 2]].float() / 255.0
        records: list[dict] = []
        stages = []  # around the monocular network, each around the one before
        if shifted or features:
            stages.append(mono_out_of_domain(partner, gen, features_only=not shifted))
        if heights:
            stages.append(mono_wrong_heights(gen, shared=cfg.heights_shared))
        estimator(images, c2w, DepthMode.FULL, mono_stages=stages, **{attr: records})
        yield i, records


def recorded_split(
    cfg: FusionRecordingConfig, estimator: DepthEstimator, record, without: str, log
):
    """(records of the seeded sample of ``cfg.scenes`` training scenes, records of the
    held-back ones, the generator that drew the sample, to go on with): ``record(estimator,
    data, indices, cfg, log)`` runs on an estimator without its part ``without`` ("selector",
    "blend"), sharing the other networks."""
    torch.manual_seed(cfg.seed)
    data = load_triplets(cfg.data, cfg.height, cfg.limit_scenes)
    train_idx, val_idx = held_back(len(data), cfg.val_scenes)
    gen = torch.Generator().manual_seed(cfg.seed)
    pick = train_idx[torch.randperm(len(train_idx), generator=gen)[: cfg.scenes]]
    estimator = estimator.configured(**{without: None})
    train = record(estimator, data, sorted(pick.tolist()), cfg, log)
    val = record(estimator, data, val_idx.tolist(), cfg, log)
    return train, val, gen


def _labels(ends: Tensor, truth: Tensor, cap: float) -> tuple[Tensor, Tensor]:
    """(label [N, h, w]: 1 where the unguided search ends nearer the truth, weight)."""
    gt = torch.exp(truth)
    err = (torch.exp(ends) - gt[:, None]).abs()  # [N, 2, h, w]
    label = (err[:, 1] < err[:, 0]).float()
    weight = (err[:, 0] - err[:, 1]).abs().clamp(max=cap)
    weight = torch.where(torch.isnan(truth), torch.zeros_like(weight), weight)
    return label, weight


def choice_l1(ends: Tensor, truth: Tensor, choice: Tensor) -> float:
    """Mean L1 (metres, canonical world) of the search end ``choice`` [N, h, w] picks."""
    end = torch.exp(ends.gather(1, choice[:, None].long())[:, 0])
    ok = ~torch.isnan(truth)
    return float((end - torch.exp(truth))[ok].abs().mean())


def _figures(net: HypothesisSelector, rec: dict[str, Tensor]) -> dict:
    feats, ends, truth = rec["features"].float(), rec["ends"], rec["truth"]
    with torch.no_grad():
        chosen = (net(feats)[:, 0] > 0).long()
    rule = (rec["rule"] > 0.5).long()  # the sweep's own rule, pooled to the selector's rows
    oracle = _labels(ends, truth, 1.0)[0].long()  # the search end nearer the truth
    return {
        "l1_rule": round(choice_l1(ends, truth, rule), 4),
        "l1_selector": round(choice_l1(ends, truth, chosen), 4),
        "l1_truth": round(choice_l1(ends, truth, oracle), 4),
        "l1_guided": round(choice_l1(ends, truth, torch.zeros_like(oracle)), 4),
        "l1_unguided": round(choice_l1(ends, truth, torch.ones_like(oracle)), 4),
    }


def train_selector(cfg: TrainSelectConfig, estimator: DepthEstimator, log=print) -> dict:
    """Record the fusion on the sampled scenes, then train the selector on it."""
    # The rule's fusion is recorded; the estimator (shared, cached) gets its selector back.
    train, val, gen = recorded_split(cfg, estimator, record_scenes, "selector", log)
    net = HypothesisSelector(
        SelectorConfig(
            rows=train["features"].shape[-2], context=cfg.context, consistency=cfg.consistency
        )
    )
    log(
        f"selector ({sum(p.numel() for p in net.parameters())} parameters): "
        f"{train['features'].shape[0]} training views, {val['features'].shape[0]} held back"
    )
    label, weight = _labels(train["ends"], train["truth"], cfg.cap)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    steps = Steps(opt, cfg.steps, cfg.lr, cfg.log_every, log, lambda m: f"loss {float(m):.4f}")
    n = train["features"].shape[0]
    for _ in steps:
        idx = torch.randint(n, (min(cfg.batch, n),), generator=gen)
        feats = train["features"][idx].float()
        # Each view turned by its own random yaw (the features wrap in width).
        shift = int(torch.randint(feats.shape[-1], (1,), generator=gen))
        feats = feats.roll(shift, -1)
        y, w = label[idx].roll(shift, -1), weight[idx].roll(shift, -1)
        logit = net(feats)[:, 0]
        bce = F.binary_cross_entropy_with_logits(logit, y, reduction="none")
        loss = (bce * w).sum() / w.sum().clamp(min=1e-6)
        steps.update(loss)
    net.eval()
    figures = _figures(net, val)
    figures.update({"steps": cfg.steps, "seconds": steps.seconds})
    log(f"final (held-back scenes, chosen search end, canonical world): {json.dumps(figures)}")
    save_trained(net, cfg, figures)
    return figures
