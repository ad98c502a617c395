"""The viewer's numbers on this machine: preparation, preview rate, refinement latency, memory.

    python benchmarks/viewer.py --scene assets/demo --out lab/results/viewer.json

- scene preparation: cold (empty cache folder: depth estimation + encoders + writing the
  cache) and cached (reading it back), median of ``--repeats``;
- the real viewer, headless on EGL (no window system; llvmpipe), with its render worker, on a
  scripted session: a walk (W held), then still until refined, ``--repeats`` times;
- preview frames per second at 512 x 1024 while moving (the preview's geometry drawn at
  `ViewerSetup.moving_height` rows, its colours read at 512 rows by the display pass, or
  shown upsampled when `ViewerSetup.sharp` is off): the median frame period (start of
  one frame to the start of the next, so including the GL work finished at buffer swap)
  over the frames where the camera moved;
- refinement: time from the last frame that moved to the first refined level on screen (the
  worker's draft: 3 guided + 1 uniform samples per ray from the 2 nearest sources, the network
  at 128 rows, shown at 512 x 1024 with the sources' colour above 32 rows), and to the last
  level (fast sampling, all sources, the network at 128 rows, the same detail), median of
  ``--repeats``; it includes the viewer's debounce (`STILL_DELAY`) and the viewer drawing
  beside the worker. Beside it, in the same process, the seed's method as published (64 + 64
  samples per ray at 512 x 1024, all sources) once, as the baseline;
- the per-scene depth refinement (on by default since round 16), which `panogrf view` runs in
  a background thread while the window already shows the plain scene: its seconds alone in a
  thread on the session's torch threads (`session.refine_prepared` on a deferred preparation)
  and in `SceneRefiner`'s thread (one torch thread) with nothing else running, median of
  ``--repeats``; then ``--repeats`` viewer sessions of ``--walks`` walks that start with it:
  the preview's median frame period while it runs (the sessions end before it does);
  ``--no-background`` skips it;
- as `panogrf view` does, the main thread only draws and every torch computation runs in
  another thread (`panogrf.app.viewer.torch_threads`). Last, the baseline for that: the main
  thread runs one parallel kernel, so that its OpenMP pool lives on as it did before round 18,
  and the scripted session and the refinement alone run again (``--no-baseline`` skips it);
- peak resident memory of the process.
A table is printed last.
"""

from __future__ import annotations

import argparse
import platform
import resource
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", type=Path, default=None, help="default: the bundled demo")
    parser.add_argument("--out", type=Path, default=Path("lab/results/viewer.json"))
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--walk-frames", type=int, default=45, help="frames per walk")
    parser.add_argument("--skip-paper", action="store_true", help="skip the 64 + 64 baseline")
    parser.add_argument(
        "--no-sharp", action="store_true", help="the preview upsampled while moving (not sharp)"
    )
    parser.add_argument(
        "--no-background",
        action="store_true",
        help="skip the sessions during the background depth refinement",
    )
    parser.add_argument(
        "--no-baseline",
        action="store_true",
        help="skip the viewer as it ran before round 18 (the main thread's OpenMP pool alive)",
    )
    parser.add_argument(
        "--walks", type=int, default=8, help="walks forward and back per background session"
    )
    args = parser.parse_args()
    from panogrf.app.runtime import keep_freed_memory
    from panogrf.app.viewer.torch_threads import serial_main_thread

    keep_freed_memory()  # as the `panogrf` command does
    # As `panogrf view` does: the main thread only draws, the torch work runs in other threads.
    with serial_main_thread() as threads:
        measure(args, threads)


