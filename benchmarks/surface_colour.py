"""Composited colour against surface colour (`Sampling.surface`), per sampling.

    python benchmarks/surface_colour.py --data data/train_mix [--scenes 24] [--height 256]

On the renderer's validation scenes of the train split (its last ``--scenes`` scenes; never the
test split, never the real dev triplet): the middle view rendered from the outer two with each
sampling, once compositing the samples' colours and once taking the sources' blend at the
composited depth. WS-PSNR and LPIPS against the real view, median seconds per panorama. The
default of each sampling was chosen from this table. A table is printed last.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import time
from pathlib import Path

import torch


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=Path("data/train_mix"))
    parser.add_argument("--scenes", type=int, default=24, help="the last N scenes")
    parser.add_argument("--height", type=int, default=256)
    parser.add_argument("--out", type=Path, default=Path("lab/results/surface_colour.json"))
    parser.add_argument("--threads", type=int, default=0)
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)

    from panogrf.app.files.images import write_json_atomic
    from panogrf.app.runtime import keep_freed_memory
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scene.session import default_models
    from panogrf.app.scoring import image_scores
    from panogrf.renderer.methods import SourceViews
    from panogrf.renderer.render import QUALITY, render_panorama

    keep_freed_memory()
    variants = {}
    for q in ("draft", "fast"):
        for surface in (False, True):
            name = f"{q} {'surface' if surface else 'composited'}"
            variants[name] = dataclasses.replace(QUALITY[q], surface=surface)
    entries = json.loads((args.data / "dataset.json").read_text())["scenes"]
    folders = [args.data / e["folder"] for e in entries[-args.scenes :]]
    models = default_models()
    net = models.renderer("panogrf")
    scores: dict[str, list[dict]] = {k: [] for k in variants}
    h = args.height
    for folder in folders:
        d = load_scene(folder, load_images=True).images
        views = SourceViews(d.images[[0, 2]], d.c2w[[0, 2]])
        cache = views.cache_for("panogrf", models)
        for name, sampling in variants.items():
            t0 = time.perf_counter()
            out = render_panorama(net, cache, d.c2w[1], h, sampling)
            sec = time.perf_counter() - t0
            scores[name].append(image_scores(out.rgb, d.images[1:2]) | {"s": sec})
        print(f"{folder.name} done", flush=True)

    table = {
        k: {
            "ws_psnr": statistics.mean(r["ws_psnr"] for r in rows),
            "lpips": statistics.mean(r["lpips"] for r in rows),
            "median_s": statistics.median(r["s"] for r in rows),
        }
        for k, rows in scores.items()
    }
    write_json_atomic(
        args.out,
        {
            "what": "middle view from the outer two, validation scenes of the train split",
            "data": str(args.data),
            "scenes": [f.name for f in folders],
            "height": h,
            "results": table,
        },
    )
    print(f"\n{len(folders)} validation scenes of {args.data}, {h} rows; wrote {args.out}")
    print(f"{'sampling':<22} {'WS-PSNR':>8} {'LPIPS':>7} {'median s':>9}")
    for k, r in table.items():
        print(f"{k:<22} {r['ws_psnr']:8.2f} {r['lpips']:7.3f} {r['median_s']:9.2f}")


if __name__ == "__main__":
    main()
