"""The GL preview from sources finer than it: as they are, or area-averaged to twice its rows
(`panogrf.app.viewer.setup.preview_sources`).

    python lab/preview_source_level.py

The 9 scenes photographed at 2048 rows (`data/hires_classic`, `data/hires_lit`: the commands in
lab/analysis.md, round 43); the middle view drawn from the outer two by the sharp preview at
512 rows (geometry at 128, 128-row meshes of 10000 triangles, as the viewer), on the shipped
depth; WS-PSNR and LPIPS against the middle photograph.
"""

# ruff: noqa: E402, E501
import statistics
import sys
from pathlib import Path

import cv2
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
from depth_stages import middle_first, scene_folders

from panogrf.app.files.images import to_uint8
from panogrf.app.scene.folder import load_scene
from panogrf.app.scene.session import default_models
from panogrf.app.scoring import image_scores
from panogrf.model.refine import PREPARE_REFINE
from panogrf.renderer.gl_preview import PreviewRenderer, create_headless_context
from panogrf.renderer.methods import SourceViews

torch.set_num_threads(2)
models = default_models()
ctx = create_headless_context()
res = {"full": [], "capped": []}
for folder in scene_folders([Path("data/hires_classic"), Path("data/hires_lit")]):
    scene = load_scene(folder, load_images=True).images
    data = middle_first(scene, scene.images.shape[-2])
    views = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]], refine=PREPARE_REFINE)
    depth = views.depth_for("full", models)[:, 0].numpy()
    imgs = to_uint8(views.images)
    for name in res:
        im = (
            imgs
            if name == "full"
            else np.stack([cv2.resize(x, (2048, 1024), interpolation=cv2.INTER_AREA) for x in imgs])
        )
        pr = PreviewRenderer(
            ctx, im, depth, views.c2w.numpy(), mesh_height=128, max_views=2, mesh_triangles=10000
        )
        rgb, _ = pr.render(data.c2w[1].numpy().astype(np.float64), 512, geometry_height=128)
        pr.release()
        s = image_scores(torch.from_numpy(rgb).permute(2, 0, 1).float() / 255, data.images[1:2])
        res[name].append((s["ws_psnr"], s["lpips"]))
        print(
            folder.parent.name,
            folder.name,
            name,
            f"{s['ws_psnr']:.2f} {s['lpips']:.4f}",
            flush=True,
        )
for k, v in res.items():
    print(
        k,
        "mean WS-PSNR",
        round(statistics.fmean(a for a, _ in v), 3),
        "LPIPS",
        round(statistics.fmean(b for _, b in v), 4),
    )