def measure(args: argparse.Namespace, threads: int) -> None:
    from panogrf.app.files.images import write_json_atomic
    from panogrf.app.scene.session import prepare_scene
    from panogrf.app.viewer.torch_threads import off_main_thread
    from panogrf.assets import path as asset_path
    from panogrf.renderer.render import render_panorama

    scene_dir = args.scene or asset_path("demo")
    quiet = lambda *a: None  # noqa: E731
    cold, cached = [], []
    for _ in range(args.repeats):
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            off_main_thread(threads, prepare_scene, scene_dir, Path(tmp), log=quiet)
            cold.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            prepared = off_main_thread(threads, prepare_scene, scene_dir, Path(tmp), log=quiet)
            views, models, result = prepared.views, prepared.models, prepared.cache
            cached.append(time.perf_counter() - t0)
            assert result.status == "loaded", result.status
    cold_s, cached_s = statistics.median(cold), statistics.median(cached)
    print(f"preparation: cold {cold_s:.2f} s, cached {cached_s:.2f} s")

    net = models.renderer("panogrf")
    cache = off_main_thread(threads, views.cache_for, "panogrf", models)
    frame_ms, first, full, setup, config = walk_and_refine(views, net, cache, threads, args)
    paper_s = None
    if not args.skip_paper:
        t0 = time.perf_counter()
        off_main_thread(threads, render_panorama, net, cache, views.c2w[0], 512, "paper")
        paper_s = time.perf_counter() - t0
        print(f"paper (64 + 64) 512x1024: {paper_s:.1f} s")
    background = None
    if not args.no_background:
        background = background_sessions(scene_dir, threads, args, quiet)
    baseline = None
    if not args.no_baseline:
        baseline = main_pool_baseline(scene_dir, views, net, cache, threads, args, quiet)
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    report = {
        "what": "viewer preparation, preview rate and refinement latency",
        "scene": str(scene_dir),
        "views": int(views.images.shape[0]),
        "prepare_cold_s": {"median": statistics.median(cold), "runs": cold},
        "prepare_cached_s": {"median": statistics.median(cached), "runs": cached},
        "preview_512x1024_frame_ms": {
            "median": frame_ms,
            "fps": 1000 / frame_ms,
            "frames": len(config.moving_frame_times),
            "p10_ms": 1000 * float(np.percentile(config.moving_frame_times, 10)),
            "p90_ms": 1000 * float(np.percentile(config.moving_frame_times, 90)),
        },
        "preview_moving_rows": setup.moving_height or setup.preview_height,
        "preview_sharp": setup.sharp,
        "preview_mesh": {"rows": setup.mesh_height, "triangles": setup.mesh_triangles},
        "refine_first_level_s": {"median": statistics.median(first), "runs": first},
        "refine_full_512x1024_s": {"median": statistics.median(full), "runs": full},
        "paper_64_64_512x1024_s": paper_s,
        "background_refinement": background,
        "main_thread_pool_baseline": baseline,
        "peak_rss_mb": peak_mb,
        "machine": f"{platform.machine()}, {threads} torch threads, CPU, Mesa llvmpipe (EGL)",
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out, report)
    rows = [
        ("scene preparation, cold", f"{statistics.median(cold):.2f} s", "-"),
        ("scene preparation, cached", f"{statistics.median(cached):.2f} s", "<= 0.5 s"),
        ("preview 512x1024 while moving", f"{1000 / frame_ms:.1f} fps", ">= 60 fps"),
        ("stop -> first refined level", f"{statistics.median(first):.2f} s", "<= 0.5 s"),
        ("stop -> refined 512x1024 (last level)", f"{statistics.median(full):.2f} s", "<= 2 s"),
        ("paper 64+64 at 512x1024", "-" if paper_s is None else f"{paper_s:.1f} s", "baseline"),
        ("peak memory (RSS)", f"{peak_mb:.0f} MB", "-"),
    ]
    if paper_s is not None:
        rows.append(("paper / fast refinement", f"{paper_s / statistics.median(full):.1f}x", ""))
    if background is not None:
        b = background
        rows += [
            (f"depth refinement, {threads} threads", f"{b['alone_s']['median']:.2f} s", "-"),
            ("depth refinement, background", f"{b['background_thread_s']['median']:.2f} s", "-"),
            ("preview while it runs", f"{1000 / b['refining_frame_ms']['median']:.1f} fps", "-"),
        ]
    if baseline is not None:
        old_full = baseline["refine_full_512x1024_s"]["median"]
        old_alone = baseline["depth_refinement_alone_s"]["median"]
        rows += [
            ("before round 18: stop -> refined", f"{old_full:.2f} s", "-"),
            ("  ratio (now / before)", f"{statistics.median(full) / old_full:.2f}x", "-"),
            (f"before: depth refinement, {threads} thr", f"{old_alone:.2f} s", "-"),
        ]
        if background is not None:
            ratio = background["alone_s"]["median"] / old_alone
            rows.append(("  ratio (now / before)", f"{ratio:.2f}x", "-"))
    print(f"\n{'measure':<40} {'median':>10} {'target':>10}")
    for name, value, target in rows:
        print(f"{name:<40} {value:>10} {target:>10}")
    print(f"wrote {args.out}")


