"""Where a `fast` render's milliseconds go on a GPU: each part timed alone (synchronised), the
whole render, and a profiler trace of one render. Lab script for a lent GPU machine.

    python lab/gpu/render_parts.py --data data/loo_lit --out OUT_DIR [--device cuda]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
import warnings
from collections import Counter
from dataclasses import replace
from pathlib import Path

import torch


def timed(fn, device, repeats=20, warm=3) -> float:
    for _ in range(warm):
        fn()
    secs = []
    for _ in range(repeats):
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        t = time.perf_counter()
        fn()
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        secs.append(time.perf_counter() - t)
    return statistics.median(secs) * 1e3


def _syncs(fn) -> list[str]:
    """Where (file:line) ``fn`` made the host wait for the GPU (torch's sync debug mode)."""
    torch.cuda.synchronize()
    torch.cuda.set_sync_debug_mode("warn")
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            fn()
    finally:
        torch.cuda.set_sync_debug_mode(0)
    return [f"{Path(w.filename).name}:{w.lineno}" for w in caught]


def _variants(fn) -> dict:
    """The fast 512 render with TF32 matrix products, and under bf16 autocast: time and the
    difference from float32 (PSNR between the two images, max abs)."""
    ref = fn().rgb.float()
    out = {}
    for name in ("tf32", "bf16"):
        torch.backends.cuda.matmul.allow_tf32 = name == "tf32"
        with torch.autocast("cuda", dtype=torch.bfloat16, enabled=name == "bf16"):
            ms = timed(fn, torch.device("cuda"))
            rgb = fn().rgb.float()
        torch.backends.cuda.matmul.allow_tf32 = False
        mse = float(((rgb - ref) ** 2).mean())
        out[name] = {
            "ms": ms,
            "psnr_vs_fp32": -10 * math.log10(max(mse, 1e-20)),
            "max_abs": float((rgb - ref).abs().max()),
        }
        print(f"variant {name}: {out[name]}", flush=True)
    return out


def main() -> None:
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scene.session import default_models
    from panogrf.model.refine import PREPARE_REFINE
    from panogrf.model.splat import fill_holes, splat_zbuffer
    from panogrf.renderer import render
    from panogrf.renderer.detail import DEFAULT_DETAIL, add_detail, render_detailed
    from panogrf.renderer.methods import SourceViews

    p = argparse.ArgumentParser()
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--device", default="cuda")
    args = p.parse_args()
    device = torch.device(args.device)
    if device.type == "cuda":
        torch.backends.cudnn.allow_tf32 = torch.backends.cuda.matmul.allow_tf32 = False
    folder = next(f for f in sorted(args.data.iterdir()) if f.is_dir())
    data = load_scene(folder, load_images=True).images
    models = default_models(device)
    views = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]], refine=PREPARE_REFINE, device=device)
    cache = views.cache_for("panogrf", models)
    net = models.renderer("panogrf")
    c2w = data.c2w[1].to(device=device, dtype=cache.images.dtype)
    h = DEFAULT_DETAIL.net_height
    live = replace(DEFAULT_DETAIL, net_height=128, sampling="bicubic")
    src = torch.nn.functional.interpolate(cache.depth, size=(h, 2 * h), mode="nearest")
    zbuf = splat_zbuffer(src, cache.c2w, c2w, h, 2 * h)
    low = render.render_panorama(net, cache, c2w, h, "fast")
    origins, dirs = render.target_rays(c2w, h, 2 * h)
    sampling = render.sampling_for("fast", cache, c2w)
    proxy = render.proxy_for(cache, c2w, h, 2 * h)
    px = (proxy.near.reshape(-1), proxy.far.reshape(-1))
    parts = {
        "render_detailed fast 512 (the product's fast_512)": lambda: render_detailed(
            net, cache, c2w, 512, "fast"
        ),
        "render_detailed fast 1024": lambda: render_detailed(net, cache, c2w, 1024, "fast"),
        "live level (512, net 128, bicubic)": lambda: render_detailed(
            net, cache, c2w, 512, "fast", live
        ),
        f"render_panorama fast {h} (the network's pass)": lambda: render.render_panorama(
            net, cache, c2w, h, "fast"
        ),
        "sample_range": lambda: render.sample_range(cache, c2w[:3, 3]),
        f"proxy_for {h}": lambda: render.proxy_for(cache, c2w, h, 2 * h),
        f"splat_zbuffer {h}": lambda: splat_zbuffer(src, cache.c2w, c2w, h, 2 * h),
        f"fill_holes {h}": lambda: fill_holes(zbuf),
        f"render_chunks {h} (the network)": lambda: render.render_chunks(
            net, cache, origins, dirs, sampling, px, None, None, None
        ),
        "add_detail to 512": lambda: add_detail(cache, c2w, low, 512, DEFAULT_DETAIL),
    }
    out = {}
    with torch.no_grad():
        for name, fn in parts.items():
            out[name] = timed(fn, device)
            print(f"{name:55s} {out[name]:8.2f} ms", flush=True)
        if device.type == "cuda":  # where the device is waited for, per render
            out["syncs"] = {
                "fast_512": _syncs(lambda: render_detailed(net, cache, c2w, 512, "fast")),
                "live": _syncs(lambda: render_detailed(net, cache, c2w, 512, "fast", live)),
            }
            for name, where in out["syncs"].items():
                print(f"{name}: {len(where)} waits for the device: {Counter(where)}", flush=True)
            out["variants"] = _variants(lambda: render_detailed(net, cache, c2w, 512, "fast"))
        from torch.profiler import ProfilerActivity, profile

        acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.type == "cuda" else [])
        with profile(activities=acts) as prof:
            for _ in range(3):
                render_detailed(net, cache, c2w, 512, "fast")
            if device.type == "cuda":
                torch.cuda.synchronize(device)
    args.out.mkdir(parents=True, exist_ok=True)
    prof.export_chrome_trace(str(args.out / "render_trace.json"))
    sort = "self_cuda_time_total" if device.type == "cuda" else "self_cpu_time_total"
    (args.out / "render_ops.txt").write_text(prof.key_averages().table(sort_by=sort, row_limit=50))
    (args.out / "render_parts.json").write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
