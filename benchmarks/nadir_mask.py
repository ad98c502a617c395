"""The capture rig at the nadir: a held-out view with and without the sources' nadir masks.

    python benchmarks/nadir_mask.py [--height 256] [--quality fast] [--no-preview]

The bundled demo scene (assets/demo, which has no rig of its own) gets a rig painted at the
nadir of every panorama, as a real capture has: a dark tripod (a hub of 8 degrees and three
legs reaching 15 degrees from the nadir) or a grey blob (a cap of 12 % of the rows, 21.6
degrees, as `panogrf.app.train.augment.photometric` paints). The middle view is rendered from
the outer two with the shipped networks, depth estimated from the (rigged) sources as `panogrf
render` does (no per-scene refinement; ``--depth true``: the scene's true depth), and scored
against the real middle view (WS-PSNR, LPIPS: `panogrf.app.scoring.image_scores`), over the
whole panorama and over the pixels where a source's rig lands in the view (its true surface
points that project into a source's rig: mean absolute error there). Variants:

- ``clean``: the sources without a rig (the ceiling of what masking can reach);
- ``no mask``: the rigged sources as they are (what a real capture got until now);
- ``auto``: the masks detected per source (`panogrf.renderer.nadir`, the default);
- ``cap 20``: a fixed cap of 20 degrees;
- ``weights only``: the detected masks, the sources' pixels not inpainted (the renderer's
  zero weights and the floor depth alone);
- ``inpaint only``: the detected masks' pixels inpainted, the renderer told nothing.

The GL preview (``--quality preview`` of `render`, drawn at the same rows) is scored too, with
and without the masks. Writes lab/results/nadir_mask.json; a table is printed last.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import torch
import torch.nn.functional as F

SOURCES = [0, 2]


def rig_masks(height: int, width: int) -> dict[str, tuple[torch.Tensor, tuple]]:
    """The painted rigs: name -> (mask [H, W] bool, colour)."""
    lat = 90.0 - 180.0 * (torch.arange(height, dtype=torch.float64) + 0.5) / height
    lon = 2 * math.pi * ((torch.arange(width, dtype=torch.float64) + 0.5) / width - 0.5)
    rho = (lat + 90.0).view(height, 1).expand(height, width)
    tripod = rho < 8.0
    for a in (0.3, 2.4, 4.5):
        d = torch.remainder(lon - a + math.pi, 2 * math.pi) - math.pi
        tripod = tripod | ((d.abs().view(1, width) < 0.15) & (rho < 15.0))
    blob = rho < 0.12 * 180.0
    return {"tripod": (tripod, (0.05, 0.05, 0.06)), "blob": (blob, (0.3, 0.28, 0.25))}


def where_rig_lands(data, mask: torch.Tensor, height: int) -> torch.Tensor:
    """[H, 2H] bool: the middle view's pixels whose true surface point projects into the rig
    ``mask`` of an outer source."""
    from panogrf.model.erp import erp_directions, sample_erp, world_to_erp

    depth = F.interpolate(data.depths[1:2], size=(height, 2 * height), mode="nearest")[0, 0]
    c2w = data.c2w[1].double()
    dirs = erp_directions(height, 2 * height, dtype=torch.float64) @ c2w[:3, :3].T
    points = (c2w[:3, 3] + dirs * depth.double()[..., None]).reshape(1, -1, 3)
    hit = torch.zeros(height, 2 * height, dtype=torch.bool)
    for k in SOURCES:
        uv, _ = world_to_erp(points, data.c2w[k].double(), *mask.shape)
        hit |= sample_erp(mask[None, None].double(), uv, "nearest")[0, 0].reshape(hit.shape) > 0.5
    return hit


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--height", type=int, default=256)
    parser.add_argument("--quality", default="fast", choices=("draft", "fast", "paper"))
    parser.add_argument("--no-preview", action="store_true", help="skip the GL preview")
    parser.add_argument(
        "--depth",
        default="estimated",
        choices=("estimated", "true"),
        help="the sources' depth: estimated from the (rigged) sources by the shipped networks "
        "(what `render` does), or the scene's true depth (faster; the rig then does not reach "
        "the depth, and the floor-plane fill is not exercised)",
    )
    parser.add_argument("--out", type=Path, default=Path("lab/results/nadir_mask.json"))
    args = parser.parse_args()

    from panogrf.app.files.images import to_uint8, write_json_atomic
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scene.session import default_models
    from panogrf.app.scoring import image_scores
    from panogrf.assets import path as asset_path
    from panogrf.renderer.methods import SourceViews, render_view
    from panogrf.renderer.nadir import inpaint_masked, nadir_masks

    data = load_scene(asset_path("demo"), load_images=True).images
    models = default_models()
    h = args.height
    gt = data.images[1:2]
    rows, results = [], {}
    ctx = None
    if not args.no_preview:
        from panogrf.renderer.gl_preview import create_headless_context

        ctx = create_headless_context()

    def views_for(images: torch.Tensor, variant: str) -> SourceViews:
        if variant in ("clean", "no mask"):
            return SourceViews(images, data.c2w[SOURCES])
        if variant == "auto":
            return SourceViews(images, data.c2w[SOURCES], nadir="auto")
        if variant == "cap 20":
            return SourceViews(images, data.c2w[SOURCES], nadir=20.0)
        # The ablations start from the balanced sources and the detected masks.
        plain = SourceViews(images, data.c2w[SOURCES])
        masks, _ = nadir_masks(plain.images, "auto")
        if variant == "weights only":
            return SourceViews(plain.images, plain.c2w, nadir_mask=masks)
        filled = inpaint_masked(plain.images, masks)
        return SourceViews(filled, plain.c2w)

    def preview(views: SourceViews) -> torch.Tensor:
        from panogrf.renderer.gl_preview import PreviewRenderer

        depth = views.depth_for("full", models)[:, 0].numpy()
        m = None if views.nadir_mask is None else views.nadir_mask[:, 0].numpy()
        with PreviewRenderer(ctx, to_uint8(views.images), depth, views.c2w.numpy(), masks=m) as p:
            rgb, _ = p.render(data.c2w[1].numpy(), h)
        return torch.from_numpy(rgb).permute(2, 0, 1).float() / 255.0

    variants = ("clean", "no mask", "auto", "cap 20", "weights only", "inpaint only")
    clean_done: dict = {}  # the clean sources do not depend on the rig: rendered once
    clean_row: list = []
    for rig, (mask, colour) in rig_masks(*data.images.shape[-2:]).items():
        rigged = data.images.clone()
        rigged[:, :, mask] = torch.tensor(colour, dtype=rigged.dtype).view(1, 3, 1)
        lands = where_rig_lands(data, mask, h)
        gt_small = F.interpolate(gt, size=(h, 2 * h), mode="area")[0]
        for variant in variants:
            if variant == "clean" and clean_done:
                results[f"{rig}/clean"] = clean_done
                rows.append((rig, variant, *clean_row))
                continue
            images = data.images[SOURCES] if variant == "clean" else rigged[SOURCES]
            t0 = time.perf_counter()
            views = views_for(images, variant)
            if args.depth == "true":
                true = F.interpolate(data.depths[SOURCES], size=(128, 256), mode="nearest")
                views.depth["full"] = true
            views.depth_for("full", models)
            prep = time.perf_counter() - t0
            t0 = time.perf_counter()
            rgb = render_view("panogrf", views, data.c2w[1], h, models, args.quality)
            sec = time.perf_counter() - t0
            s = image_scores(rgb, gt)
            region = float((rgb - gt_small)[:, lands].abs().mean())
            entry = {
                **s,
                "rig_region_mae": region,
                "prepare_s": prep,
                "nadir_s": views.seconds.get("nadir", 0.0),
                "render_s": sec,
                "notes": views.nadir_notes,
            }
            row = [s["ws_psnr"], s["lpips"], region]
            if ctx is not None:
                pv = preview(views)
                ps = image_scores(pv, gt)
                pregion = float((pv - gt_small)[:, lands].abs().mean())
                entry["preview"] = {**ps, "rig_region_mae": pregion}
                row += [ps["ws_psnr"], ps["lpips"], pregion]
            row += [views.seconds.get("nadir", 0.0)]
            results[f"{rig}/{variant}"] = entry
            if variant == "clean":
                clean_done, clean_row = entry, row
            rows.append((rig, variant, *row))
            scores = " ".join(f"{v:.4f}" for v in row)
            print(f"{rig} {variant}: {scores} ({prep + sec:.1f} s)", flush=True)
        results[f"{rig}/lands_fraction"] = float(lands.float().mean())
    if ctx is not None:
        ctx.release()

    write_json_atomic(
        args.out,
        {
            "what": "demo scene's middle view from the outer two, a rig painted at every nadir",
            "height": h,
            "quality": args.quality,
            "depth": args.depth,
            "results": results,
        },
    )
    head = f"{'rig':7} {'variant':13} {'WS-PSNR':>8} {'LPIPS':>6} {'rig MAE':>8}"
    if ctx is not None:
        head += f" | {'preview':>8} {'LPIPS':>6} {'rig MAE':>8}"
    print(head + f" | {'mask s':>6}")
    for rig, variant, *vals in rows:
        line = f"{rig:7} {variant:13} {vals[0]:8.2f} {vals[1]:6.3f} {vals[2]:8.4f}"
        if ctx is not None:
            line += f" | {vals[3]:8.2f} {vals[4]:6.3f} {vals[5]:8.4f}"
        print(line + f" | {vals[-1]:6.2f}")


if __name__ == "__main__":
    main()