def walk_and_refine(views, net, cache, threads: int, args):
    """The scripted session (walk, then still until refined, ``args.repeats`` times): the
    preview's median frame period while moving (ms), the seconds to the first and the last
    refined level of each cycle, the setup and the session's config."""
    from panogrf.app.viewer.setup import UPSAMPLED_MOVING_ROWS, ViewerSetup
    from panogrf.app.viewer.window import parse_script, run_viewer
    from panogrf.app.viewer.worker import LEVELS, RenderWorker

    worker = RenderWorker(net, cache, levels=LEVELS, threads=threads).start()
    # Walk forward, wait for the refinement, walk back, wait, ...: the camera stays near the
    # sources (1.5 m at most with the default 45 frames at 1 m/s).
    cycles = [f"{'ws'[k % 2]}*{args.walk_frames},refined" for k in range(args.repeats)]
    setup = ViewerSetup.from_views(
        views,
        worker=worker,
        script=parse_script(",".join(["wait*5", *cycles, "esc"])),
        fixed_step=1 / 30,
        preview_height=512,
        sharp=not args.no_sharp,
        **({"moving_height": UPSAMPLED_MOVING_ROWS} if args.no_sharp else {}),
        log=lambda *a: None,
    )
    try:
        config = run_viewer(setup, "headless", (1024, 512))
    finally:
        worker.stop()
    frame_ms = 1000 * statistics.median(config.moving_frame_times)
    # Each cycle's last level and the first level just before it (the start pose, still for a
    # few frames while the shaders compile, may get a first level of its own: not a cycle's).
    log, last = config.refine_log, len(LEVELS) - 1
    full = [s for level, s in log if level == last]
    first = [log[i - 1][1] for i, (level, _) in enumerate(log) if level == last and i > 0]
    if len(full) != args.repeats or any(
        log[i - 1][0] != 0 for i, e in enumerate(log) if e[0] == last
    ):
        raise SystemExit(f"expected {args.repeats} refinements, got {config.refine_log}")
    print(
        f"preview while moving (512x1024, geometry at {setup.moving_height or 512} rows, "
        f"{'sharp' if setup.sharp else 'upsampled'}): "
        f"{frame_ms:.1f} ms per frame, {1000 / frame_ms:.1f} fps"
    )
    print(
        f"first refined level after {statistics.median(first):.2f} s, last level (512x1024) "
        f"after {statistics.median(full):.2f} s"
    )
    return frame_ms, first, full, setup, config


