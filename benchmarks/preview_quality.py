"""The GL preview's cost and quality against the rows of its depth meshes.

    python benchmarks/preview_quality.py --data data/val_fusion_classic data/val_fusion_home

- cost: the preview of the bundled demo scene (3 sources, the 2 nearest drawn, as the viewer
  does) at 512 x 1024 on headless EGL, median milliseconds per frame over a short walk, the GL
  work finished each frame (``ctx.finish()``);
- quality: WS-PSNR of the middle view drawn from the outer two at the data's resolution, on
  validation scenes (generated from the train split's generator with seeds no training used:
  ``panogrf dataset make --split train --seed 90000`` classic, ``--seed 90001 --world home``;
  never the test split), depth estimated by the full estimator.
A table is printed last.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np
import torch

ROWS = (32, 48, 64, 96, 128)


def frame_costs(views, configs, rounds: int = 3, frames: int = 15) -> dict[tuple, float]:
    """Median ms per preview frame for each (mesh rows, preview rows) of ``configs``,
    interleaved round by round so a machine that slows down for a while slows all alike."""
    from panogrf.app.files.images import to_uint8
    from panogrf.renderer.gl_preview import PreviewRenderer, create_headless_context

    ctx = create_headless_context()
    images, depth = to_uint8(views.images), views.depth["full"][:, 0].numpy()
    renderers = {
        r: PreviewRenderer(ctx, images, depth, views.c2w.numpy(), r, max_views=2)
        for r in sorted({r for r, _ in configs})
    }
    times: dict[tuple, list[float]] = {c: [] for c in configs}
    pose = views.c2w[0].numpy().astype(np.float64)
    for _ in range(rounds):
        for r, height in configs:
            pr = renderers[r]
            for k in range(frames + 2):
                p = pose.copy()
                p[2, 3] -= 0.02 * k  # walking forward
                t0 = time.perf_counter()
                pr.render_to_framebuffer(p, height, fill_top=False, distance=False)  # as viewed
                ctx.finish()
                if k >= 2:
                    times[r, height].append(time.perf_counter() - t0)
    for pr in renderers.values():
        pr.release()
    ctx.release()
    return {c: 1000 * statistics.median(t) for c, t in times.items()}


def upsample(rgb: np.ndarray, height: int) -> torch.Tensor:
    """An ERP preview [h, 2h, 3] uint8 -> [3, height, 2 height] in [0, 1], bilinear (the
    display's texture sampling), wrapping at the seam."""
    from panogrf.renderer.detail import upsample_erp

    x = torch.from_numpy(rgb).permute(2, 0, 1).float() / 255
    return upsample_erp(x, (height, 2 * height))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--data",
        type=Path,
        nargs="+",
        default=[Path("data/val_fusion_classic"), Path("data/val_fusion_home")],
    )
    parser.add_argument("--scenes", type=int, default=0, help="the last N scenes of each (0: all)")
    parser.add_argument(
        "--oblique",
        default="6",
        help="MAX_OBLIQUE_TAN values to score (comma-separated; the first is timed)",
    )
    parser.add_argument(
        "--heights",
        default="0",
        help="preview rows to score (comma-separated; 0: the data's own), each shown upsampled "
        "to the data's rows, with --rows mesh rows",
    )
    parser.add_argument("--rows", type=int, default=64, help="mesh rows for --heights")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/preview_quality.json"))
    args = parser.parse_args()

    from panogrf.app.files.images import to_uint8, write_json_atomic
    from panogrf.app.runtime import keep_freed_memory
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scene.session import default_models, prepare_scene
    from panogrf.app.scoring import image_scores
    from panogrf.assets import path as asset_path
    from panogrf.renderer import gl_preview
    from panogrf.renderer.detail import render_detailed
    from panogrf.renderer.gl_preview import PreviewRenderer, create_headless_context
    from panogrf.renderer.methods import METHODS, SourceViews

    obliques = [float(x) for x in args.oblique.split(",")]
    gl_preview.MAX_OBLIQUE_TAN = obliques[0]
    keep_freed_memory()
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        views = prepare_scene(asset_path("demo"), Path(tmp), log=lambda *a: None).views
    heights = [int(x) for x in args.heights.split(",")]
    configs = [(r, 512) for r in ROWS] + [(args.rows, h) for h in heights if h and h != 512]
    cost = frame_costs(views, configs)
    print("cost:", {f"{r}@{h}": round(v, 1) for (r, h), v in cost.items()}, flush=True)

    folders = []
    for root in args.data:
        entries = json.loads((root / "dataset.json").read_text())["scenes"]
        folders += [root / e["folder"] for e in entries[-args.scenes :]]
    models = default_models()
    ctx = create_headless_context()
    spec = METHODS["panogrf"]
    net = models.renderer(spec.renderer)
    drafts: list[float] = []
    scores: dict[tuple[int, float, int], list[float]] = {
        (r, o, 0): [] for r in ROWS for o in obliques
    }
    scores |= {(args.rows, obliques[0], h): [] for h in heights if h}
    for folder in folders:
        d = load_scene(folder, load_images=True).images
        v = SourceViews(d.images[[0, 2]], d.c2w[[0, 2]])
        depth = v.depth_for("full", models)[:, 0].numpy()
        images = to_uint8(d.images[[0, 2]])
        height = d.images.shape[-2]
        # The draft refinement of the same view, for reference.
        out = render_detailed(net, v.cache_for(spec, models), d.c2w[1], height, "draft")
        drafts.append(image_scores(out.rgb, d.images[1:2])["ws_psnr"])
        for r, o, h in scores:
            gl_preview.MAX_OBLIQUE_TAN = o
            with PreviewRenderer(ctx, images, depth, d.c2w[[0, 2]].numpy(), r) as pr:
                rgb, _ = pr.render(d.c2w[1].numpy(), h or height)
            x = upsample(rgb, height)
            scores[r, o, h].append(image_scores(x, d.images[1:2])["ws_psnr"])
    ctx.release()
    draft = statistics.mean(drafts)

    report = {
        "what": "GL preview: frame cost at 512x1024 (demo, 2 sources drawn) and WS-PSNR of the "
        "middle view from the outer two against depth-mesh rows",
        "quality_scenes": [f"{f.parent.name}/{f.name}" for f in folders],
        "quality_height": int(height),
        "max_oblique_tan_timed": obliques[0],
        "rows": {
            str(r): {"frame_ms": cost[r, 512]}
            | {f"ws_psnr_oblique_{o:g}": statistics.mean(scores[r, o, 0]) for o in obliques}
            for r in ROWS
        },
        "preview_heights": {
            str(h): {"frame_ms": cost[args.rows, h], "ws_psnr": statistics.mean(scores[k])}
            for k in scores
            if (h := k[2])
        },
        "draft_ws_psnr": draft,
        "machine": "2-core CPU, Mesa llvmpipe (EGL)",
    }
    write_json_atomic(args.out, report)
    heads = "".join(f"{f'WS-PSNR@{o:g}':>14}" for o in obliques)
    print(f"\n{'mesh rows':>10} {'ms/frame':>10} {'fps':>7}{heads}")
    for r in ROWS:
        m = cost[r, 512]
        cells = "".join(f"{statistics.mean(scores[r, o, 0]):>14.2f}" for o in obliques)
        print(f"{r:>10} {m:>10.1f} {1000 / m:>7.1f}{cells}")
    print(f"(WS-PSNR@t: MAX_OBLIQUE_TAN = t; frame times at 512 x 1024 and {obliques[0]:g})")
    for (r, _, h), v in scores.items():
        if h:
            m = cost[r, h]
            print(
                f"preview at {h} rows ({r}-row meshes), shown at {height}: "
                f"{m:.1f} ms ({1000 / m:.1f} fps), WS-PSNR {statistics.mean(v):.2f}"
            )
    print(f"draft refinement (3 + 1 samples, the network at the data's rows): {draft:.2f}")
    names = ", ".join(str(d) for d in args.data)
    print(f"({len(folders)} validation scenes of {names}; wrote {args.out})")


if __name__ == "__main__":
    main()
