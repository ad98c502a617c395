"""`panogrf dataset make`: write synthetic scenes as scene folders (RGB + spherical depth + poses).

Layout of the output::

    OUT/
      dataset.json                 # index: split, seeds, baselines, sizes, one entry per scene
      <split>_00000/
        transforms.json            # camera_model EQUIRECTANGULAR, frames with c2w and depth
        images/frame_000.png ...   # first, middle, last camera on a line
        depth/frame_000.png ...    # 16-bit PNG, spherical depth in millimetres, 0 = unknown

Seeds: scene ``i`` of a split gets seed ``2 * (base_seed * 1_000_000 + i) + s`` with s = 0 for
train and 1 for test, so the splits never share a seed; their textures are disjoint too
(`app.synth.textures`).
"""

from __future__ import annotations

import json
import os
import re
import time
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from panogrf.app.files.atomic import refuse_foreign_folder, write_text_atomic
from panogrf.app.files.images import write_depth, write_rgb
from panogrf.app.scene.datasets import read_index_data
from panogrf.app.synth.gl_render import PanoramaRenderer
from panogrf.app.synth.layout import LayoutConfig, SynthScene, generate_layout
from panogrf.app.synth.make_index import check_joins, keep_written, write_index
from panogrf.app.synth.textures import texture_bank

SPLITS = ("train", "test")
WORLDS = ("classic", "home")
#: `MakeConfig`'s home-world finishes, each a probability per scene.
FINISHES = ("trims", "coves", "sheers")
RENDERERS = ("gl", "pyrender")
NAMES = ["frame_000", "frame_001", "frame_002"]
#: Scenes of one base seed (`scene_seed`): scene i of seed s + 1 is scene i + this of seed s.
SCENES_PER_SEED = 1_000_000


@dataclass(frozen=True)
class MakeConfig:
    """What `make_dataset` writes."""

    out: Path
    """Output folder (created; files of scene folders with the same name are overwritten)."""
    split: str = "train"
    """"train" or "test": disjoint seeds and disjoint texture sets."""
    count: int = 12
    """Number of scenes (three panoramas each)."""
    height: int = 256
    """Panorama height in pixels; width is twice this."""
    baselines: tuple[float, ...] = ()
    """First-to-last camera distances to cycle through (metres); empty: random in [0.2, 2.0]."""
    seed: int = 0
    """Base seed; the same seed and split always give the same scenes."""
    start: int = 0
    """Index of the first scene (to extend a dataset)."""
    procedural_textures: int = 32
    """Procedural textures in the split's pool (besides its photographs)."""
    world: str = "classic"
    """"classic" (photographs and patterns on the walls) or "home" (`panogrf.app.synth.home`:
    household materials, bright windows, rugs, sun patches, baselines up to 3.5 m)."""
    renderer: str = "gl"
    """"gl" (`panogrf.app.synth.gl_render`: unshadowed Lambertian lights, fast) or "pyrender"
    (`panogrf.app.synth.pbr_render`: shadow-casting lights, sun through the windows, gloss,
    auto exposure; about 30x slower, run in ``workers`` processes of its own)."""
    workers: int = 2
    """Worker processes of the "pyrender" renderer."""
    trims: float = 0.0
    """Home world: the probability per scene that the main room's walls are finished in parts
    (a picture rail with a frieze above it, maybe a dado rail with wainscot below;
    `panogrf.app.synth.home`). 0 leaves every scene as before."""
    coves: float = 0.0
    """Home world: the probability per scene that the main room's walls meet its ceiling in a
    cove or a crown moulding instead of a sharp corner. 0 leaves every scene as before."""
    sheers: float = 0.0
    """Home world: the probability per scene that the main room's windows get sheer or lace
    curtains (pleated, near white, glowing in front of the glass). 0 leaves every scene as
    before."""


def scene_seed(split: str, base_seed: int, index: int) -> int:
    """The seed of scene ``index`` of ``split``; even for train, odd for test."""
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    return 2 * (base_seed * SCENES_PER_SEED + index) + SPLITS.index(split)


