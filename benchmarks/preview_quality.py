"""The GL preview's cost and quality against the rows of its depth meshes.

    python benchmarks/preview_quality.py --data data/train

- cost: the preview of the bundled demo scene (3 sources, the 2 nearest drawn, as the viewer
  does) at 512 x 1024 on headless EGL, median milliseconds per frame over a short walk, the GL
  work finished each frame (``ctx.finish()``);
- quality: WS-PSNR of the middle view drawn from the outer two at the data's resolution, on
  the renderer's validation scenes of the train split (its last ``--scenes`` scenes; never
  the test split), depth estimated by the full estimator.
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


def frame_costs(views, rounds: int = 3, frames: int = 15) -> dict[int, float]:
    """Median ms per preview frame for each mesh height, the heights interleaved round by
    round so a machine that slows down for a while slows all of them alike."""
    from panogrf.app.files.images import to_uint8
    from panogrf.renderer.gl_preview import PreviewRenderer, create_headless_context

    ctx = create_headless_context()
    images, depth = to_uint8(views.images), views.depth["full"][:, 0].numpy()
    renderers = {
        r: PreviewRenderer(ctx, images, depth, views.c2w.numpy(), r, max_views=2) for r in ROWS
    }
    times: dict[int, list[float]] = {r: [] for r in ROWS}
    pose = views.c2w[0].numpy().astype(np.float64)
    for _ in range(rounds):
        for r, pr in renderers.items():
            for k in range(frames + 2):
                p = pose.copy()
                p[2, 3] -= 0.02 * k  # walking forward
                t0 = time.perf_counter()
                pr.render_to_framebuffer(p, 512, fill_top=False, distance=False)  # as the viewer
                ctx.finish()
                if k >= 2:
                    times[r].append(time.perf_counter() - t0)
    for pr in renderers.values():
        pr.release()
    ctx.release()
    return {r: 1000 * statistics.median(t) for r, t in times.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=Path("data/train"))
    parser.add_argument("--scenes", type=int, default=24, help="the last N scenes")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/preview_quality.json"))
    args = parser.parse_args()

    from panogrf.app.files.images import to_uint8, write_json_atomic
    from panogrf.app.runtime import keep_freed_memory
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scene.session import default_models, prepare_scene
    from panogrf.app.scoring import image_scores
    from panogrf.assets import path as asset_path
    from panogrf.renderer.gl_preview import PreviewRenderer, create_headless_context
    from panogrf.renderer.methods import SourceViews

    keep_freed_memory()
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        views = prepare_scene(asset_path("demo"), Path(tmp), log=lambda *a: None).views
    cost = frame_costs(views)
    print("cost:", {r: round(v, 1) for r, v in cost.items()}, flush=True)

    entries = json.loads((args.data / "dataset.json").read_text())["scenes"]
    folders = [args.data / e["folder"] for e in entries[-args.scenes :]]
    models = default_models()
    ctx = create_headless_context()
    scores: dict[int, list[float]] = {r: [] for r in ROWS}
    for folder in folders:
        d = load_scene(folder, load_images=True).images
        v = SourceViews(d.images[[0, 2]], d.c2w[[0, 2]])
        depth = v.depth_for("full", models)[:, 0].numpy()
        images = to_uint8(d.images[[0, 2]])
        height = d.images.shape[-2]
        for r in ROWS:
            with PreviewRenderer(ctx, images, depth, d.c2w[[0, 2]].numpy(), r) as pr:
                rgb, _ = pr.render(d.c2w[1].numpy(), height)
            x = torch.from_numpy(rgb).permute(2, 0, 1).float() / 255
            scores[r].append(image_scores(x, d.images[1:2])["ws_psnr"])
    ctx.release()

    report = {
        "what": "GL preview: frame cost at 512x1024 (demo, 2 sources drawn) and WS-PSNR of the "
        "middle view from the outer two against depth-mesh rows",
        "quality_scenes": [f.name for f in folders],
        "quality_height": int(height),
        "rows": {
            str(r): {"frame_ms": cost[r], "ws_psnr": statistics.mean(scores[r])} for r in ROWS
        },
        "machine": "2-core CPU, Mesa llvmpipe (EGL)",
    }
    write_json_atomic(args.out, report)
    print(f"\n{'mesh rows':>10} {'ms/frame':>10} {'fps':>7} {'WS-PSNR':>9}")
    for r in ROWS:
        m = cost[r]
        print(f"{r:>10} {m:>10.1f} {1000 / m:>7.1f} {statistics.mean(scores[r]):>9.2f}")
    print(f"({len(folders)} validation scenes of {args.data}; wrote {args.out})")


if __name__ == "__main__":
    main()
