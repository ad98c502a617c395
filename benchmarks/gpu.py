"""The chain on a GPU against the CPU: a new scene end to end, renders, memory, the same pixels.

    python benchmarks/gpu.py --data data/loo_lit [--device cuda] [--scenes 6] \
        [--cpu-scenes 1] [--out lab/results/gpu.json] [--profile DIR]

For each scene folder of three 512x1024 panoramas (the middle one is the target):

- **new scene end to end**: the two outer panoramas read from disk, exposure balance, mode full's
  depth, the per-scene refinement, the renderer's feature maps and the first `fast` render of
  the middle view at 512 rows, on ``--device`` (the GPU synchronised before every clock read),
  with each stage's seconds; the first scene is the cold start (CUDA context, kernels loaded);
  the table gives the median of the others. The same on the CPU for ``--cpu-scenes`` scenes
  (this machine's cores: say which).
- **renders** of a prepared scene: `fast` and `paper` at 512 and 1024 rows, median of 5 after
  two warm-ups; the viewer's refined view is the `fast` render at 512 rows.
- **peak memory** on the GPU (torch's allocator) over the whole run.
- **the same pixels**: on the CPU-measured scenes, the depth's L1 between the devices (metres)
  and the WS-PSNR of each device's render against the true middle view.

``--chunks A,B,..``: the renders of the first scene again with each GPU chunk (sample points
per view in one pass of the network, `renderer.render.GPU_CHUNK`), their times and the peak
memory above the prepared scene's. ``--graphs``: the first scene's per-scene refinement with and
without CUDA graphs (`model.refine.CUDA_GRAPHS`) from the same estimate, median of 3 each, the
depth L1 between them, and on the CPU from that estimate too.

``--profile DIR``: torch's profiler over one warm preparation and one `fast` render, the top
operators by device time written to DIR. Prints a table last and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import torch


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def new_scene(folder: Path, models, device: torch.device, rows: int = 512) -> dict:
    """A new scene prepared from its files and its first render, each stage timed."""
    from panogrf.app.scene.folder import load_scene
    from panogrf.model.refine import PREPARE_REFINE
    from panogrf.renderer.methods import METHODS, SourceViews, render_view

    spec = METHODS["panogrf"]
    times = {}
    _sync(device)
    t0 = time.perf_counter()
    data = load_scene(folder, load_images=True).images
    times["read"] = time.perf_counter() - t0
    t = time.perf_counter()
    views = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]], refine=PREPARE_REFINE, device=device)
    _sync(device)
    times["balance"] = time.perf_counter() - t
    t = time.perf_counter()
    views.refine = None  # the estimate first, then the refinement, each timed
    with torch.no_grad():
        depth = views.depth_for(spec.depth_mode, models)
    _sync(device)
    times["depth"] = time.perf_counter() - t
    t = time.perf_counter()
    views.refine = PREPARE_REFINE
    views.plain = depth.clone()  # the estimate before the refinement (`parity`)
    depth = views.refined_depth(depth, spec.depth_mode, models)
    views.depth[spec.depth_mode] = depth
    _sync(device)
    times["refine"] = time.perf_counter() - t
    t = time.perf_counter()
    views.cache_for(spec, models)
    _sync(device)
    times["maps"] = time.perf_counter() - t
    t = time.perf_counter()
    rgb = render_view("panogrf", views, data.c2w[1], rows, models, "fast")
    _sync(device)
    times["render"] = time.perf_counter() - t
    times["total"] = time.perf_counter() - t0
    return {"times": times, "views": views, "rgb": rgb, "data": data}


def render_times(
    views, target, models, device, repeats=5, warm=2, skip=(), rows_list=(512, 1024)
) -> dict:
    from panogrf.renderer.methods import render_view

    out = {}
    for quality in ("fast", "paper"):
        for rows in rows_list:
            if f"{quality}_{rows}" in skip:
                continue
            for _ in range(warm):
                render_view("panogrf", views, target, rows, models, quality)
            _sync(device)
            secs = []
            for _ in range(repeats):
                t = time.perf_counter()
                render_view("panogrf", views, target, rows, models, quality)
                _sync(device)
                secs.append(time.perf_counter() - t)
            out[f"{quality}_{rows}"] = statistics.median(secs)
    return out


def chunk_sweep(views, target, models, device, chunks, rows_list) -> list[dict]:
    """The renders with each GPU chunk: median seconds and peak memory above the scene's."""
    from panogrf.renderer import render

    saved, out = render.GPU_CHUNK, []
    for chunk in chunks:
        render.GPU_CHUNK = chunk
        _sync(device)
        base = torch.cuda.memory_allocated(device) if device.type == "cuda" else 0
        if device.type == "cuda":
            torch.cuda.reset_peak_memory_stats(device)
        times = render_times(views, target, models, device, 3, 1, ("paper_1024",), rows_list)
        peak = torch.cuda.max_memory_allocated(device) - base if device.type == "cuda" else 0
        out.append({"chunk": chunk, "renders_s": times, "peak_extra_mib": peak / 2**20})
        print(
            f"chunk {chunk}: "
            + " ".join(f"{k} {1000 * v:.1f} ms" for k, v in times.items())
            + f"; peak +{peak / 2**20:.0f} MiB",
            flush=True,
        )
    render.GPU_CHUNK = saved
    return out


