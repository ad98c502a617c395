"""How much of a real home's scores is the rig under the camera: the middle view at 512 rows
scored whole and scored above the target photo's own rig cap (`detect_nadir` on the target;
the rows below it cropped from both images), for PanoGRF and the nearest photo.

    python lab/nadir_score.py ZIND_SCENES/floor_01_complete_room_06_*
"""

# ruff: noqa: E402, E501
import statistics
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
from depth_stages import middle_first, scene_folders

from panogrf.app.scene.folder import load_scene
from panogrf.app.scene.session import default_models
from panogrf.app.scoring import image_scores
from panogrf.model.refine import PREPARE_REFINE
from panogrf.renderer.cache import resize_erp
from panogrf.renderer.methods import SourceViews, render_view
from panogrf.renderer.nadir import detect_nadir

torch.set_num_threads(2)
models = default_models()
rows = []
for folder in scene_folders([Path(p) for p in sys.argv[1:]]):
    scene = load_scene(folder, load_images=True).images
    data = middle_first(scene, 512)
    views = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]], refine=PREPARE_REFINE)
    truth = data.images[1:2]
    mask, how, radius = detect_nadir(truth[0])
    cut = int(round(512 * (1 - radius / 180.0))) if how != "none" else 512  # rows above the cap
    for method in ("panogrf", "nearest"):
        rgb = render_view(method, views, data.c2w[1], 512, models, "fast")
        full = image_scores(rgb, truth)
        # scored above the target's rig cap: crop the rows below it from both
        cr = image_scores(rgb[:, :cut], resize_erp(truth, 512)[:, :, :cut]) if cut < 512 else full
        rows.append(
            (
                folder.name,
                method,
                how,
                radius,
                full["ws_psnr"],
                full["lpips"],
                cr["ws_psnr"],
                cr["lpips"],
            )
        )
        print(
            f"{folder.name} {method:8s} nadir {how} {radius:.1f} deg: full {full['ws_psnr']:.2f}/{full['lpips']:.3f}  above cap {cr['ws_psnr']:.2f}/{cr['lpips']:.3f}",
            flush=True,
        )
for m in ("panogrf", "nearest"):
    r = [x for x in rows if x[1] == m]
    print(
        m,
        "mean full",
        round(statistics.fmean(x[4] for x in r), 2),
        round(statistics.fmean(x[5] for x in r), 3),
        "above cap",
        round(statistics.fmean(x[6] for x in r), 2),
        round(statistics.fmean(x[7] for x in r), 3),
    )
