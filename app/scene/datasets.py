"""Scenes by the folder: a dataset (``dataset.json`` from `panogrf dataset make`), one scene
folder, or a folder of scene folders; and the scored triplets of an evaluation by baseline."""

from __future__ import annotations

import json
from pathlib import Path

from panogrf.app.errors import UserError
from panogrf.app.files.atomic import parse_json


def scene_folders(root: Path) -> tuple[list[Path], bool]:
    """The scene folders under ``root``, and whether they come from a dataset.json index.

    ``root`` is a dataset (``dataset.json`` listing its folders, from `panogrf dataset make`),
    a single scene folder (``transforms.json``), or a folder of scene folders.
    """
    from panogrf.app.scene.folder import TRANSFORMS

    index_path = root / "dataset.json"
    if index_path.exists():
        return read_index(index_path), True
    if (root / TRANSFORMS).is_file():
        return [root], False
    if not root.is_dir():
        raise UserError(f"{root}: no such folder")
    folders = sorted(p for p in root.iterdir() if (p / TRANSFORMS).is_file())
    if not folders:
        raise UserError(
            f"{root}: no dataset.json, no {TRANSFORMS}, and no scene folder with a {TRANSFORMS}"
        )
    return folders, False


def read_index(index_path: Path) -> list[Path]:
    """The scene folders a ``dataset.json`` lists: {"scenes": [{"folder": NAME, ...}, ...]}."""
    return [index_path.parent / e["folder"] for e in read_index_data(index_path)["scenes"]]


def read_index_data(index_path: Path) -> dict:
    """A ``dataset.json`` as a dict whose "scenes" is a list of {"folder": NAME, ...}, each
    folder once; a `UserError` naming the file and the problem otherwise."""
    try:
        data = parse_json(index_path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise UserError(f"{index_path}: cannot read ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise UserError(f"{index_path}: not UTF-8 text") from None
    except json.JSONDecodeError as exc:
        raise UserError(f"{index_path}: not JSON ({exc})") from None
    scenes = data.get("scenes") if isinstance(data, dict) else None
    if not isinstance(scenes, list):
        raise UserError(f'{index_path}: not a dataset index (expected {{"scenes": [...]}})')
    names: set[Path] = set()  # "a" and "./a" are one folder
    for i, entry in enumerate(scenes):
        name = entry.get("folder") if isinstance(entry, dict) else None
        if not isinstance(name, str) or not name.strip():
            got = json.dumps(entry)
            raise UserError(
                f'{index_path}: scenes[{i}]: expected {{"folder": NAME, ...}}, got '
                f"{got if len(got) <= 60 else got[:57] + '...'}"
            )
        if Path(name) in names:
            raise UserError(f"{index_path}: scenes[{i}]: folder {name!r} is listed twice")
        names.add(Path(name))
    return data


def triplets_by_baseline(
    root: Path, baselines: list[float] | None, limit: int | None, broken: list | None = None
) -> tuple[list[tuple[float, Path]], list[float]]:
    """(baseline, folder) of every scene to score, and the baselines scored.

    Without ``baselines``: 1.0, 1.5 and 2.0 m for a dataset, every baseline found for a plain
    folder of scenes. A scene that is broken (or has not three views) raises its `UserError`,
    or, with a ``broken`` list, is appended to it as {"scene", "why"} and left out.
    """
    from panogrf.app.scene.folder import load_scene

    folders, indexed = scene_folders(root)
    found = []
    for folder in folders:
        try:
            scene = load_scene(folder)
            if scene.num_views != 3:
                raise UserError(
                    f"{folder}: expected three views (the middle one is scored), found "
                    f"{scene.num_views}"
                )
        except UserError as exc:
            if broken is None:
                raise
            broken.append({"scene": str(folder), "why": str(exc)})
            continue
        c = scene.c2w[:, :3, 3]
        found.append((round(float(((c[2] - c[0]) ** 2).sum() ** 0.5), 1), folder))
    if baselines is None:
        baselines = [1.0, 1.5, 2.0] if indexed else sorted({b for b, _ in found})
    out, counts = [], {b: 0 for b in baselines}
    for b, folder in found:
        if b in counts and (limit is None or counts[b] < limit):
            counts[b] += 1
            out.append((b, folder))
    missing = [b for b, n in counts.items() if n == 0]
    if missing:
        raise UserError(f"{root}: no scene with baseline {missing} m")
    return out, baselines
