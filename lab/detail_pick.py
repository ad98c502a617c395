"""Which sources give a novel view its detail: the agreement-weighted blend of all (shipped)
against one source per pixel (issue 56: two misaligned copies of a texture average to a blur).

    python lab/detail_pick.py --data data/loo_classic data/loo_home data/loo_lit ZIND_SCENES... \
        --out lab/results/detail_pick.json

Per scene (three views, the middle one rendered from the outer two at 512 rows): the shipped
preparation (mode full, per-scene refinement), one `fast` network pass at 256 rows, then the
detail above 32 rows added by each variant from that same pass:
- ``blend``: shipped (`panogrf.renderer.detail.add_detail`);
- ``best``: each pixel's detail from the source that agrees best with the network there;
- ``sharpN``: the agreement weights raised to the power N, normalised (between the two);
- ``visT`` / ``occlT``: the agreement weights times each source's geometric consistency at the
  point: its own depth where the point projects against its distance to the point, as a log
  ratio r, factor 0.05 + 0.95 exp(-(r / T)^2) (``vis``: both sides; ``occl``: only where the
  source's depth is nearer, i.e. something hides the point from it), normalised.
The gate (no detail where no source agrees) is the shipped one in every variant.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))


def consistency(cache, c2w, depth_low, tau: float, one_sided: bool):
    """[V, h, 2h] factor in (0.05, 1]: how well each source's own depth agrees with its
    distance to the target's points at ``depth_low`` [1, h, 2h] (nearest depth texel)."""
    from panogrf.model.erp import direction_to_pixel, erp_directions, pad_seam, sample_padded

    h, w = depth_low.shape[-2:]
    dirs = erp_directions(h, w, dtype=depth_low.dtype) @ c2w[:3, :3].T
    points = c2w[:3, 3] + dirs * depth_low[0, ..., None]
    w2c = cache.w2c
    cam = points.reshape(1, -1, 3) @ w2c[:, :3, :3].transpose(1, 2) + w2c[:, None, :3, 3]
    dist = cam.norm(dim=-1)  # [V, N]
    hd, wd = cache.depth.shape[-2:]
    uv = direction_to_pixel(cam, hd, wd)
    own = sample_padded(pad_seam(cache.depth), uv, "nearest")[:, 0]  # [V, N]
    r = torch.log(own.clamp(min=1e-3) / dist.clamp(min=1e-3))
    if one_sided:
        r = r.clamp(max=0.0)
    f = 0.05 + 0.95 * torch.exp(-((r / tau) ** 2))
    return f.reshape(-1, h, w)


def ray_angles(cache, c2w, depth_low):
    """[V, h, 2h] angle (radians) at each of the target's points at ``depth_low`` [1, h, 2h]
    between the target's ray and each source's ray to it (unstructured lumigraph's penalty)."""
    from panogrf.model.erp import erp_directions

    h, w = depth_low.shape[-2:]
    dirs = erp_directions(h, w, dtype=depth_low.dtype) @ c2w[:3, :3].T  # [h, w, 3] unit
    points = c2w[:3, 3] + dirs * depth_low[0, ..., None]
    centres = cache.c2w[:, :3, 3]  # [V, 3]
    to_point = points[None] - centres[:, None, None]  # [V, h, w, 3]
    to_point = to_point / to_point.norm(dim=-1, keepdim=True).clamp(min=1e-6)
    cos = (to_point * dirs[None]).sum(-1).clamp(-1.0, 1.0)
    return torch.arccos(cos)


def _gray8(x):
    """[3, H, W] colour in [0, 1] -> uint8 grey numpy image."""
    g = (0.299 * x[0] + 0.587 * x[1] + 0.114 * x[2]).clamp(0, 1)
    return (g * 255 + 0.5).to(torch.uint8).numpy()


