"""The index of a `panogrf dataset make` folder (``dataset.json``): the scenes a run wrote
listed beside those listed before, and what a stopped run leaves (`keep_written`)."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from panogrf.app.errors import UserError
from panogrf.app.files.atomic import write_text_atomic
from panogrf.app.scene.datasets import read_index_data

if TYPE_CHECKING:
    from panogrf.app.synth.make import MakeConfig


def keep_written(cfg: MakeConfig, entries: list[dict], index_path: Path, new: list[str]) -> None:
    """After a stop: the scenes whose transforms.json is in place listed in the index, the
    folders this run made (``new``) that hold no whole scene removed, and what to run to go
    on said."""
    out = Path(cfg.out)
    done = [e for e in entries if (out / e["folder"] / "transforms.json").is_file()]
    for name in new:
        folder = out / name
        if folder.is_dir() and not (folder / "transforms.json").is_file():
            shutil.rmtree(folder, ignore_errors=True)
    if done:
        write_index(cfg, done, index_path)
    left = cfg.count - len(done)
    print(
        f"{out}: {len(done)} of {cfg.count} scenes written and listed in dataset.json; to "
        f"make the other {left}: --start {cfg.start + len(done)} --count {left}",
        file=sys.stderr,
    )


def write_index(cfg: MakeConfig, entries: list[dict], index_path: Path) -> None:
    """``entries`` listed in ``index_path`` beside any scenes listed there before."""
    from panogrf.app.synth.make import FINISHES as finishes

    index = read_index_data(index_path) if index_path.exists() else {"scenes": []}
    known = {e["folder"] for e in entries}
    index["scenes"] = [e for e in index.get("scenes", []) if e["folder"] not in known] + entries
    index["scenes"].sort(key=lambda e: e["folder"])
    index.update(
        {
            "generator": "panogrf dataset make",
            "world": cfg.world,
            "renderer": cfg.renderer,
            **{name: getattr(cfg, name) for name in finishes if getattr(cfg, name) > 0},
            "height": cfg.height,
            "width": 2 * cfg.height,
        }
    )
    write_text_atomic(index_path, json.dumps(index, indent=2))


def check_joins(index: dict, index_path: Path, cfg: MakeConfig) -> None:
    """Refuse scenes that would join a dataset of another size, world, renderer or split: its
    index describes all of its scenes with one of each (train and test stay disjoint), or
    another scene under a name it lists (a scene of another seed would be replaced)."""
    from panogrf.app.synth.make import scene_seed

    for key, value in (("height", cfg.height), ("world", cfg.world), ("renderer", cfg.renderer)):
        if key in index and index[key] != value:
            raise UserError(
                f"{index_path}: its scenes have {key} {index[key]}, not {value}; "
                "write these to another --out (`panogrf dataset merge` joins datasets)"
            )
    listed = {e["folder"]: e.get("seed") for e in index["scenes"]}
    for i in range(cfg.start, cfg.start + cfg.count):  # another scene under a listed name
        name, seed = f"{cfg.split}_{i:05d}", scene_seed(cfg.split, cfg.seed, i)
        if listed.get(name, seed) != seed:
            raise UserError(
                f"{index_path}: lists another {name} (seed {listed[name]}); add scenes after "
                f"the last with --start {len(listed)}, or write these to another --out"
            )
    other = [e["folder"] for e in index["scenes"] if not e["folder"].startswith(cfg.split + "_")]
    if other:
        raise UserError(
            f"{index_path}: holds {other[0]}, not of the {cfg.split} split; train and test "
            "scenes go to different folders"
        )
