"""A view near one photo: is the blend of both photos better than the near photo alone?

    python lab/near_source.py make --out data/near_home --t 0.2 --seed 90070 --count 6 \
        --baselines 2.0,3.0,4.0,5.0 [--world home] [--renderer gl]
    python lab/near_source.py eval --data data/near_home --out lab/results/near_source.json

``make``: synthetic triplets (`panogrf dataset make`) whose middle camera stands on the line
from the first to the last at fraction ``--t`` of the way (instead of halfway), with its own
heading: a view a user sees walking away from the first photo. ``eval``: the middle view
rendered (PanoGRF, ``fast``, the shipped preparation of the outer two) from both (`both`) and
from the near one's part of that preparation alone (`near`), WS-PSNR / SSIM / LPIPS against
the true view. Table printed last.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
from depth_stages import scene_folders  # noqa: E402


def make(args) -> None:
    from panogrf.app.synth import make as synth

    plain = synth.build_scene

    def at_fraction(*a, **kw):
        scene = plain(*a, **kw)
        cams = scene.cameras.copy()
        p0, p2 = cams[0, :3, 3], cams[2, :3, 3]
        cams[1, :3, 3] = p0 + args.t * (p2 - p0)  # on the segment: kept clear of furniture
        return dataclasses.replace(scene, cameras=cams)

    synth.build_scene = at_fraction
    cfg = synth.MakeConfig(
        out=args.out,
        split="train",
        count=args.count,
        height=args.height,
        baselines=tuple(float(b) for b in args.baselines.split(",")),
        seed=args.seed,
        world=args.world,
        renderer=args.renderer,
        workers=1,
        trims=0.3 if args.world == "home" else 0.0,
        coves=0.3 if args.world == "home" else 0.0,
        sheers=0.3 if args.world == "home" else 0.0,
    )
    print(synth.make_dataset(cfg))


def evaluate(args) -> None:
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scene.session import default_models
    from panogrf.app.scoring import image_scores
    from panogrf.model.refine import PREPARE_REFINE
    from panogrf.renderer.detail import render_detailed
    from panogrf.renderer.methods import SourceViews
    from panogrf.renderer.render import Quality

    torch.set_num_threads(2)
    models = default_models("cpu")
    rows = []
    for folder in scene_folders(args.data):
        data = load_scene(folder, load_images=True).images
        centres = data.c2w[:, :3, 3]
        near = 0 if (centres[1] - centres[0]).norm() <= (centres[1] - centres[2]).norm() else 2
        row = {"scene": str(folder), "t": float((centres[1] - centres[0]).norm()
                                                / (centres[2] - centres[0]).norm())}  # fmt: skip
        # Both photos prepared together (each one's depth from the other); `near` renders from
        # the near photo's part of that preparation alone.
        views = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]], refine=PREPARE_REFINE)
        cache = views.cache_for("panogrf", models)
        net = models.renderer("panogrf")
        height = data.images.shape[-2]
        for name, part in (("both", cache), ("near", cache.select([0 if near == 0 else 1]))):
            out = render_detailed(net, part, data.c2w[1], height, Quality.FAST)
            s = image_scores(out.rgb, data.images[1:2])
            row[name] = {k: s[k] for k in ("ws_psnr", "ssim", "lpips")}
        print(f"{folder.name} t {row['t']:.2f}: both {row['both']['ws_psnr']:.2f} dB / "
              f"{row['both']['lpips']:.3f}, near {row['near']['ws_psnr']:.2f} / "
              f"{row['near']['lpips']:.3f}", flush=True)  # fmt: skip
        rows.append(row)
    table = {
        name: {k: statistics.fmean(r[name][k] for r in rows) for k in ("ws_psnr", "ssim", "lpips")}
        for name in ("both", "near")
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"rows": rows, "table": table}, indent=1))
    print("\nsources | WS-PSNR | SSIM | LPIPS")
    for name, t in table.items():
        print(f"{name} | {t['ws_psnr']:.2f} | {t['ssim']:.3f} | {t['lpips']:.4f}")


def main() -> int:
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest="cmd", required=True)
    m = sub.add_parser("make")
    m.add_argument("--out", type=Path, required=True)
    m.add_argument("--t", type=float, default=0.2)
    m.add_argument("--seed", type=int, default=90070)
    m.add_argument("--count", type=int, default=6)
    m.add_argument("--height", type=int, default=512)
    m.add_argument("--baselines", default="2.0,3.0,4.0,5.0")
    m.add_argument("--world", default="home")
    m.add_argument("--renderer", default="gl")
    e = sub.add_parser("eval")
    e.add_argument("--data", type=Path, nargs="+", required=True)
    e.add_argument("--out", type=Path, default=Path("lab/results/near_source.json"))
    args = parser.parse_args()
    make(args) if args.cmd == "make" else evaluate(args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