def background_sessions(scene_dir: Path, threads: int, args, quiet) -> dict:
    """The depth refinement alone in a thread on the session's ``threads`` torch threads, then
    in `SceneRefiner`'s background thread (one torch thread) with nothing else running, then
    beside ``args.repeats`` viewer sessions that walk while it runs (as `panogrf view` does):
    seconds, and the preview's frame period while it runs."""
    from panogrf.app.viewer.scene_refiner import SceneRefiner
    from panogrf.app.viewer.torch_threads import off_main_thread
    from panogrf.app.viewer.window import ViewerSetup, parse_script, run_viewer
    from panogrf.app.viewer.worker import LEVELS, RenderWorker
    from panogrf.model.refine import PREPARE_REFINE

    def deferred(tmp: str):
        return deferred_scene(scene_dir, Path(tmp), threads, quiet)

    alone, thread, refining = [], [], []
    for _ in range(args.repeats):
        alone.append(refine_alone(scene_dir, threads, quiet))
        with tempfile.TemporaryDirectory() as tmp:
            refiner = SceneRefiner(deferred(tmp), log=quiet).start()
            refiner.join()
            thread.append(refiner.seconds)
    walks = ",".join(f"{'ws'[k % 2]}*{args.walk_frames}" for k in range(args.walks))
    for _ in range(args.repeats):
        with tempfile.TemporaryDirectory() as tmp:
            prepared = deferred(tmp)
            views, models = prepared.views, prepared.models
            cache = off_main_thread(threads, views.cache_for, "panogrf", models)
            worker = RenderWorker(
                models.renderer("panogrf"), cache, levels=LEVELS, threads=threads
            ).start()
            refiner = SceneRefiner(prepared, log=quiet).start()
            setup = ViewerSetup.from_views(
                views,
                worker=worker,
                script=parse_script(f"{walks},esc"),
                fixed_step=1 / 30,
                preview_height=512,
                scene_refiner=refiner,
                log=quiet,
            )
            try:
                config = run_viewer(setup, "headless", (1024, 512))
            finally:
                worker.stop()
                refiner.stop()
            if not config.refining_frame_times:
                raise SystemExit("the refinement ended before the walk began: lower --walks")
            refining.append(1000 * statistics.median(config.refining_frame_times))
    print(
        f"depth refinement: alone on {threads} threads {statistics.median(alone):.2f} s, "
        f"background thread {statistics.median(thread):.2f} s; preview "
        f"{statistics.median(refining):.1f} ms per frame while it runs"
    )
    return {
        "setting": repr(PREPARE_REFINE),
        "alone_s": _med(alone),
        "background_thread_s": _med(thread),
        "refining_frame_ms": _med(refining),
    }


def deferred_scene(scene_dir: Path, tmp: Path, threads: int, quiet):
    """The scene prepared in a thread of its own, its depth refinement left to do."""
    from panogrf.app.scene.session import prepare_scene
    from panogrf.app.viewer.torch_threads import off_main_thread
    from panogrf.model.refine import PREPARE_REFINE

    prepared = off_main_thread(
        threads, prepare_scene, scene_dir, tmp, refine=PREPARE_REFINE, defer_refine=True, log=quiet
    )
    assert prepared.pending_refine is not None
    return prepared


def main_pool_baseline(scene_dir: Path, views, net, cache, threads: int, args, quiet) -> dict:
    """The viewer as it ran before round 18, last in the process (the pool stays): the main
    thread runs one parallel kernel on the session's threads, so that its OpenMP pool lives on
    beside the worker threads (`panogrf.app.viewer.torch_threads`). Then the scripted session
    again, and the depth refinement alone in a thread."""
    torch.set_num_threads(threads)
    torch.ones(1 << 22).mul_(2)  # far above torch's grain: runs on the main thread's pool
    print("with the main thread's OpenMP pool (as before round 18):")
    frame_ms, first, full, *_ = walk_and_refine(views, net, cache, threads, args)
    alone = [refine_alone(scene_dir, threads, quiet) for _ in range(args.repeats)]
    print(f"depth refinement alone on {threads} threads: {statistics.median(alone):.2f} s")
    return {
        "preview_512x1024_frame_ms": frame_ms,
        "refine_first_level_s": _med(first),
        "refine_full_512x1024_s": _med(full),
        "depth_refinement_alone_s": _med(alone),
    }


def refine_alone(scene_dir: Path, threads: int, quiet) -> float:
    """Seconds of one depth refinement in a thread of its own on ``threads`` torch threads."""
    from panogrf.app.scene.session import refine_prepared
    from panogrf.app.viewer.torch_threads import off_main_thread

    with tempfile.TemporaryDirectory() as tmp:
        prepared = deferred_scene(scene_dir, Path(tmp), threads, quiet)
        t0 = time.perf_counter()
        off_main_thread(threads, refine_prepared, prepared, log=quiet)
        return time.perf_counter() - t0


def _med(runs: list[float]) -> dict:
    return {"median": statistics.median(runs), "runs": runs}


if __name__ == "__main__":
    main()
