"""The viewer's first refinement: quality and cost of few-sample depth-guided samplings.

    python benchmarks/draft_sampling.py --data data/train

On the renderer's validation scenes of the train split (its last ``--scenes`` scenes; never
the test split): the middle view rendered from the outer two at ``--height`` rows with each
sampling (guided samples around the splatted depths + a sparse uniform backbone), WS-PSNR
against the real view and the median seconds per panorama on this CPU. The viewer's ``draft``
was chosen from this table. A table is printed last.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import torch


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=Path("data/train"))
    parser.add_argument("--scenes", type=int, default=24, help="the last N scenes")
    parser.add_argument("--height", type=int, default=256)
    parser.add_argument("--out", type=Path, default=Path("lab/results/draft_sampling.json"))
    args = parser.parse_args()

    from panogrf.app.files.images import write_json_atomic
    from panogrf.app.runtime import keep_freed_memory
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scene.session import default_models
    from panogrf.app.scoring import image_scores
    from panogrf.renderer.methods import SourceViews
    from panogrf.renderer.render import QUALITY, Sampling, render_panorama

    keep_freed_memory()
    variants = {
        "fast (8 + 4)": QUALITY["fast"],
        "4 + 2": Sampling(n_coarse=2, n_fine=0, n_guided=4),
        "4 + 1": Sampling(n_coarse=1, n_fine=0, n_guided=4),
        "3 + 2": Sampling(n_coarse=2, n_fine=0, n_guided=3),
        "3 + 1": Sampling(n_coarse=1, n_fine=0, n_guided=3),
        "2 + 2": Sampling(n_coarse=2, n_fine=0, n_guided=2),
    }
    names = {s: k for k, s in variants.items()}
    draft = names.get(QUALITY["draft"], "draft")
    variants.setdefault(draft, QUALITY["draft"])
    entries = json.loads((args.data / "dataset.json").read_text())["scenes"]
    folders = [args.data / e["folder"] for e in entries[-args.scenes :]]
    models = default_models()
    net = models.renderer("panogrf")
    psnr: dict[str, list[float]] = {k: [] for k in variants}
    secs: dict[str, list[float]] = {k: [] for k in variants}
    h = args.height
    for folder in folders:
        d = load_scene(folder, load_images=True).images
        views = SourceViews(d.images[[0, 2]], d.c2w[[0, 2]])
        cache = views.cache_for("panogrf", models)
        real = torch.nn.functional.interpolate(d.images[1:2], size=(h, 2 * h), mode="area")
        for name, sampling in variants.items():
            t0 = time.perf_counter()
            out = render_panorama(net, cache, d.c2w[1], h, sampling)
            secs[name].append(time.perf_counter() - t0)
            psnr[name].append(image_scores(out.rgb, real)["ws_psnr"])
        print(f"{folder.name} done", flush=True)

    report = {
        "what": "middle view from the outer two, validation scenes of the train split",
        "scenes": [f.name for f in folders],
        "height": h,
        "draft": draft,
        "samplings": {
            k: {"ws_psnr": statistics.mean(psnr[k]), "median_s": statistics.median(secs[k])}
            for k in variants
        },
    }
    write_json_atomic(args.out, report)
    print(f"\n{'sampling':<14} {'WS-PSNR':>8} {'median s':>9}")
    for k in variants:
        mark = "  <- draft" if k == draft else ""
        print(f"{k:<14} {statistics.mean(psnr[k]):>8.2f} {statistics.median(secs[k]):>9.3f}{mark}")
    print(f"({len(folders)} scenes of {args.data} at {h} rows; wrote {args.out})")


if __name__ == "__main__":
    main()
