"""Training of the blend of the fused depth with the monocular depth (`panogrf train blend`).

The depth networks and the selector are frozen and shipped. For a seeded sample of the
training scenes, mode "full" runs on the first and last views (each the other's source)
exactly as at preparation, under the same conditions as the selector's recording
(`panogrf.app.train.select.fusion_runs`: the monocular network out of its domain on some scenes,
camera corruptions on others), and records per view what the blend sees
(`panogrf.model.blend.blend_features`) and the two depths it blends. The records are cached
beside the data, keyed by the depth weights, the scenes and these settings.

The loss is the L1 (metres, canonical world) of the blended depth against the truth. The log
reports, on held-back scenes, the L1 of the fused depth, of the monocular depth, of the blend
and of the better of the two per pixel.
"""

from __future__ import annotations

import json

import torch
from torch import Tensor

from panogrf.app.errors import UserError
from panogrf.app.files.atomic import save_tensors_atomic
from panogrf.app.train.configs import TrainBlendConfig
from panogrf.app.train.loop import Steps, save_trained
from panogrf.app.train.select import (
    cached_record,
    canonical_truth,
    fusion_runs,
    recorded_split,
    recording_path,
)
from panogrf.model.blend import FEATURES, BlendConfig, DepthBlend
from panogrf.model.depth import DepthEstimator

#: What `record_scenes` returns (and caches).
RECORD_KEYS = ("features", "logs", "truth")


@torch.no_grad()
def record_scenes(
    estimator: DepthEstimator, data, indices: list[int], cfg: TrainBlendConfig, log=print
) -> dict[str, Tensor]:
    """The blend's inputs for the first and last views of the scenes ``indices``:
    {"features": [N, FEATURES, h, w] float16, "logs": [N, 2, h, w] the fused and the mono
    depth, "truth": [N, h, w] (all log metres in the canonical world; truth nan: unknown)}.
    Cached in the data folder (written to a temporary file and renamed)."""
    settings = [cfg.shift, cfg.photometric, cfg.heights, cfg.height, cfg.seed, FEATURES]
    settings += cfg.extra_key
    path = recording_path(cfg.data, "blend", estimator, [data.names[i] for i in indices], settings)
    cached = cached_record(path, RECORD_KEYS, FEATURES, "blend", log)
    if cached is not None:
        return cached
    feats, logs, truth = [], [], []
    for i, records in fusion_runs(estimator, data, indices, cfg, "blend_record"):
        for entry in records:
            feats.append(entry["features"].half())
            logs.append(entry["logs"])
            truth.append(canonical_truth(estimator, data, i, entry, entry["logs"].shape[-2:]))
    if not feats:
        raise UserError(f"{cfg.data}: no scene has two views far enough apart to fuse")
    out = {"features": torch.stack(feats), "logs": torch.stack(logs), "truth": torch.stack(truth)}
    save_tensors_atomic(path, out)
    return out


def blend_l1(log_depth: Tensor, truth: Tensor) -> Tensor:
    """Mean L1 (metres) of log depth [N, h, w] against the truth [N, h, w] (nan: unknown)."""
    ok = ~torch.isnan(truth)
    return (torch.exp(log_depth) - torch.exp(truth))[ok].abs().mean()


def _figures(net: DepthBlend, rec: dict[str, Tensor]) -> dict:
    logs, truth = rec["logs"], rec["truth"]
    with torch.no_grad():
        blended = net.blend(rec["features"].float(), logs[:, 0], logs[:, 1])
    gt = torch.exp(truth)
    err = (torch.exp(logs) - gt[:, None]).abs()
    best = torch.where(err[:, 0] <= err[:, 1], logs[:, 0], logs[:, 1])
    return {
        "l1_fused": round(float(blend_l1(logs[:, 0], truth)), 4),
        "l1_mono": round(float(blend_l1(logs[:, 1], truth)), 4),
        "l1_blend": round(float(blend_l1(blended, truth)), 4),
        "l1_better_per_pixel": round(float(blend_l1(best, truth)), 4),
    }


def train_blend(cfg: TrainBlendConfig, estimator: DepthEstimator, log=print) -> dict:
    """Record the fusion on the sampled scenes, then train the blend on it."""
    # The unblended fusion is recorded; the estimator (shared, cached) gets its blend back.
    train, val, gen = recorded_split(cfg, estimator, record_scenes, "blend", log)
    net = DepthBlend(BlendConfig(rows=train["features"].shape[-2]))
    log(
        f"blend ({sum(p.numel() for p in net.parameters())} parameters): "
        f"{train['features'].shape[0]} training views, {val['features'].shape[0]} held back"
    )
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    steps = Steps(opt, cfg.steps, cfg.lr, cfg.log_every, log, lambda m: f"L1 {float(m):.4f} m")
    n = train["features"].shape[0]
    for _ in steps:
        idx = torch.randint(n, (min(cfg.batch, n),), generator=gen)
        # Each view turned by its own random yaw (everything wraps in width).
        shift = int(torch.randint(train["features"].shape[-1], (1,), generator=gen))
        feats = train["features"][idx].float().roll(shift, -1)
        logs = train["logs"][idx].roll(shift, -1)
        truth = train["truth"][idx].roll(shift, -1)
        if torch.isnan(truth).all():
            continue
        loss = blend_l1(net.blend(feats, logs[:, 0], logs[:, 1]), truth)
        steps.update(loss)
    net.eval()
    figures = _figures(net, val)
    figures.update({"steps": cfg.steps, "seconds": steps.seconds})
    log(f"final (held-back scenes, canonical world): {json.dumps(figures)}")
    save_trained(net, cfg, figures)
    return figures
