"""The uniform samples' range: fixed [0.5, 15] m against the range from the cached depth.

    python benchmarks/sample_range.py --data data/test --scenes 6 --height 128 --threads 1

The middle view of the first ``--scenes`` test triplets rendered from the outer two by PanoGRF
with each sampling (draft, fast, paper), once with the fixed range the renderer used before
(`Sampling(near=0.5, far=15.0)`) and once with `sample_range` (the default now); WS-PSNR per
sampling and the mean difference. The guided samples of draft and fast do not depend on the
range, only their uniform backbone does.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
from pathlib import Path

import torch


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=Path("data/test"))
    parser.add_argument("--scenes", type=int, default=6)
    parser.add_argument("--height", type=int, default=128)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path("lab/results/sample_range.json"))
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    from panogrf.app.files.atomic import write_json_atomic
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scene.session import default_models
    from panogrf.app.scoring import image_scores
    from panogrf.renderer.methods import SourceViews
    from panogrf.renderer.render import QUALITY, render_panorama, sample_range

    entries = json.loads((args.data / "dataset.json").read_text())["scenes"][: args.scenes]
    models = default_models()
    net = models.renderer("panogrf")
    scores: dict[str, list[float]] = {}
    ranges = []
    for e in entries:
        d = load_scene(args.data / e["folder"], load_images=True).images
        views = SourceViews(d.images[[0, 2]], d.c2w[[0, 2]])
        cache = views.cache_for("panogrf", models)
        ranges.append(sample_range(cache, d.c2w[1, :3, 3]))
        near, far = ranges[-1]
        line = [f"{e['folder']} ({e['baseline_m']} m) range {near:.2f}-{far:.1f}"]
        for q in ("draft", "fast", "paper"):
            for tag, sampling in (
                ("fixed", dataclasses.replace(QUALITY[q], near=0.5, far=15.0)),
                ("depth", QUALITY[q]),
            ):
                rgb = render_panorama(net, cache, d.c2w[1], args.height, sampling).rgb
                s = image_scores(rgb, d.images[1:2])["ws_psnr"]
                scores.setdefault(f"{q}:{tag}", []).append(s)
                line.append(f"{q}:{tag} {s:.2f}")
        print("  ".join(line), flush=True)
    means = {k: statistics.fmean(v) for k, v in scores.items()}
    print(f"\n{'sampling':>8} {'fixed':>8} {'depth':>8} {'diff':>7}")
    for q in ("draft", "fast", "paper"):
        a, b = means[f"{q}:fixed"], means[f"{q}:depth"]
        print(f"{q:>8} {a:8.2f} {b:8.2f} {b - a:+7.2f}")
    write_json_atomic(
        args.out,
        {
            "what": "WS-PSNR of the middle view, uniform samples over fixed [0.5, 15] m against "
            "the range from the cached depth (sample_range)",
            "scenes": [e["folder"] for e in entries],
            "height": args.height,
            "ranges": ranges,
            "ws_psnr": means,
            "per_scene": scores,
            "machine": f"{args.threads} torch thread(s), 2-core CPU shared with other jobs",
        },
    )
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
