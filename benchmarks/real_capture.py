"""Novel views and depth on real captures: every method, image and depth tables.

    python scripts/make_dev_triplet.py --mirror PATH/TO/PanSplat.git   # once: data/real/
    python benchmarks/real_capture.py [--data data/real] [--heights 512,256]

Fetches nothing: it reads a dataset folder of triplets (``dataset.json`` listing scene folders
of three views on a line with ground-truth depth), by default ``data/real`` as written by
``scripts/make_dev_triplet.py`` (ignored by git: Matterport3D's terms keep the data and
anything derived from it out of the repository). Without that folder it says how to make it
and exits 0.

For every triplet the middle view is rendered from the first and last by every method at each
height and scored (PSNR, WS-PSNR, SSIM, LPIPS). Depth: the first and last views, each the
other's source, estimated by every depth mode (mono, MVS-only, full) and compared with the
ground truth at the dataset's resolution on 0 < gt <= d_max, also by band of elevation (L1
over both views' pixels in the band: where each depth is wrong, the ceiling, walls or floor).
``--picture`` writes the true middle view, PanoGRF, MVS-only and meshwarp stacked (into the
ignored data folder by default).
Every multi-view depth is refined per scene first (`SourceViews.refine`, as the CLI does by
default since round 16), for the depth table and every method that reads it;
``--no-refine-depth`` uses the networks' depth as it is.
``--gt-depth`` adds diagnostic rows that use the ground truth:
- ``gt_depth``: PanoGRF's renderer with the two sources' true depth in place of the estimate
  (what the renderer does when the depth is right);
- ``reprojected``: no network, each source's full-resolution pixels read at the points of the
  middle view's own true depth (bicubic), averaged over the sources that see the point (its
  distance within 5 % of the source's true depth), else from the nearest source: what
  resampling the sources can give with perfect geometry and visibility;
- ``true_via_256``: the true middle view area-averaged to 256 rows and bilinearly upsampled,
  at heights above 256: what a perfect 256-row render scores at that height. Together they say
  how far LPIPS at 512 rows can fall below LPIPS at 256 by any method that resamples the
  sources (issue 12's criterion compares the two).
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import subprocess
import time
from pathlib import Path

import numpy as np
import torch

from panogrf.model.metrics import ELEVATION_BANDS, band_key, depth_l1_by_band, depth_metrics

METHODS = ("panogrf", "no_mono", "no_mvs", "meshwarp", "nearest")
DEPTH_MODES = ("mono", "mvs", "full")
IMAGE_KEYS = ("psnr", "ws_psnr", "ssim", "lpips")
DEPTH_KEYS = ("l1", "rmse", "ws_l1", "ws_rmse")
#: Bands of elevation (degrees, camera frame) of the depth's L1 by band: where a depth is wrong
#: (the ceiling, the walls, the floor).
BANDS = ELEVATION_BANDS
BAND_KEYS = tuple(band_key(band) for band in BANDS)


def triplets(root: Path) -> list[Path]:
    index = json.loads((root / "dataset.json").read_text())
    return [root / entry["folder"] for entry in index["scenes"]]


def depth_scores(models, views, data, mode: str) -> dict[str, float]:
    """Depth metrics of the first and last views (each the other's source), averaged."""
    est_net = models.estimator(mode)
    depth = views.depth_for(mode, models)  # working resolution
    depth = torch.nn.functional.interpolate(
        depth, size=data.images.shape[-2:], mode="bilinear", align_corners=False
    )
    rows = []
    for k, v in enumerate((0, 2)):
        gt = data.depths[v, 0]
        mask = (gt > 0) & (gt <= est_net.d_max)
        m = depth_metrics(depth[k, 0], gt, mask)
        rows.append([float(getattr(m, key)) for key in DEPTH_KEYS])
    scores = dict(zip(DEPTH_KEYS, np.mean(rows, axis=0).tolist(), strict=True))
    # L1 by band of elevation, over the pixels of both views in the band.
    gt = data.depths[[0, 2], 0].to(depth.dtype)
    ok = (gt > 0) & (gt <= est_net.d_max)
    for key, (total, count) in depth_l1_by_band(depth[:, 0], gt, ok).items():
        scores[key] = total / count if count else float("nan")
    return scores


def _with_true_depth(views, data, models):
    """A copy of ``views`` whose full-mode depth is the sources' ground truth at the estimator's
    working resolution (pixels without ground truth: the estimate)."""
    from panogrf.renderer.methods import SourceViews

    est = views.depth_for("full", models)
    gt = data.depths[[0, 2]].float()
    gt = torch.nn.functional.interpolate(gt, size=est.shape[-2:], mode="nearest")
    out = SourceViews(views.images, views.c2w)
    out.depth["full"] = torch.where(gt > 0, gt, est)
    return out


def _reprojected(data, height: int) -> torch.Tensor:
    """The middle view [3, H, 2H] made from the first and last views' full-resolution pixels at
    the points of its own true depth (see the module docstring, ``reprojected``)."""
    import torch.nn.functional as F

    from panogrf.model.erp import erp_directions, pad_seam, sample_padded, world_to_erp

    size = (height, 2 * height)
    gt = data.depths[1:2].float()
    depth = F.interpolate(gt, size=size, mode="nearest")[0, 0]
    c2w = data.c2w.float()
    points = c2w[1, :3, 3] + (erp_directions(*size) @ c2w[1, :3, :3].T) * depth[..., None]
    hi, wi = data.images.shape[-2:]
    colours, seen = [], []
    for v in (0, 2):
        uv, dist = world_to_erp(points.reshape(-1, 3), c2w[v], hi, wi)
        colours.append(sample_padded(pad_seam(data.images[v : v + 1], 2), uv[None], "bicubic", 2))
        own = sample_padded(pad_seam(data.depths[v : v + 1].float()), uv[None], "nearest")[0, 0]
        seen.append(((dist - own).abs() <= 0.05 * own) & (own > 0))
    colour = torch.stack(colours)[:, 0]  # [2, 3, N]
    weight = torch.stack(seen).float()  # [2, N]
    gap = torch.stack([(c2w[v, :3, 3] - c2w[1, :3, 3]).norm() for v in (0, 2)])
    nearest = (torch.arange(2) == gap.argmin()).float()[:, None].expand_as(weight)
    weight = torch.where(weight.sum(0, keepdim=True) > 0, weight, nearest)
    out = (colour * weight[:, None]).sum(0) / weight.sum(0)[None]
    return out.reshape(3, *size).clamp(0, 1)


def _true_via_256(data, height: int) -> torch.Tensor:
    """The true middle view through 256 rows, shown at ``height`` rows [3, H, 2H]."""
    from panogrf.renderer.cache import resize_erp
    from panogrf.renderer.detail import upsample_erp

    return upsample_erp(resize_erp(data.images[1:2], 256)[0], (height, 2 * height)).clamp(0, 1)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=Path("data/real"))
    parser.add_argument("--heights", default="512,256", help="render heights")
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--quality", default="fast", help="sampling of the neural methods")
    parser.add_argument("--out", type=Path, default=Path("lab/results/real_capture.json"))
    parser.add_argument(
        "--picture", type=Path, default=None, help="comparison PNG (default DATA/comparison.png)"
    )
    parser.add_argument("--threads", type=int, default=0)
    parser.add_argument(
        "--gt-depth", action="store_true", help="also render with the sources' true depth"
    )
    parser.add_argument(
        "--refine-depth",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="refine every multi-view depth per scene first, as the CLI does by default "
        "(--no-refine-depth: the networks' depth)",
    )
    args = parser.parse_args()
    if not (args.data / "dataset.json").exists():
        print(
            f"real_capture: no {args.data}/dataset.json; make the dev triplet with\n"
            "  python scripts/make_dev_triplet.py --mirror PATH/TO/PanSplat.git\n"
            "(a bare mirror of the public repository chengzhag/PanSplat). Nothing measured."
        )
        return 0
    if args.threads:
        torch.set_num_threads(args.threads)

    from panogrf.app.files.atomic import nan_to_null, write_json_atomic
    from panogrf.app.files.images import to_uint8, write_rgb
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scene.session import default_models
    from panogrf.app.scoring import image_scores
    from panogrf.model.refine import PREPARE_REFINE
    from panogrf.renderer.methods import SourceViews, prepare, render_view

    heights = [int(h) for h in args.heights.split(",")]
    methods = [m for m in args.methods.split(",") if m]
    if args.gt_depth:
        methods.append("gt_depth")
    models = default_models()
    image_rows: dict[tuple[str, int], list[dict]] = {}
    depth_rows: dict[str, list[dict]] = {m: [] for m in DEPTH_MODES}
    pictures = []
    start = time.perf_counter()
    for folder in triplets(args.data):
        scene = load_scene(folder, load_images=True)
        data = scene.images
        refine = PREPARE_REFINE if args.refine_depth else None
        views = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]], refine=refine)
        for mode in DEPTH_MODES:
            depth_rows[mode].append(depth_scores(models, views, data, mode))
        renders = {}
        for method in methods:
            method_views, render_as = views, method
            if method == "gt_depth":
                method_views, render_as = _with_true_depth(views, data, models), "panogrf"
            prepare(render_as, method_views, models)
            for h in heights:
                t0 = time.perf_counter()
                rgb = render_view(render_as, method_views, data.c2w[1], h, models, args.quality)
                sec = time.perf_counter() - t0
                scores = image_scores(rgb, data.images[1:2]) | {"seconds": sec}
                image_rows.setdefault((method, h), []).append(scores)
                renders[(method, h)] = rgb
                print(
                    f"{folder.name} {method:>9} {h:4d} rows: WS-PSNR {scores['ws_psnr']:.2f} "
                    f"LPIPS {scores['lpips']:.3f} ({sec:.1f} s)",
                    flush=True,
                )
        if args.gt_depth:
            references = [("reprojected", h, _reprojected) for h in heights]
            references += [("true_via_256", h, _true_via_256) for h in heights if h > 256]
            for name, h, make in references:
                scores = image_scores(make(data, h), data.images[1:2]) | {"seconds": 0.0}
                image_rows.setdefault((name, h), []).append(scores)
                print(
                    f"{folder.name} {name:>12} {h:4d} rows: WS-PSNR {scores['ws_psnr']:.2f} "
                    f"LPIPS {scores['lpips']:.3f}",
                    flush=True,
                )
        h0 = max(heights)
        from panogrf.renderer.cache import resize_erp

        panel = [resize_erp(data.images[1:2], h0)[0]]
        panel += [
            renders[(m, h0)] for m in ("panogrf", "no_mono", "meshwarp") if (m, h0) in renders
        ]
        pictures.append(torch.cat(panel, 1))  # stacked vertically
    seconds = time.perf_counter() - start

    image_table = {
        f"{m}@{h}": {k: statistics.fmean(r[k] for r in rows) for k in (*IMAGE_KEYS, "seconds")}
        | {"n": len(rows)}
        for (m, h), rows in image_rows.items()
    }
    depth_table = {
        mode: {k: statistics.fmean(r[k] for r in rows) for k in (*DEPTH_KEYS, *BAND_KEYS)}
        | {"n": len(rows)}
        for mode, rows in depth_rows.items()
    }
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    report = {
        "what": "middle view of each real triplet rendered from the first and last views",
        "data": str(args.data),
        "scenes": [p.name for p in triplets(args.data)],
        "quality": args.quality,
        "refine_depth": repr(PREPARE_REFINE) if args.refine_depth else None,
        "images": image_table,
        "depth_metres": depth_table,
        "machine": f"{platform.machine()}, {torch.get_num_threads()} torch threads, CPU",
        "seconds": round(seconds, 1),
        "commit": commit.stdout.strip(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out, nan_to_null(report))
    picture = args.picture or args.data / "comparison.png"
    write_rgb(picture, to_uint8(torch.cat(pictures, 1)))

    print(f"\nreal captures: {args.data} ({len(pictures)} triplet(s)); wrote {args.out}, {picture}")
    print(f"{'mode':>6} " + " ".join(f"{k:>8}" for k in DEPTH_KEYS) + "   (depth, metres)")
    for mode, r in depth_table.items():
        print(f"{mode:>6} " + " ".join(f"{r[k]:8.3f}" for k in DEPTH_KEYS))
    print(f"\n{'mode':>6} " + " ".join(f"{f'{hi}..{lo}':>8}" for hi, lo in BANDS), end="")
    print("   (depth L1 by elevation band, degrees; metres)")
    for mode, r in depth_table.items():
        print(f"{mode:>6} " + " ".join(f"{r[k]:8.3f}" for k in BAND_KEYS))
    print(
        f"\n{'method':>12} {'rows':>5} {'PSNR':>7} {'WS-PSNR':>8} {'SSIM':>6} {'LPIPS':>6} {'s':>6}"
    )
    order = [*methods, "reprojected", "true_via_256"]
    for m, h in sorted(image_rows, key=lambda k: (-k[1], order.index(k[0]))):
        r = image_table[f"{m}@{h}"]
        print(
            f"{m:>12} {h:5d} {r['psnr']:7.2f} {r['ws_psnr']:8.2f} {r['ssim']:6.3f} "
            f"{r['lpips']:6.3f} {r['seconds']:6.1f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