def refine_graphs(views, models, device, repeats=3) -> dict:
    """The refinement of the same estimate with and without CUDA graphs, and on the CPU."""
    from panogrf.model import refine
    from panogrf.model.depth_config import compared_sources
    from panogrf.model.refine import refine_depth

    out, depths = {}, {}
    for graphs in (False, True):
        refine.CUDA_GRAPHS = graphs
        secs = []
        for _ in range(repeats):
            _sync(device)
            t = time.perf_counter()
            depths[graphs] = views.refined_depth(views.plain, "full", models)
            _sync(device)
            secs.append(time.perf_counter() - t)
        out["graphs" if graphs else "launches"] = {"median_s": statistics.median(secs), "s": secs}
    refine.CUDA_GRAPHS = True
    again = views.refined_depth(views.plain, "full", models)
    out["l1_graphs_vs_launches_m"] = float((depths[True] - depths[False]).abs().mean())
    out["l1_graphs_repeat_m"] = float((depths[True] - again).abs().mean())
    # The same estimate refined on the CPU, and there moved by one part in a million (the
    # refinement's own sensitivity).
    est = default_models_cpu().estimator("full")
    c2w = views.c2w.cpu()
    sources = compared_sources(est.config, c2w, est.view_sources(c2w)[0])
    plain = views.plain.cpu()
    config = views.refine
    args = (c2w.to(plain.dtype), plain, sources, config, (0.05, est.d_max))
    with torch.enable_grad():
        gpu = refine_depth(
            views.images,
            views.c2w.to(views.plain.dtype),
            views.plain,
            sources,
            config,
            (0.05, est.d_max),
        )
        cpu = refine_depth(views.images.cpu(), *args)
        moved = refine_depth(views.images.cpu(), args[0], plain * (1 + 1e-6), *args[2:])
    out["parity"] = {
        "l1_device_vs_cpu_m": float((gpu.cpu() - cpu).abs().mean()),
        "l1_cpu_vs_cpu_moved_1e-6_m": float((moved - cpu).abs().mean()),
        "l1_cpu_vs_plain_m": float((cpu - plain).abs().mean()),
    }
    print(f"refinement: {json.dumps(out)}", flush=True)
    return out


