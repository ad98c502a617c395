"""Full-resolution refinement: the network at every output pixel against the network at its
training resolution plus the sources' detail (`panogrf.renderer.detail`).

    python benchmarks/detail.py --data data/val_detail_classic data/val_detail_home \
        [--height 512] [--agreement 0.03,0.05,0.1] [--out lab/results/detail.json]

For every scene folder of the datasets (three views; the middle one rendered from the outer two
by PanoGRF with the ``fast`` sampling, depth and caches prepared once per scene): rows
``network at H`` (today's render), ``network at 256, bilinear`` (no detail) and ``network at
256 + detail`` per agreement scale. Prints mean WS-PSNR, SSIM, LPIPS and the median seconds per
panorama (render only), and writes JSON. Settings are chosen on validation scenes generated
from the train split's generator with seeds no training used, never on the test split.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import torch
import torch.nn.functional as F

from panogrf.app.scene.folder import load_scene
from panogrf.app.scene.session import default_models
from panogrf.app.scoring import image_scores
from panogrf.renderer.detail import PROJECTIONS, DetailConfig, render_detailed
from panogrf.renderer.methods import METHODS, SourceViews
from panogrf.renderer.render import render_panorama

KEYS = ("ws_psnr", "ssim", "lpips")


def scenes(root: Path) -> list[Path]:
    index = json.loads((root / "dataset.json").read_text())
    return [root / entry["folder"] for entry in index["scenes"]]


def _extras(extras: list[str]) -> dict:
    """Ladder suffixes ``:bicubic`` or ``:bilinear`` (DetailConfig.sampling), ``:splat`` or
    ``:network`` (DetailConfig.projection), ``:medianK`` (DetailConfig.median)."""
    kw: dict = {}
    for x in extras:
        if x in ("bilinear", "bicubic"):
            kw["sampling"] = x
        elif x in PROJECTIONS:
            kw["projection"] = x
        elif x.startswith("median") and x[6:].isdigit():
            kw["median"] = int(x[6:])
        else:
            raise SystemExit(
                f"unknown ladder suffix {x!r}: bilinear, bicubic, splat, network or medianK"
            )
    return kw


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--height", type=int, default=512)
    parser.add_argument("--agreement", default="0.05")
    parser.add_argument("--limit", type=int, default=0, help="scenes per dataset (0: all)")
    parser.add_argument(
        "--ladder",
        default="",
        help="only rows QUALITY@NET_ROWS[@CUTOFF] + detail, e.g. draft@128,fast@192,fast@192@96 "
        "(the viewer's refinement levels; the agreement is the first of --agreement; CUTOFF: "
        "DetailConfig.cutoff), each optionally followed by :bicubic or :bilinear "
        "(DetailConfig.sampling), :splat or :network (DetailConfig.projection), :medianK",
    )
    parser.add_argument("--threads", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    models = default_models()
    spec = METHODS["panogrf"]
    net = models.renderer(spec.renderer)
    h = args.height
    rows: dict[str, dict[str, list[float]]] = {}

    def record(name: str, rgb, target, seconds: float) -> None:
        row = rows.setdefault(name, {k: [] for k in (*KEYS, "seconds")})
        scores = image_scores(rgb, target)
        for k in KEYS:
            row[k].append(scores[k])
        row["seconds"].append(seconds)

    for root in args.data:
        folders = scenes(root)[: args.limit or None]
        for folder in folders:
            data = load_scene(folder, load_images=True).images
            views = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]])
            cache = views.cache_for(spec, models)
            target, c2w = data.images[1:2], data.c2w[1]
            if args.ladder:
                a = float(args.agreement.split(",")[0])
                for item in args.ladder.split(","):
                    head, *extras = item.split(":")
                    quality, rows_net, *cut = head.split("@")
                    cfg = DetailConfig(
                        net_height=int(rows_net),
                        agreement=a,
                        cutoff=int(cut[0]) if cut else None,
                        **_extras(extras),
                    )
                    t0 = time.perf_counter()
                    out = render_detailed(net, cache, c2w, h, quality, cfg)
                    record(
                        f"{quality} at {rows_net} + detail"
                        + (f" above {cut[0]}" if cut else "")
                        + "".join(f", {x}" for x in extras),
                        out.rgb,
                        target,
                        time.perf_counter() - t0,
                    )
                print(f"{root.name}/{folder.name} done", flush=True)
                continue
            t0 = time.perf_counter()
            full = render_panorama(net, cache, c2w, h, "fast")
            record(f"network at {h}", full.rgb, target, time.perf_counter() - t0)
            t0 = time.perf_counter()
            low = render_panorama(net, cache, c2w, 256, "fast")
            up = F.interpolate(low.rgb[None], size=(h, 2 * h), mode="bilinear")[0]
            record("network at 256, bilinear", up, target, time.perf_counter() - t0)
            for a in (float(x) for x in args.agreement.split(",")):
                t0 = time.perf_counter()
                out = render_detailed(net, cache, c2w, h, "fast", DetailConfig(agreement=a))
                record(
                    f"network at 256 + detail ({a:g})", out.rgb, target, time.perf_counter() - t0
                )
            print(f"{root.name}/{folder.name} done", flush=True)
    summary = {
        name: {k: statistics.fmean(v[k]) for k in KEYS}
        | {"median_seconds": statistics.median(v["seconds"]), "scenes": len(v["seconds"])}
        for name, v in rows.items()
    }
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        payload = {"data": [str(d) for d in args.data], "height": h, "results": summary}
        args.out.write_text(json.dumps(payload, indent=2) + "\n")
    print(f"\n{h}x{2 * h}, PanoGRF fast, middle view from the outer two")
    print("| render | WS-PSNR | SSIM | LPIPS | s / panorama |")
    print("|---|---|---|---|---|")
    for name, r in summary.items():
        print(
            f"| {name} | {r['ws_psnr']:.2f} | {r['ssim']:.3f} | {r['lpips']:.3f} "
            f"| {r['median_seconds']:.2f} |"
        )


if __name__ == "__main__":
    main()
