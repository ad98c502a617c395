"""How the mono-guided and the unguided MVS depth are best fused: depth error per setting.

    python benchmarks/depth_fusion.py --data data/val_fusion_classic data/val_fusion_home \
        [--gains 0,0.01,0.03] [--out lab/results/depth_fusion.json]

Settings are chosen here on *validation* scenes, freshly generated from the train split's
generator with seeds no training run used (``panogrf dataset make --split train --seed 90000``
classic and ``--seed 90001 --world home``), never on the test split or a real capture. For every
scene the first and last views are estimated, each the other's source, and compared with the
ground truth on 0 < gt <= d_max. Rows: mono; MVS-only (with the sweep); full without fusion
(mono-guided network and the sweep, round 2); full fused in the canonical world
(``DepthConfig.canonical``: the world scaled to the monocular network's sense of size);
full fused with the unguided depth
at each ``switch_gain`` (how much better the unguided depth must match to replace the
mono-guided one); without any sweep; with mode full's search at +-0, +-0.15 and +-0.25 in log
depth (``DepthConfig.fusion_sweep``), each with and without the monocular depth as a third
hypothesis; round 8's rows: the wide search with a stronger prior (far moves need more
evidence), and a median after the sweep (``DepthConfig.median``, in modes full and mvs);
round 14's: the learned choice of each pixel's hypothesis (``DepthEstimator.selector``, when
``depth_select.safetensors`` is among the weights); round 24's: the monocular depth blended
back in (``DepthEstimator.blend``, when ``depth_blend.safetensors`` is).
``--mono-shape`` also measures every setting with the monocular depth made wrong in
shape (`corrupt_mono`), as on real captures; ``--mono-shift`` with the monocular network out of
its domain; ``--mono-heights`` with its ceiling and floor at wrong heights (`wrong_heights`),
drawn per view; ``--mono-room`` the same with one draw for both views (they agree, as a real
capture's views do); ``--mono-warp`` with the monocular network seeing both views as a room of
other heights (`mono_warped_room`: its depth and features wrong together, one draw per scene);
``--mono-true`` with the monocular depth replaced by the true depth and its features left as
computed (what the mono-guided network does with a right prior and the features of this
image: where it is still wrong, the features lead it); ``--mono-features`` with only the
features out of the network's domain (as ``--mono-shift`` draws them), its depth as computed.
Prints a table of mean L1 (m) per dataset and overall, and the seconds per pair; ``--bands``
first a table of each setting's L1 by band of elevation (where it is wrong: the ceiling, the
walls, the floor), pooled over every column's pixels (always in the ``--out`` file).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor

from panogrf.app.train.augment import (
    corrupt_mono,
    mono_depth_changed,
    mono_out_of_domain,
    mono_warped_room,
    mono_wrong_heights,
)
from panogrf.app.train.data import load_triplets
from panogrf.app.weights.networks import (
    BLEND,
    SELECTOR,
    load_blend,
    load_depth_estimator,
    load_selector,
    weights_path,
)
from panogrf.model.depth import DEFAULT_SWEEP
from panogrf.model.metrics import ELEVATION_BANDS, band_key, depth_l1_by_band, depth_metrics
from panogrf.model.sweep import SweepConfig

#: The monocular prior's conditions besides "clean" (`_pairs`'s ``mono``): what each does.
MONO_CONDITIONS = {
    "shape": "its monocular depth wrong in shape, as on real captures",
    "shift": "the monocular network out of its domain, depth and features wrong together",
    "heights": "the monocular depth's ceiling and floor at wrong heights",
    "room": "the monocular depth's ceiling and floor at wrong heights, the same in both views",
    "warp": "the monocular network seeing a room of other heights, depth and features wrong "
    "together, the same in both views",
    "true": "the monocular depth replaced by the true depth, its features as computed",
    "features": "the monocular features of the view out of its domain, its depth as computed",
}

#: The monocular depth as a third hypothesis of the fusion.
MONO = {"mono_hypothesis": True}


def _pairs(
    estimator, data, mode: str, scale: float = 1.0, mono: str = "clean"
) -> tuple[list[float], list[float], dict[str, list[float]]]:
    """L1 of the first and last views, seconds per pair, and the error summed by band of
    elevation with its pixel count ({band: [sum, count]}, `depth_l1_by_band`). ``mono``:
    "clean", "shape" (its depth wrong in shape), "shift" (the network out of its domain) or
    "heights" (its ceiling and floor at wrong heights, `wrong_heights`, seeded per scene) or
    "room" (the same, one draw for both views) or "warp" (the network sees a room of other
    heights, `mono_warped_room`) or "true" (the true depth for the monocular depth, its
    features kept, `_mono_true`) or "features" (the features of the view out of its domain,
    the depth as computed)."""
    errors, seconds = [], []
    bands = {band_key(band): [0.0, 0] for band in ELEVATION_BANDS}
    for i in range(len(data)):
        images = data.images[i, [0, 2]].float() / 255.0
        c2w = data.c2w[i, [0, 2]].clone()
        c2w[:, :3, 3] *= scale
        t0 = time.perf_counter()
        stages = []  # around the monocular network
        if mono == "shape":
            stages.append(_mono_wrong_in_shape(seed=i))
        elif mono in ("shift", "features"):
            partner = data.images[(i + 1) % len(data), [0, 2]].float() / 255.0
            stages.append(_mono_out_of_domain(partner, i, mono == "features"))
        elif mono == "heights":
            stages.append(mono_wrong_heights(torch.Generator().manual_seed(i)))
        elif mono == "room":
            stages.append(mono_wrong_heights(torch.Generator().manual_seed(i), shared=True))
        elif mono == "warp":
            stages.append(mono_warped_room(torch.Generator().manual_seed(i)))
        elif mono == "true":
            stages.append(_mono_true(estimator, data.depths[i, [0, 2]] * scale))
        est = estimator(images, c2w, mode, mono_stages=stages)
        seconds.append(time.perf_counter() - t0)
        for k, v in enumerate((0, 2)):
            gt = data.depths[i, v] * scale
            mask = (gt > 0) & (gt <= estimator.d_max)
            errors.append(float(depth_metrics(est.depth[k, 0], gt, mask).l1))
            for key, (total, count) in depth_l1_by_band(est.depth[k, 0], gt, mask).items():
                bands[key][0] += total
                bands[key][1] += count
    return errors, seconds, bands


def _mono_true(estimator, truth: Tensor):
    """A stage: the monocular depth of the views is ``truth`` [V, H, W] (metres) resized
    to the network's rows (nearest), its own value kept where the truth is missing or beyond
    ``d_max``; the features stay as computed."""

    def change(depth: Tensor) -> Tensor:
        if depth.shape[0] != truth.shape[0]:
            raise ValueError(
                f"the true depth has {truth.shape[0]} views, the call {depth.shape[0]}"
            )
        gt = F.interpolate(truth[:, None].float(), size=depth.shape[-2:], mode="nearest")
        ok = (gt > 0) & (gt <= estimator.d_max)
        return torch.where(ok, gt, depth)

    return mono_depth_changed(change)


def _mono_wrong_in_shape(seed: int):
    """A stage: the monocular network's depth made wrong as on real rooms: smooth regions
    off by up to +-40 % and a global scale of 0.7-1.4x (`corrupt_mono`, every view), seeded."""
    gen = torch.Generator().manual_seed(seed)
    return mono_depth_changed(lambda depth: corrupt_mono(depth, gen, p=1.0))


def _mono_out_of_domain(partner, seed: int, features_only: bool = False):
    """A stage: the monocular network sees every view blended (weight 0.35-0.55) with
    ``partner``'s panoramas [V, 3, H, W] (another scene), turned by a seeded random yaw: its
    depth and features are wrong together (`out_of_domain`, training's ``--mono-shift``), or
    only its features (``features_only``, training's ``--mono-features-shift``)."""
    gen = torch.Generator().manual_seed(seed)
    return mono_out_of_domain(partner, gen, features_only)


def _base(estimator):
    """The settings each row starts from (the canonical world off: rows name what they add)."""
    return estimator.configured(
        fuse=True,
        switch_gain=0.0,
        canonical=False,
        mono_hypothesis=False,
        selector=None,
        select_margin=0.0,
        sweep=DEFAULT_SWEEP,
        fusion_sweep=DEFAULT_SWEEP,
        median=1,
        blend=None,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--gains", default="0,0.01,0.03")
    parser.add_argument(
        "--scales",
        default="1",
        help="world scales: every scene also measured with its translations and true depth "
        "times each (the same images: a room of another size than the monocular network "
        "learned, which it cannot tell)",
    )
    parser.add_argument(
        "--settings",
        default="",
        help="only settings whose name contains one of these |-separated parts (names hold "
        "commas); a part starting with = must match a name exactly (=mono: only the row 'mono')",
    )
    # The monocular prior's conditions, each a column 'DATA mono-NAME' measured at scale 1.
    for name, what in MONO_CONDITIONS.items():
        parser.add_argument(
            f"--mono-{name}",
            choices=("no", "also", "only"),
            default="no",
            help=f"measure every scene (at scale 1) also / only with {what} "
            f"(column 'DATA mono-{name}')",
        )
    parser.add_argument(
        "--blend",
        type=Path,
        nargs="*",
        default=[],
        help="further blend weights (depth_blend.safetensors files), each a row of the shipped "
        "setting with that blend, named after its folder",
    )
    parser.add_argument(
        "--bands",
        action="store_true",
        help="also print each setting's L1 by band of elevation (the ceiling, walls, floor), "
        "pooled over the pixels of every column (always written to --out)",
    )
    parser.add_argument("--threads", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    estimator = load_depth_estimator(("full", "mvs"))
    wide = {"fusion_sweep": DEFAULT_SWEEP}  # mode full's sweep up to round 6
    canonical = {"canonical": True}
    settings: list[tuple[str, str, dict]] = [
        ("mono", "mono", {}),
        ("mvs", "mvs", {}),
        ("mvs, no sweep", "mvs", {"sweep": None}),
        ("full, no sweep", "full", {"sweep": None}),
        ("full, canonical world, no sweep", "full", canonical | {"sweep": None}),
        ("full, no fusion", "full", wide | {"fuse": False}),
        ("full, fused, mono aligned to MVS", "full", wide | {"guide": "aligned"}),
        ("full, fused, guided by the MVS depth", "full", wide | {"guide": "mvs"}),
        ("full, fused, canonical world (round 6, shipped)", "full", wide | canonical),
        ("full, fused, canonical world, mono hypothesis", "full", wide | canonical | MONO),
    ]
    for span, n in ((0.0, 1), (0.15, 7), (0.25, 11)):
        search = {"fusion_sweep": SweepConfig(candidates=n, span=span)}
        name = f"full, fused, search +-{span:g}, canonical world"
        settings.append((name, "full", search | canonical))
        settings.append((f"{name}, mono hypothesis", "full", search | canonical | MONO))
    # Round 8: the wide search with a stronger prior (far moves need more evidence).
    for prior in (0.05, 0.1):
        name = f"full, fused, search +-0.5, prior {prior:g}, canonical world"
        settings.append((name, "full", {"fusion_sweep": SweepConfig(prior=prior)} | canonical))
    # Round 8: the sweep's speckle taken out by a median.
    for k in (5, 7, 9):
        name = f"full, fused, canonical world, median {k}"
        settings.append((name, "full", wide | canonical | {"median": k}))
        settings.append((f"mvs, median {k}", "mvs", {"median": k}))
    # Round 14: the learned choice between the two hypotheses (`panogrf.model.select`), when
    # its weights are there.
    if weights_path(SELECTOR).exists():
        selector = load_selector(weights_path(SELECTOR))
        for k in (1, 5, 7, 9):
            name = f"full, fused, canonical world, median {k}, selector"
            settings.append((name, "full", wide | canonical | {"median": k, "selector": selector}))
        # Round 15: where the selector is unsure, the rule's per-pixel choice (for the median
        # to vote on).
        for margin in (0.1, 0.2):
            name = f"full, fused, canonical world, median 7, selector, margin {margin:g}"
            attrs = {"median": 7, "selector": selector, "select_margin": margin}
            settings.append((name, "full", wide | canonical | attrs))
        # Round 24: the monocular depth blended back in (`panogrf.model.blend`), when its
        # weights are there.
        blends = [("", weights_path(BLEND))] if weights_path(BLEND).exists() else []
        blends += [(f" {path.parent.name}", path) for path in args.blend]
        for suffix, path in blends:
            attrs = {"median": 7, "selector": selector, "select_margin": 0.1}
            attrs["blend"] = load_blend(path)
            name = f"full, fused, canonical world, median 7, selector, margin 0.1, blend{suffix}"
            settings.append((name, "full", wide | canonical | attrs))
            if not suffix:
                # Round 28: the shipped chain in the metric world (no canonical world).
                metric = name.replace("canonical world", "metric world")
                settings.append((metric, "full", wide | attrs))
    for g in (float(x) for x in args.gains.split(",")):
        settings.append((f"full, fused, switch {g:g}", "full", {"fuse": True, "switch_gain": g}))
    if args.settings:
        keep = args.settings.split("|")
        settings = [
            s
            for s in settings
            if any(s[0] == k[1:] if k.startswith("=") else k in s[0] for k in keep)
        ]
    scales = [float(x) for x in args.scales.split(",")]
    results: dict[str, dict] = {}
    columns: list[str] = []
    asked = {name: getattr(args, f"mono_{name}") for name in MONO_CONDITIONS}
    monos = [] if "only" in asked.values() else ["clean"]
    monos += [name for name, value in asked.items() if value != "no"]
    runs = [(f, s, m) for f in args.data for s in scales for m in monos if m == "clean" or s == 1]
    for folder, scale, mono in runs:
        data = load_triplets(folder, 256)
        column = folder.name if scale == 1 else f"{folder.name} x{scale:g}"
        column += f" mono-{mono}" if mono != "clean" else ""
        columns.append(column)
        for name, mode, attrs in settings:
            errors, seconds, bands = _pairs(
                _base(estimator).configured(**attrs), data, mode, scale, mono
            )
            row = results.setdefault(name, {"l1": {}, "seconds": [], "bands": {}})
            row["l1"][column] = statistics.fmean(errors)
            row["seconds"] += seconds
            row["bands"][column] = bands
            print(f"{column} {name}: L1 {statistics.fmean(errors):.4f}", flush=True)
    names = columns
    lines = [
        "| setting | " + " | ".join(names) + " | mean | s / pair |",
        "|---" * (len(names) + 3) + "|",
    ]
    band_lines = [
        "| setting (L1 by band of elevation, pixels of every column pooled) | "
        + " | ".join(f"{hi}..{lo}" for hi, lo in ELEVATION_BANDS)
        + " |",
        "|---" * (len(ELEVATION_BANDS) + 1) + "|",
    ]
    for name, row in results.items():
        row["mean_l1"] = statistics.fmean(row["l1"].values())
        row["median_seconds"] = statistics.median(row.pop("seconds"))
        cells = " | ".join(f"{row['l1'][n]:.4f}" for n in names)
        lines.append(f"| {name} | {cells} | {row['mean_l1']:.4f} | {row['median_seconds']:.2f} |")
        sums = row.pop("bands")
        row["bands"] = {
            c: {k: t / n if n else None for k, (t, n) in b.items()} for c, b in sums.items()
        }
        pooled = {k: [sum(b[k][i] for b in sums.values()) for i in (0, 1)] for k in sums[names[0]]}
        row["bands_pooled"] = {k: t / n if n else None for k, (t, n) in pooled.items()}
        cells = " | ".join("-" if v is None else f"{v:.4f}" for v in row["bands_pooled"].values())
        band_lines.append(f"| {name} | {cells} |")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"data": names, "results": results}, indent=2) + "\n")
    if args.bands:
        print("\n".join(band_lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
