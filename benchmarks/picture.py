"""The README's picture: a scene's middle view, true and rendered from the outer two by PanoGRF,
by PanoGRF on MVS-only depth and by turning the nearest photo, each with its scores.

    python benchmarks/picture.py --scene data/loo_lit/train_00003 --out docs/views.jpg

(``data/loo_lit``: ``panogrf dataset make --out data/loo_lit --split train --world home
--baselines 1.0,2.0,3.0,4.0 --renderer pyrender --seed 90032 --count 6 --height 512``, the
lit homes of the lean-chain measurement, which no training used.)

The scene (three views) is prepared as `panogrf render` prepares it (mode full with the
per-scene refinement, `fast`, 512 rows); the panels are labelled with WS-PSNR and LPIPS and
laid out two by two (JPEG). The scores are printed as a table last.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> None:
    from depth_stages import middle_first

    from panogrf.app.files.atomic import write_bytes_atomic
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scene.session import default_models
    from panogrf.app.scoring import image_scores
    from panogrf.model.refine import PREPARE_REFINE
    from panogrf.renderer.methods import SourceViews, render_view

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", type=Path, required=True)
    parser.add_argument("--out", type=Path, default=Path("docs/views.jpg"))
    parser.add_argument("--rows", type=int, default=512)
    parser.add_argument("--panel-rows", type=int, default=320)
    args = parser.parse_args()
    torch.set_num_threads(2)
    data = middle_first(load_scene(args.scene, load_images=True).images, args.rows)
    models = default_models()
    views = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]], refine=PREPARE_REFINE)
    centres = data.c2w[:, :3, 3]
    gaps = [float((centres[1] - centres[i]).norm()) for i in (0, 2)]
    panels, rows = [("true view", data.images[1], None)], []
    for method, label in (
        ("panogrf", "PanoGRF"),
        ("no_mono", "MVS-only depth"),
        ("nearest", "nearest photo"),
    ):
        quality = "fast" if method != "nearest" else None
        rgb = render_view(
            method, views, data.c2w[1], args.rows, models, *([quality] if quality else [])
        )
        scores = image_scores(rgb, data.images[1:2])
        panels.append((label, rgb, scores))
        rows.append((label, scores["ws_psnr"], scores["ssim"], scores["lpips"]))
    tiles = []
    for label, rgb, scores in panels:
        img = (rgb.permute(1, 2, 0).clamp(0, 1).numpy() * 255).astype(np.uint8)
        img = cv2.resize(img, (2 * args.panel_rows, args.panel_rows), interpolation=cv2.INTER_AREA)
        text = (
            label
            if scores is None
            else f"{label}: {scores['ws_psnr']:.1f} dB, LPIPS {scores['lpips']:.2f}"
        )
        img = np.ascontiguousarray(img)
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.6, 1)
        cv2.rectangle(img, (4, 4), (16 + tw, 16 + th), (0, 0, 0), -1)
        cv2.putText(
            img, text, (10, 10 + th), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA
        )
        tiles.append(img)
    grid = np.concatenate((np.concatenate(tiles[:2], 1), np.concatenate(tiles[2:], 1)), 0)
    ok, jpeg = cv2.imencode(
        ".jpg", cv2.cvtColor(grid, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 85]
    )
    assert ok
    write_bytes_atomic(args.out, jpeg.tobytes())
    print(f"{args.scene}: middle view {gaps[0]:.2f} m and {gaps[1]:.2f} m from the two sources")
    print(f"wrote {args.out} ({len(jpeg) // 1024} KB)\n")
    print(f"{'method':<16} {'WS-PSNR':>8} {'SSIM':>6} {'LPIPS':>6}")
    for label, psnr, ssim, lpips in rows:
        print(f"{label:<16} {psnr:8.2f} {ssim:6.3f} {lpips:6.3f}")


if __name__ == "__main__":
    main()