def floating(proj, up_w, preset: str, wrap: int = 64):
    """Floating textures (Eisemann et al. 2008): each projection [V, 3, H, W] warped towards
    where the others, weighted by ``up_w`` [V, H, W], see the same texture, by optical flow
    (OpenCV's DIS) between the projections, so that a blend of misaligned copies has one copy."""
    import cv2
    import numpy as np

    presets = {"u": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, "f": cv2.DISOPTICAL_FLOW_PRESET_FAST,
               "m": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}  # fmt: skip
    dis = cv2.DISOpticalFlow_create(presets[preset])
    v, _, h, w = proj.shape
    grey = [np.concatenate((g[:, -wrap:], g, g[:, :wrap]), axis=1) for g in map(_gray8, proj)]
    out = torch.empty_like(proj)
    ys, xs = torch.meshgrid(
        torch.arange(h, dtype=proj.dtype), torch.arange(w, dtype=proj.dtype), indexing="ij"
    )
    for i in range(v):
        shift = torch.zeros(2, h, w, dtype=proj.dtype)
        for j in range(v):
            if j == i:
                continue
            f = dis.calc(grey[i], grey[j], None)[:, wrap : wrap + w]  # I_i(x) ~ I_j(x + f)
            shift += up_w[j] * torch.from_numpy(np.ascontiguousarray(f)).permute(2, 0, 1)
        sx = (xs - shift[0]) % w
        sy = (ys - shift[1]).clamp(0, h - 1)
        grid = torch.stack((sx / (w - 1) * 2 - 1, sy / (h - 1) * 2 - 1), -1)[None]
        out[i] = torch.nn.functional.grid_sample(
            proj[i : i + 1], grid, mode="bilinear", padding_mode="border", align_corners=True
        )[0]
    return out


def add_detail_pick(cache, c2w, low, height, config, pick: str):
    from panogrf.renderer import detail as D
    from panogrf.renderer.cache import resize_erp

    size = (height, 2 * height)
    h = low.rgb.shape[-2]
    depth = D._upsample_depth(D.projection_depth(cache, c2w, low, config), size)
    sampling = config.sampling if height >= cache.images.shape[-2] else "bilinear"
    proj, masked = D._projected(cache, c2w.to(depth.dtype), depth[0], sampling)
    proj_low = resize_erp(proj, h)
    diff = D._smooth((proj_low - low.rgb[None]).abs().mean(1))
    weight = torch.exp(-diff / config.agreement)
    if masked is not None:
        weight = weight * D.mask_factor(resize_erp(masked, h)[:, 0])
    total = weight.sum(0, keepdim=True)
    if pick == "blend":
        blend_w = weight / total.clamp(min=1e-6)
    elif pick == "best":
        blend_w = torch.nn.functional.one_hot(weight.argmax(0), weight.shape[0])
        blend_w = blend_w.permute(2, 0, 1).to(weight.dtype)
    elif pick.startswith(("vis", "occl")):
        tau = float(pick.removeprefix("vis").removeprefix("occl"))
        depth_low = D.projection_depth(cache, c2w, low, config)
        f = consistency(cache, c2w, depth_low, tau, pick.startswith("occl"))
        p = weight * f
        blend_w = p / p.sum(0, keepdim=True).clamp(min=1e-12)
    elif pick.startswith("ulr"):
        power = float(pick.removeprefix("ulr"))
        depth_low = D.projection_depth(cache, c2w, low, config)
        theta = ray_angles(cache, c2w, depth_low)
        p = weight * (1.0 / (theta + 0.0175)) ** power  # 1 degree: the source's own pose
        blend_w = p / p.sum(0, keepdim=True).clamp(min=1e-12)
    elif pick.startswith(("dist", "float")):
        power = 2.0 if pick.startswith("float") else float(pick[4:].removesuffix("lp"))
        d = (cache.c2w[:, :3, 3] - c2w[:3, 3]).norm(dim=-1)  # [V] metres from the target
        p = weight * ((1.0 / (d + 0.01)) ** power)[:, None, None]  # 1 cm: the source's pose
        blend_w = p / p.sum(0, keepdim=True).clamp(min=1e-12)
    else:
        k = float(pick.removeprefix("sharp"))
        p = weight**k
        blend_w = p / p.sum(0, keepdim=True).clamp(min=1e-12)
    gate = total.clamp(max=1.0)
    up = D.upsample_erp(torch.cat((low.rgb, gate, blend_w)), size)
    up_rgb, up_gate, up_w = up[:3], up[3:4], up[4:]
    if pick.startswith("float"):
        proj = floating(proj, up_w, pick.removeprefix("float") or "m")
    blend = (up_w[:, None] * proj).sum(0)
    cut = min(config.cutoff or h, h)
    diff = blend - up_rgb if cut < h else blend
    low_share = 1.0
    if pick.endswith("lp"):  # near a photo the blend's low band too, halfway the network's
        d = (cache.c2w[:, :3, 3] - c2w[:3, 3]).norm(dim=-1)
        p = (1.0 / (d + 0.01)) ** float(pick.removeprefix("dist").removesuffix("lp"))
        share = float(p.max() / p.sum())
        v = p.numel()
        low_share = min(1.0, max(0.0, (1.0 - share) / (1.0 - 1.0 / v)))
    detail = diff - low_share * D.upsample_erp(resize_erp(diff[None], cut)[0], size)
    return (up_rgb + up_gate * detail).clamp(0, 1)


