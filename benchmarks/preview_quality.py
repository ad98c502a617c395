"""The GL preview's cost and quality, configuration by configuration.

    python benchmarks/preview_quality.py --data data/val_detail_classic data/val_detail_home

Each configuration: the rows of the depth meshes (and the triangles each is simplified to),
the rows the geometry is drawn at, and whether the colours are read from the sources at the
display's 512 rows (the sharp preview) or the preview is shown upsampled.
- cost: a frame as the viewer draws it while moving, on the bundled demo scene (3 sources,
  the 2 nearest drawn), headless EGL: the preview, then the display pass at 512 x 1024 (the
  sharp colours computed there, or the last push-pull step and the upsampling), the GL work
  finished each frame (``ctx.finish()``); median ms over a short walk, the configurations
  interleaved round by round so a machine that slows down for a while slows all alike; and
  the ratio to the first configuration, measured side by side;
- quality: WS-PSNR and LPIPS of the middle view drawn from the outer two at 512 rows, on
  validation scenes (generated from the train split's generator with seeds no training used:
  ``panogrf dataset make --split train --seed 90000`` classic, ``--seed 90001 --world home``;
  never the test split), depth estimated by the full estimator. The sharp colours are scored
  as `PreviewRenderer.render` reads them back (their own pass, the same code the viewer's
  display runs: tests/app/test_view_window.py checks that the two agree).
A table is printed last.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch


class Config(NamedTuple):
    name: str
    mesh_rows: int
    triangles: int | None  # each mesh simplified to this many (None: all kept)
    rows: int  # the geometry's rows
    sharp: bool  # colours read at the display's rows (else shown upsampled)


CONFIGS = (
    Config("drawn at 256, upsampled (round 8, moving)", 64, None, 256, False),
    Config("drawn at 512 (round 8, still)", 64, None, 512, False),
    Config("sharp, geometry at 192", 64, None, 192, True),
    Config("sharp, geometry at 128", 64, None, 128, True),
    Config("sharp, geometry at 128, 128-row meshes to 10k", 128, 10000, 128, True),
    Config("sharp, geometry at 128, 128-row meshes to 6k", 128, 6000, 128, True),
    Config("sharp, geometry at 128, 128-row meshes to 4k", 128, 4000, 128, True),
    Config("drawn at 256, upsampled, 128-row meshes to 10k", 128, 10000, 256, False),
)
DISPLAY = (512, 1024)


def frame_costs(views, configs, rounds: int = 5, frames: int = 15) -> dict[str, list[float]]:
    """Seconds per viewer frame of each configuration (see the module docstring)."""
    import moderngl

    from panogrf.app.files.images import to_uint8
    from panogrf.renderer.gl_preview import PreviewRenderer, create_headless_context
    from panogrf.shaders import load as load_shader

    ctx = create_headless_context()
    images, depth = to_uint8(views.images), views.depth["full"][:, 0].numpy()
    renderers = {
        (c.mesh_rows, c.triangles): PreviewRenderer(
            ctx, images, depth, views.c2w.numpy(), c.mesh_rows, 2, c.triangles
        )
        for c in configs
    }
    screen = ctx.texture(DISPLAY[::-1], 4)
    fbo = ctx.framebuffer([screen])
    displays = {}
    for sharp in (0, 1):
        defines = {"PERSPECTIVE": 0, "DEPTH": 0, "FILL": 1 - sharp, "ROTATE": 0, "SHARP": sharp}
        prog = ctx.program(
            vertex_shader=load_shader("fullscreen.vert"),
            fragment_shader=load_shader("display.frag", defines | {"VIEWS": 2}),
        )
        displays[sharp] = (prog, ctx.vertex_array(prog, []))
    times: dict[str, list[float]] = {c.name: [] for c in configs}
    pose = views.c2w[0].numpy().astype(np.float64)
    for _ in range(rounds):
        for c in configs:
            pr = renderers[c.mesh_rows, c.triangles]
            prog, vao = displays[int(c.sharp)]
            for k in range(frames + 2):
                p = pose.copy()
                p[2, 3] -= 0.02 * k  # walking forward
                t0 = time.perf_counter()
                out = pr.render_to_framebuffer(
                    p,
                    c.rows,
                    fill_top=False,
                    distance=False,
                    sharp_height=DISPLAY[0] if c.sharp else None,
                    sharp_pass=False,
                )
                fbo.use()
                fbo.viewport = (0, 0, DISPLAY[1], DISPLAY[0])
                if c.sharp:
                    pr.bind_sharp(prog, out.sharp, 2)
                else:
                    out.blend.use(location=0)
                    out.coarse.use(location=1)
                    prog["u_pano"].value, prog["u_coarse"].value = 0, 1
                prog["u_origin"].value = (0.0, 0.0)
                prog["u_size"].value = (float(DISPLAY[1]), float(DISPLAY[0]))
                vao.render(moderngl.TRIANGLES, vertices=3)
                ctx.finish()
                if k >= 2:
                    times[c.name].append(time.perf_counter() - t0)
    for pr in renderers.values():
        pr.release()
    ctx.release()
    return times


def upsample(rgb: np.ndarray, height: int) -> torch.Tensor:
    """An ERP preview [h, 2h, 3] uint8 -> [3, height, 2 height] in [0, 1], bilinear (the
    display's texture sampling), wrapping at the seam."""
    from panogrf.renderer.detail import upsample_erp

    x = torch.from_numpy(rgb).permute(2, 0, 1).float() / 255
    return upsample_erp(x, (height, 2 * height)) if rgb.shape[0] != height else x


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--data",
        type=Path,
        nargs="+",
        default=[Path("data/val_detail_classic"), Path("data/val_detail_home")],
    )
    parser.add_argument("--scenes", type=int, default=0, help="the last N scenes of each (0: all)")
    parser.add_argument("--out", type=Path, default=Path("lab/results/preview_quality.json"))
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
    times = frame_costs(views, CONFIGS)
    cost = {name: 1000 * statistics.median(t) for name, t in times.items()}
    base = CONFIGS[0].name
    print("ms per frame:", {k: round(v, 1) for k, v in cost.items()}, flush=True)

    folders = []
    for root in args.data:
        entries = json.loads((root / "dataset.json").read_text())["scenes"]
        folders += [root / e["folder"] for e in entries[-args.scenes :]]
    models = default_models()
    ctx = create_headless_context()
    scores: dict[str, list[dict]] = {c.name: [] for c in CONFIGS}
    height = None
    for folder in folders:
        d = load_scene(folder, load_images=True).images
        v = SourceViews(d.images[[0, 2]], d.c2w[[0, 2]])
        depth = v.depth_for("full", models)[:, 0].numpy()
        images = to_uint8(d.images[[0, 2]])
        height = d.images.shape[-2]
        pose = d.c2w[1].numpy()
        for c in CONFIGS:
            with PreviewRenderer(
                ctx, images, depth, d.c2w[[0, 2]].numpy(), c.mesh_rows, mesh_triangles=c.triangles
            ) as pr:
                if c.sharp:
                    rgb, _ = pr.render(pose, height, geometry_height=c.rows)
                else:
                    rgb, _ = pr.render(pose, c.rows)
            scores[c.name].append(image_scores(upsample(rgb, height), d.images[1:2]))
        print(folder, flush=True)
    ctx.release()

    rows = {}
    for c in CONFIGS:
        rows[c.name] = c._asdict() | {
            "frame_ms": cost[c.name],
            "frame_ratio": cost[c.name] / cost[base],
            "fps": 1000 / cost[c.name],
            "ws_psnr": statistics.mean(s["ws_psnr"] for s in scores[c.name]),
            "lpips": statistics.mean(s["lpips"] for s in scores[c.name]),
        }
    report = {
        "what": "GL preview: a viewer frame at 512x1024 while moving (demo, 2 sources drawn, "
        "median ms, ratio to the first row measured side by side) and the middle view from the "
        "outer two at the data's rows (WS-PSNR dB, LPIPS)",
        "quality_scenes": [f"{f.parent.name}/{f.name}" for f in folders],
        "quality_height": int(height),
        "configs": rows,
        "machine": "2-core CPU, Mesa llvmpipe (EGL)",
    }
    write_json_atomic(args.out, report)
    print(f"\n{'configuration':<48} {'ms':>6} {'ratio':>6} {'fps':>6} {'WS-PSNR':>8} {'LPIPS':>7}")
    for name, r in rows.items():
        print(
            f"{name:<48} {r['frame_ms']:>6.1f} {r['frame_ratio']:>6.2f} {r['fps']:>6.1f} "
            f"{r['ws_psnr']:>8.2f} {r['lpips']:>7.3f}"
        )
    names = ", ".join(str(d) for d in args.data)
    print(f"({len(folders)} validation scenes of {names} at {height} rows; wrote {args.out})")


if __name__ == "__main__":
    main()
