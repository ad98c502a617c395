"""`panogrf dataset merge`: one dataset folder listing the scenes of several, linked."""

from __future__ import annotations

import json
from pathlib import Path

from panogrf.app.errors import UserError
from panogrf.app.files.atomic import refuse_foreign_folder, write_text_atomic
from panogrf.app.scene.datasets import read_index_data


def merge_datasets(out: Path, sources: list[Path]) -> dict:
    """One dataset folder listing the scenes of several (`dataset make` folders): every scene
    folder is linked (a symbolic link to the source's, nothing copied) and ``out/dataset.json``
    lists them all. Scene folder names must be unique across the sources (make them with
    different ``--start``). Run again with the same sources, it changes nothing."""
    out = Path(out)
    entries, links = [], {}
    seen: set[Path] = set()
    heights: dict[object, Path] = {}
    for source in sources:
        source = Path(source).resolve()
        if source in seen:
            raise UserError(f"{source}: listed twice; give each dataset once")
        seen.add(source)
        index_path = source / "dataset.json"
        if not index_path.exists():
            raise UserError(f"{source}: no dataset.json (make one with `panogrf dataset make`)")
        index = read_index_data(index_path)
        heights.setdefault(index.get("height"), source)
        if len(heights) > 1:  # a training reads every scene at one height
            (a, first), (b, _) = heights.items()
            raise UserError(
                f"{source}: panoramas of {b} rows, {first} of {a}: merge datasets of one "
                "height (make them with the same --height)"
            )
        for entry in index["scenes"]:
            name = entry["folder"]
            if name in links:
                raise UserError(
                    f"scene {name} is in both {links[name].parent} and {source}: "
                    "make the datasets with different --start"
                )
            if not (source / name / "transforms.json").exists():
                raise UserError(f"{source / name}: listed in {index_path} but incomplete")
            links[name] = source / name
            entries.append(dict(entry, source=str(source)))
    if out.exists() and not out.is_dir():
        raise UserError(f"{out} exists and is not a folder")
    refuse_foreign_folder(out, "dataset merge", _earlier_merge)
    out.mkdir(parents=True, exist_ok=True)
    for name, target in links.items():
        link = out / name
        if link.is_symlink() and link.resolve() == target:
            continue
        if link.exists() or link.is_symlink():
            raise UserError(f"{link} exists and is not a link to {target}")
    for name, target in links.items():
        if not (out / name).is_symlink():
            (out / name).symlink_to(target, target_is_directory=True)
    index = {
        "generator": "panogrf dataset merge",
        "merged_from": [str(Path(s).resolve()) for s in sources],
        "scenes": sorted(entries, key=lambda e: e["folder"]),
    }
    write_text_atomic(out / "dataset.json", json.dumps(index, indent=2))
    return {"scenes": len(entries), "sources": len(sources)}


def _earlier_merge(out: Path) -> bool:
    """Whether ``out`` holds only what `merge_datasets` writes: its index and links."""
    try:
        index = json.loads((out / "dataset.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    if not isinstance(index, dict) or index.get("generator") != "panogrf dataset merge":
        return False
    return all(p.name == "dataset.json" or p.is_symlink() for p in out.iterdir())