def live_rate(views, target, models, seconds: float = 3.0) -> dict:
    """The viewer's live worker (`RenderWorker` ``live``, its `LIVE_LEVELS`: 512 x 1024) while
    the camera moves: a new pose every 4 ms (a window at 250 fps), for ``seconds``; frames
    published per second and the median request-to-frame seconds of those it finished."""
    import numpy as np

    from panogrf.app.viewer.worker import LIVE_LEVELS, RenderWorker

    cache = views.cache_for("panogrf", models)
    worker = RenderWorker(models.renderer("panogrf"), cache, LIVE_LEVELS, live=True).start()
    pose = target.double().cpu().numpy()
    seen, latencies = set(), []
    try:
        worker.request(pose)  # after its warm-up, the first frame
        end = time.perf_counter() + 30
        while worker.latest() is None and time.perf_counter() < end:
            time.sleep(0.001)
        start = time.perf_counter()
        step = 0
        while time.perf_counter() - start < seconds:
            step += 1
            moved = pose.copy()
            moved[0, 3] += 0.0005 * step  # 0.5 mm per request: 12.5 cm/s at 250 requests/s
            worker.request(moved)
            time.sleep(0.004)
            latest = worker.latest()
            if latest is not None and latest.generation not in seen:
                seen.add(latest.generation)
                latencies.append(latest.seconds)
        elapsed = time.perf_counter() - start
    finally:
        worker.stop()
    out = {
        "frames_per_s": len(seen) / elapsed,
        "median_request_to_frame_s": float(np.median(latencies)) if latencies else None,
        "requests": step,
        "levels": [list(lv) for lv in LIVE_LEVELS],
        "error": worker.error,
    }
    print(f"live: {json.dumps(out)}", flush=True)
    return out


def sweep_compare(data, models, device, repeats=3) -> dict:
    """Mode full's depth of the two outer views with the sweep's candidates scored one at a
    time and all at once (`model.sweep.GPU_BATCH`): median seconds and the L1 between them."""
    from panogrf.model import sweep
    from panogrf.renderer.methods import SourceViews

    out, depth = {}, {}
    for batch in (False, True):
        sweep.GPU_BATCH = batch
        secs = []
        for _ in range(repeats):
            views = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]], refine=None, device=device)
            _sync(device)
            t = time.perf_counter()
            with torch.no_grad():
                depth[batch] = views.depth_for("full", models)
            _sync(device)
            secs.append(time.perf_counter() - t)
        out["batched" if batch else "one_at_a_time"] = {"median_s": statistics.median(secs)}
    sweep.GPU_BATCH = True
    out["l1_between_m"] = float((depth[True] - depth[False]).abs().mean())
    print(f"sweep: {json.dumps(out)}", flush=True)
    return out


def default_models_cpu():
    from panogrf.app.scene.session import default_models

    return default_models("cpu")


def profile(views, data, models, device, out_dir: Path) -> None:
    from torch.profiler import ProfilerActivity
    from torch.profiler import profile as torch_profile

    from panogrf.model.refine import PREPARE_REFINE
    from panogrf.renderer.methods import SourceViews, render_view

    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.type == "cuda" else [])
    sort = "self_cuda_time_total" if device.type == "cuda" else "self_cpu_time_total"
    out_dir.mkdir(parents=True, exist_ok=True)
    with torch_profile(activities=activities) as prof:
        fresh = SourceViews(
            data.images[[0, 2]], data.c2w[[0, 2]], refine=PREPARE_REFINE, device=device
        )
        fresh.cache_for("panogrf", models)
        _sync(device)
    (out_dir / "profile_prepare.txt").write_text(
        prof.key_averages().table(sort_by=sort, row_limit=40)
    )
    with torch_profile(activities=activities) as prof:
        render_view("panogrf", views, data.c2w[1], 512, models, "fast")
        _sync(device)
    (out_dir / "profile_render.txt").write_text(
        prof.key_averages().table(sort_by=sort, row_limit=40)
    )


def parity(folders, models, cpu_models, device) -> list[dict]:
    """Per scene: the depth's L1 between the devices before and after the refinement, and the
    WS-PSNR of each device's render of the middle view against the truth."""
    rows = []
    for folder in folders:
        r = new_scene(folder, models, device)
        c = new_scene(folder, cpu_models, torch.device("cpu"))
        rows.append({"scene": folder.name} | _compare(r, c))
        print(rows[-1], flush=True)
    return rows