def build_textures(
    split: str, base_seed: int, procedural: int = 32, world: str = "classic"
) -> tuple[np.ndarray, dict[str, range] | None]:
    """The texture pool [L, S, S, 3] of a split and, for the home world, its material groups.

    Classic: the split's photographs plus procedural textures. Made once per dataset run (and
    uploaded once); each scene picks its materials from it.
    """
    if world == "home":
        from panogrf.app.synth.materials import home_texture_bank

        rng = np.random.default_rng([base_seed, SPLITS.index(split), 0x40E])
        return home_texture_bank(split, rng, max(4, procedural // 4))
    rng = np.random.default_rng([base_seed, SPLITS.index(split), 0x7E7])
    return texture_bank(split, rng, procedural), None


def build_scene(
    split: str,
    seed: int,
    baseline: float | None,
    n_layers: int,
    config: LayoutConfig | None = None,
    groups: dict[str, range] | None = None,
    **finishes: float,
) -> SynthScene:
    """The layout of one synthetic scene whose materials index a pool of ``n_layers`` textures
    (home world: ``groups``, the pool's material groups; ``finishes``, the probabilities named
    in `FINISHES`, as in `MakeConfig`)."""
    if groups is not None:
        from panogrf.app.synth.home import generate_home

        return generate_home(seed, split, groups, baseline, **finishes)
    return generate_layout(seed, split, n_layers, baseline, config or LayoutConfig())


def _write_json_atomic(path: Path, obj: dict) -> None:
    write_text_atomic(path, json.dumps(obj, indent=2))


def transforms_dict(scene: SynthScene, height: int, names: list[str]) -> dict:
    """The scene's nerfstudio-style transforms.json content."""
    return {
        "camera_model": "EQUIRECTANGULAR",
        "w": 2 * height,
        "h": height,
        "frames": [
            {
                "file_path": f"images/{name}.png",
                "depth_file_path": f"depth/{name}.png",
                "transform_matrix": np.asarray(c2w).tolist(),
            }
            for name, c2w in zip(names, scene.cameras, strict=True)
        ],
        "panogrf": {
            "generator": "panogrf.app.synth",
            "split": scene.split,
            "seed": scene.seed,
            "baseline_m": scene.baseline,
            "layout": scene.meta,
        },
    }


def _scene_job(cfg: MakeConfig, groups, n_layers: int, i: int):
    """Scene ``i``'s layout and its (created) folder."""
    seed = scene_seed(cfg.split, cfg.seed, i)
    baseline = cfg.baselines[i % len(cfg.baselines)] if cfg.baselines else None
    finishes = {name: getattr(cfg, name) for name in FINISHES}
    scene = build_scene(cfg.split, seed, baseline, n_layers, groups=groups, **finishes)
    folder = Path(cfg.out) / f"{cfg.split}_{i:05d}"
    (folder / "images").mkdir(parents=True, exist_ok=True)
    (folder / "depth").mkdir(parents=True, exist_ok=True)
    return scene, folder


def _entry(scene: SynthScene, folder: Path, triangles: int) -> dict:
    return {
        "folder": folder.name,
        "seed": scene.seed,
        "baseline_m": scene.baseline,
        "triangles": triangles,
    }


# -- pyrender workers (their own processes: a pyrender EGL context and a moderngl one do not mix)
_WORKER: dict = {}


def _exit_with_parent(parent: int) -> None:
    """End this worker once its parent is gone (killed, not interrupted: an interrupt reaches
    the whole process group), instead of rendering the rest of its queue into the folder."""
    import threading

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def _pbr_worker_init(cfg: MakeConfig, parent: int) -> None:
    import torch

    from panogrf.app.synth.pbr_render import PyrenderPanoramaRenderer

    _exit_with_parent(parent)
    torch.set_num_threads(1)
    textures, groups = build_textures(cfg.split, cfg.seed, cfg.procedural_textures, cfg.world)
    renderer = PyrenderPanoramaRenderer()
    renderer.set_textures(textures)
    _WORKER.update(cfg=cfg, groups=groups, layers=len(textures), renderer=renderer)


def _pbr_worker_scene(i: int) -> tuple[dict, dict, float]:
    """Render and write scene ``i`` (all but its transforms.json): (entry, transforms, s)."""
    cfg, renderer = _WORKER["cfg"], _WORKER["renderer"]
    scene, folder = _scene_job(cfg, _WORKER["groups"], _WORKER["layers"], i)
    t0 = time.perf_counter()
    renderer.set_scene(scene)
    for name, c2w in zip(NAMES, scene.cameras, strict=True):
        rgb, depth = renderer.render(c2w, cfg.height, 2 * cfg.height)
        write_rgb(folder / "images" / f"{name}.png", rgb)
        write_depth(folder / "depth" / f"{name}.png", depth)
    seconds = time.perf_counter() - t0
    entry = _entry(scene, folder, renderer.triangles)
    return entry, transforms_dict(scene, cfg.height, NAMES), seconds


def _make_pyrender(cfg: MakeConfig, progress: bool, entries: list[dict]) -> float:
    """Scenes rendered by pyrender in ``cfg.workers`` spawned processes, each entry appended to
    ``entries`` once written; the render seconds."""
    import multiprocessing

    render_s = 0.0
    context = multiprocessing.get_context("spawn")
    with (
        ProcessPoolExecutor(
            max_workers=max(1, cfg.workers),
            mp_context=context,
            initializer=_pbr_worker_init,
            initargs=(cfg, os.getpid()),
        ) as pool,
        tqdm(total=cfg.count * 3, unit="pano", disable=not progress, desc=cfg.split) as bar,
    ):
        futures = [
            pool.submit(_pbr_worker_scene, i) for i in range(cfg.start, cfg.start + cfg.count)
        ]
        try:
            for fut in futures:
                entry, meta, seconds = fut.result()
                # transforms.json last: a folder is a scene only once all its files are in place.
                _write_json_atomic(Path(cfg.out) / entry["folder"] / "transforms.json", meta)
                entries.append(entry)
                render_s += seconds
                bar.update(3)
        except BaseException:
            # A failed scene (or an interrupt) stops the run: the queued scenes are dropped
            # instead of rendered before the error surfaces.
            for fut in futures:
                fut.cancel()
            raise
    return render_s / max(1, cfg.workers)  # the workers' render time, in parallel


def _make_gl(cfg: MakeConfig, progress: bool, entries: list[dict]) -> float:
    """Scenes rendered by the moderngl renderer in this process, each entry appended to
    ``entries`` (its transforms.json may follow with the next scene); the render seconds."""
    render_s = 0.0
    with (
        PanoramaRenderer() as renderer,
        ThreadPoolExecutor(max_workers=2) as pool,
        tqdm(total=cfg.count * 3, unit="pano", disable=not progress, desc=f"{cfg.split}") as bar,
    ):
        textures, groups = build_textures(cfg.split, cfg.seed, cfg.procedural_textures, cfg.world)
        renderer.set_textures(textures)
        previous = None  # (folder, transforms, write futures) of the scene still being written

        def finish(job) -> None:
            folder, meta, futures = job
            for fut in futures:
                fut.result()  # surface write errors here, scene by scene
            # transforms.json last: a folder is a scene only once all its files are in place.
            _write_json_atomic(folder / "transforms.json", meta)

        for i in range(cfg.start, cfg.start + cfg.count):
            scene, folder = _scene_job(cfg, groups, len(textures), i)
            t0 = time.perf_counter()
            renderer.set_scene(scene)
            futures = []
            for name, c2w in zip(NAMES, scene.cameras, strict=True):
                rgb, depth = renderer.render(c2w, cfg.height, 2 * cfg.height)
                # PNG encoding runs beside the next renders (OpenCV releases the GIL).
                futures.append(pool.submit(write_rgb, folder / "images" / f"{name}.png", rgb))
                futures.append(pool.submit(write_depth, folder / "depth" / f"{name}.png", depth))
                bar.update(1)
            render_s += time.perf_counter() - t0
            if previous is not None:
                finish(previous)
            previous = (folder, transforms_dict(scene, cfg.height, NAMES), futures)
            entries.append(_entry(scene, folder, renderer.triangles))
        if previous is not None:
            finish(previous)
    return render_s


def check_out(cfg: MakeConfig) -> None:
    """What the command line refuses before any work besides what `make_dataset` refuses: an
    ``out`` that is not empty and holds no earlier `dataset make` output (a scene folder, the
    user's photos), after the index there is read (its problems named first)."""
    index_path = Path(cfg.out) / "dataset.json"
    if index_path.exists():
        check_joins(read_index_data(index_path), index_path, cfg)
    refuse_foreign_folder(cfg.out, "dataset make", _earlier_make)


def _earlier_make(out: Path) -> bool:
    """Whether ``out`` holds only what `make_dataset` writes: its index and scene folders, or
    the scene folders of a run stopped before it wrote the index."""
    index = out / "dataset.json"
    if index.exists():
        try:
            data = json.loads(index.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return False
        if not isinstance(data, dict) or data.get("generator") != "panogrf dataset make":
            return False
    scene = re.compile(rf"^({'|'.join(SPLITS)})_\d{{5,}}$")
    return all(
        p.name == "dataset.json" or (scene.match(p.name) and p.is_dir() and not p.is_symlink())
        for p in out.iterdir()
        if not p.name.startswith(".")
    )


def make_dataset(cfg: MakeConfig, progress: bool = True) -> dict:
    """Render ``cfg.count`` scenes into ``cfg.out``; returns a summary with timings."""
    if cfg.split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {cfg.split!r}")
    if cfg.world not in WORLDS:
        raise ValueError(f"world must be one of {WORLDS}, got {cfg.world!r}")
    if cfg.renderer not in RENDERERS:
        raise ValueError(f"renderer must be one of {RENDERERS}, got {cfg.renderer!r}")
    if cfg.count < 1 or cfg.height < 8:
        raise ValueError("count must be >= 1 and height >= 8")
    for name in FINISHES:
        p = getattr(cfg, name)
        if not 0.0 <= p <= 1.0 or (p > 0 and cfg.world != "home"):
            raise ValueError(f"{name} must be in [0, 1] and needs the home world, got {p}")
    out = Path(cfg.out)
    index_path = out / "dataset.json"
    if index_path.exists():  # before the rendering: scenes added must match those there
        check_joins(read_index_data(index_path), index_path, cfg)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    make = _make_pyrender if cfg.renderer == "pyrender" else _make_gl
    entries: list[dict] = []
    names = [f"{cfg.split}_{i:05d}" for i in range(cfg.start, cfg.start + cfg.count)]
    before = {name for name in names if (out / name).exists()}
    try:
        render_s = make(cfg, progress, entries)
    except BaseException:
        # Stopped (Ctrl-C, a signal) or failed: the scenes written are listed, the one being
        # written is removed, so the dataset is usable and the same command can go on.
        keep_written(cfg, entries, index_path, [n for n in names if n not in before])
        raise
    triangles = [e["triangles"] for e in entries]
    elapsed = time.perf_counter() - start
    write_index(cfg, entries, index_path)
    n = 3 * cfg.count
    return {
        "scenes": cfg.count,
        "panoramas": n,
        "height": cfg.height,
        "width": 2 * cfg.height,
        "renderer": cfg.renderer,
        "seconds": elapsed,
        "panoramas_per_s": n / elapsed,
        "render_panoramas_per_s": n / render_s if render_s > 0 else float("nan"),
        "max_triangles": int(max(triangles)),
    }