def main() -> None:
    from depth_stages import middle_first, scene_folders

    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scene.session import default_models
    from panogrf.app.scoring import image_scores
    from panogrf.model.refine import PREPARE_REFINE
    from panogrf.renderer.detail import DEFAULT_DETAIL
    from panogrf.renderer.methods import SourceViews
    from panogrf.renderer.render import render_panorama

    parser = argparse.ArgumentParser()
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--variants", default="blend,best,sharp2,sharp4")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("lab/results/detail_pick.json"))
    parser.add_argument("--save", type=Path, help="folder for each variant's render (PNG)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    variants = args.variants.split(",")
    models = default_models()
    net = models.renderer("panogrf")
    rows: dict[str, dict[str, list[dict]]] = {v: {} for v in variants}
    for folder in scene_folders(args.data):
        group = folder.parent.name if (folder.parent / "dataset.json").exists() else "real"
        data = middle_first(load_scene(folder, load_images=True).images, 512)
        views = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]], refine=PREPARE_REFINE)
        cache = views.cache_for("panogrf", models)
        with torch.no_grad():
            low = render_panorama(net, cache, data.c2w[1], DEFAULT_DETAIL.net_height, "fast")
            for v in variants:
                rgb = add_detail_pick(cache, data.c2w[1], low, 512, DEFAULT_DETAIL, v)
                s = image_scores(rgb, data.images[1:2])
                if args.save is not None:
                    import cv2

                    args.save.mkdir(parents=True, exist_ok=True)
                    img = (rgb.permute(1, 2, 0).numpy()[..., ::-1] * 255 + 0.5).astype("uint8")
                    cv2.imwrite(str(args.save / f"{group}_{folder.name}_{v}.png"), img)
                    true = data.images[1].permute(1, 2, 0).numpy()[..., ::-1]
                    cv2.imwrite(str(args.save / f"{group}_{folder.name}_true.png"),
                                (true * 255 + 0.5).astype("uint8"))  # fmt: skip
                row = {k: s[k] for k in ("ws_psnr", "ssim", "lpips")} | {"scene": str(folder)}
                rows[v].setdefault(group, []).append(row)
                print(f"{group}/{folder.name} {v:>7}: {s['ws_psnr']:.2f} dB LPIPS {s['lpips']:.3f}",
                      flush=True)  # fmt: skip
        table = {
            v: {
                g: {k: statistics.fmean(r[k] for r in rs) for k in ("ws_psnr", "ssim", "lpips")}
                for g, rs in [*per.items(), ("pooled", [r for rs in per.values() for r in rs])]
            }
            for v, per in rows.items()
        }
        args.out.write_text(json.dumps({"table": table, "rows": rows}, indent=1))
    print(f"\n{'variant':>8} " + " ".join(f"{g:>22}" for g in table[variants[0]]))
    for v in variants:
        cells = [f"{t['ws_psnr']:6.2f} / {t['lpips']:.4f}" for t in table[v].values()]
        print(f"{v:>8} " + " ".join(f"{c:>22}" for c in cells))


if __name__ == "__main__":
    main()
