"""The GL preview's weight of each source by closeness, 1 / (d + 1 cm)^P: P = 1 (shipped)
against 2 (the refined view's detail since round 51), as the viewer draws it while moving (the
sharp preview: geometry at 128 rows from 128-row meshes of 10k triangles, colours at the
data's rows), the middle view from the outer two, WS-PSNR / LPIPS:

    python lab/preview_closeness.py --data data/near_home data/loo_home \\
        --out lab/results/preview_closeness.json
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

import torch


def main() -> None:
    from panogrf.app.files.images import to_uint8
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scene.session import default_models
    from panogrf.app.scoring import image_scores
    from panogrf.renderer import gl_preview
    from panogrf.renderer.gl_preview import PreviewRenderer, create_headless_context
    from panogrf.renderer.methods import SourceViews

    parser = argparse.ArgumentParser()
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--powers", default="1,2")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    torch.set_num_threads(2)
    powers = [float(p) for p in args.powers.split(",")]
    models, ctx = default_models(), create_headless_context()
    rows: dict[str, dict[str, list[dict]]] = {str(p): {} for p in powers}
    for root in args.data:
        for entry in json.loads((root / "dataset.json").read_text())["scenes"]:
            d = load_scene(root / entry["folder"], load_images=True).images
            v = SourceViews(d.images[[0, 2]], d.c2w[[0, 2]])
            depth = v.depth_for("full", models)[:, 0].numpy()
            images, height = to_uint8(d.images[[0, 2]]), d.images.shape[-2]
            for p in powers:
                gl_preview.CLOSENESS_POWER = p
                c2w = d.c2w[[0, 2]].numpy()
                with PreviewRenderer(ctx, images, depth, c2w, 128, mesh_triangles=10000) as pr:
                    rgb, _ = pr.render(d.c2w[1].numpy(), height, geometry_height=128)
                rgb_t = torch.from_numpy(rgb).permute(2, 0, 1).float() / 255.0
                s = image_scores(rgb_t, d.images[1:2])
                row = {"scene": entry["folder"], "ws_psnr": s["ws_psnr"], "lpips": s["lpips"]}
                rows[str(p)].setdefault(root.name, []).append(row)
                print(f"{root.name}/{entry['folder']} P={p:g}: {s['ws_psnr']:.2f} dB "
                      f"LPIPS {s['lpips']:.4f}", flush=True)  # fmt: skip
    ctx.release()
    table = {
        p: {
            g: {k: statistics.fmean(r[k] for r in rs) for k in ("ws_psnr", "lpips")}
            for g, rs in per.items()
        }  # fmt: skip
        for p, per in rows.items()
    }
    args.out.write_text(json.dumps({"table": table, "rows": rows}, indent=1))
    for p, per in table.items():
        print(
            f"P={p}: "
            + "  ".join(f"{g} {t['ws_psnr']:.2f} / {t['lpips']:.4f}" for g, t in per.items())
        )


if __name__ == "__main__":
    main()