def _compare(r, c) -> dict:
    from panogrf.app.scoring import image_scores

    truth = r["data"].images[1:2]
    dev, cpu = r["views"], c["views"]
    return {
        "depth_l1_plain": float((dev.plain.cpu() - cpu.plain).abs().mean()),
        "depth_l1_refined": float((dev.depth["full"].cpu() - cpu.depth["full"]).abs().mean()),
        "ws_psnr_device": image_scores(r["rgb"], truth)["ws_psnr"],
        "ws_psnr_cpu": image_scores(c["rgb"], truth)["ws_psnr"],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, required=True, help="a dataset folder")
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--scenes", type=int, default=6)
    parser.add_argument("--cpu-scenes", type=int, default=1)
    parser.add_argument("--profile", type=Path, default=None)
    parser.add_argument("--tf32", choices=("on", "off"), default="on", help="TF32 convolutions")
    parser.add_argument(
        "--parity", action="store_true", help="only the CPU against the device, scene by scene"
    )
    parser.add_argument(
        "--render-rows",
        type=lambda s: tuple(int(x) for x in s.split(",")),
        default=(512, 1024),
        help="rows of the timed renders (default 512,1024)",
    )
    parser.add_argument(
        "--chunks",
        type=lambda s: tuple(int(x) for x in s.split(",")),
        default=(),
        help="GPU chunks to time the renders with (default: none)",
    )
    parser.add_argument("--graphs", action="store_true", help="refinement with/without graphs")
    parser.add_argument(
        "--render-graphs",
        choices=("on", "off"),
        default="on",
        help="renders asked for again replayed from a CUDA graph (panogrf.renderer.graphs)",
    )
    parser.add_argument("--live", action="store_true", help="the viewer's live worker's rate")
    parser.add_argument("--sweep", action="store_true", help="the sweep batched and not")
    parser.add_argument("--out", type=Path, default=Path("lab/results/gpu.json"))
    args = parser.parse_args()

    from panogrf.app.runtime import resolve_device
    from panogrf.app.scene.session import default_models
    from panogrf.app.scoring import image_scores

    device = resolve_device(args.device)
    from panogrf.renderer import graphs as render_graphs

    render_graphs.ENABLED = args.render_graphs == "on"
    torch.backends.cudnn.allow_tf32 = args.tf32 == "on"
    torch.backends.cuda.matmul.allow_tf32 = args.tf32 == "on"
    if args.parity:
        index = json.loads((args.data / "dataset.json").read_text())
        folders = [args.data / e["folder"] for e in index["scenes"]][: args.scenes]
        rows = parity(folders, default_models(device), default_models("cpu"), device)
        args.out.write_text(json.dumps({"parity": rows, "device": str(device)}, indent=2))
        return 0
    index = json.loads((args.data / "dataset.json").read_text())
    folders = [args.data / e["folder"] for e in index["scenes"]][: args.scenes]
    models = default_models(device)
    cpu_models = default_models("cpu")
    start = time.perf_counter()
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    runs = []
    for i, folder in enumerate(folders):
        r = new_scene(folder, models, device)
        row = {"scene": folder.name, "device": r["times"]}
        truth = r["data"].images[1:2]
        row["ws_psnr_device"] = image_scores(r["rgb"], truth)["ws_psnr"]
        if i < args.cpu_scenes and device.type != "cpu":
            c = new_scene(folder, cpu_models, torch.device("cpu"))
            row["cpu"] = c["times"]
            row["ws_psnr_cpu"] = image_scores(c["rgb"], truth)["ws_psnr"]
            d_dev = r["views"].depth["full"].cpu()
            row["depth_l1_between"] = float((d_dev - c["views"].depth["full"]).abs().mean())
        if i == 0:
            row["renders"] = render_times(
                r["views"], r["data"].c2w[1], models, device, rows_list=args.render_rows
            )
            if device.type != "cpu":
                row["renders_cpu"] = (
                    render_times(
                        c["views"],
                        r["data"].c2w[1],
                        cpu_models,
                        torch.device("cpu"),
                        repeats=1,
                        warm=1,
                        skip=("paper_1024",),
                        rows_list=args.render_rows,
                    )
                    if "cpu" in row
                    else {}
                )
            if args.chunks:
                row["chunks"] = chunk_sweep(
                    r["views"], r["data"].c2w[1], models, device, args.chunks, args.render_rows
                )
            if args.profile is not None:
                profile(r["views"], r["data"], models, device, args.profile)
            if args.live:
                row["live"] = live_rate(r["views"], r["data"].c2w[1], models)
            if args.sweep:
                row["sweep_batch"] = sweep_compare(r["data"], models, device)
            if args.graphs:
                try:
                    row["refine_graphs"] = refine_graphs(r["views"], models, device)
                except Exception as exc:  # the rest of the run still reports
                    row["refine_graphs"] = {"error": f"{type(exc).__name__}: {exc}"}
                    print(f"refinement comparison failed: {row['refine_graphs']}", flush=True)
        runs.append(row)
        print(
            f"{folder.name}: new scene {r['times']['total']:.3f} s on {device} "
            + " ".join(f"{k} {v:.3f}" for k, v in r["times"].items() if k != "total")
            + (f"; CPU {row['cpu']['total']:.2f} s" if "cpu" in row else ""),
            flush=True,
        )
    peak = torch.cuda.max_memory_allocated(device) / 2**20 if device.type == "cuda" else None
    warm = runs[1:] or runs
    stages = list(runs[0]["device"])
    summary = {
        "new_scene_cold_s": runs[0]["device"]["total"],
        "new_scene_warm_median_s": statistics.median(r["device"]["total"] for r in warm),
        "stages_warm_median_s": {
            k: statistics.median(r["device"][k] for r in warm) for k in stages
        },
        "renders_s": runs[0]["renders"],
        "renders_cpu_s": runs[0].get("renders_cpu", {}),
        "peak_memory_mib": peak,
    }
    cpu_rows = [r for r in runs if "cpu" in r]
    if cpu_rows:
        summary["new_scene_cpu_s"] = statistics.median(r["cpu"]["total"] for r in cpu_rows)
        summary["stages_cpu_s"] = {
            k: statistics.median(r["cpu"][k] for r in cpu_rows) for k in stages
        }
        summary["depth_l1_between_m"] = max(r["depth_l1_between"] for r in cpu_rows)
        summary["ws_psnr_gap_db"] = max(
            abs(r["ws_psnr_device"] - r["ws_psnr_cpu"]) for r in cpu_rows
        )
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else platform.processor()
    report = {
        "what": "a new 512x1024 scene end to end on a GPU against the CPU; renders; memory",
        "device": f"{device}: {name}",
        "cpu": f"{platform.machine()}, {torch.get_num_threads()} torch threads",
        "torch": torch.__version__,
        "data": str(args.data),
        "summary": summary,
        "runs": runs,
        "seconds": round(time.perf_counter() - start, 1),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))
    print(f"\n{report['device']}; CPU {report['cpu']}; torch {torch.__version__}; wrote {args.out}")
    print(f"{'what':>34} | {'device':>10} | {'CPU':>10}")
    cpu_stages = summary.get("stages_cpu_s", {})
    print(f"{'new scene, cold (first)':>34} | {summary['new_scene_cold_s']:10.3f} | {'':>10}")
    cpu_total = summary.get("new_scene_cpu_s")
    cpu_cell = f"{cpu_total:10.3f}" if cpu_total else f"{'-':>10}"
    warm_s = summary["new_scene_warm_median_s"]
    print(f"{'new scene, warm (median)':>34} | {warm_s:10.3f} | {cpu_cell}")
    for k, v in summary["stages_warm_median_s"].items():
        c = f"{cpu_stages[k]:10.3f}" if k in cpu_stages else f"{'-':>10}"
        print(f"{'  ' + k:>34} | {v:10.3f} | {c}")
    for k, v in summary["renders_s"].items():
        c = summary["renders_cpu_s"].get(k)
        c = f"{1000 * c:10.1f}" if c else f"{'-':>10}"
        print(f"{'render ' + k + ' (ms)':>34} | {1000 * v:10.1f} | {c}")
    if peak is not None:
        print(f"{'peak GPU memory (MiB)':>34} | {peak:10.0f} |")
    if cpu_rows:
        print(f"{'depth L1 between devices (m)':>34} | {summary['depth_l1_between_m']:10.5f} |")
        print(f"{'WS-PSNR gap between devices (dB)':>34} | {summary['ws_psnr_gap_db']:10.4f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
