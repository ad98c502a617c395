"""Scene folders of real-home pairs and triplets from a Zillow Indoor Dataset (ZInD) tour.

    python benchmarks/zind_scenes.py ZIND_TOUR_DIR OUT_DIR [--max-per-room 8] [--seed 0]

ZIND_TOUR_DIR holds ``zind_data.json`` and ``panos/`` (e.g. ``sample_tour/000`` of
github.com/zillow/zind). ZInD's data is for academic, non-commercial use only: keep it and
everything made from it out of this repository. Every scene is a set of panoramas of one
complete room (every two of them 0.5-6 m apart), with ZInD's annotated poses as the truth:
floor-plan position and heading (levelled panoramas), camera height 1 in the room's units.

ZInD's frames (its ``code/transformations.py``): a panorama's local frame has z up and the image
centre column along +y, the column at a quarter of the width along +x (a left-handed frame
with z up); local -> floor plan is ``p = scale * R(rotation) p_local + translation``, and
``scale_meters_per_coordinate`` takes floor-plan units to metres. Here the floor plan's x is
negated (a right-handed world, z up) and the camera axes mapped to OpenGL's.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import random
from pathlib import Path

import numpy as np

from panogrf.app.files.images import read_rgb
from panogrf.app.scene.folder import write_scene

#: OpenGL camera axes -> ZInD local axes: x_l = -x, y_l = -z, z_l = y.
GL_TO_ZIND = np.array([[-1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
#: Negate the floor plan's x (a right-handed world), then z up -> y up.
WORLD = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]) @ np.diag([-1.0, 1, 1])


def panoramas(tour: Path) -> dict[str, list[dict]]:
    """Per complete room: [{"image", "c2w" (OpenGL, metres, y up), "label"}]."""
    data = json.loads((tour / "zind_data.json").read_text())
    rooms: dict[str, list[dict]] = {}
    for floor, rooms_of_floor in data["merger"].items():
        metres = data["scale_meters_per_coordinate"][floor]
        if metres is None:
            continue
        for room, partials in rooms_of_floor.items():
            for partial in partials.values():
                for pano in partial.values():
                    t = pano["floor_plan_transformation"]
                    a = math.radians(t["rotation"])
                    rz = np.array(
                        [[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]]
                    )
                    height = pano["camera_height"] * t["scale"] * metres
                    centre = np.array([*(np.array(t["translation"]) * metres), height])
                    c2w = np.eye(4)
                    c2w[:3, :3] = WORLD @ rz @ GL_TO_ZIND
                    c2w[:3, 3] = WORLD @ centre
                    rooms.setdefault(f"{floor}_{room}", []).append(
                        {"image": tour / pano["image_path"], "c2w": c2w, "label": pano["label"]}
                    )
    return rooms


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("tour", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--max-per-room", type=int, default=8, help="triplets per room at most")
    parser.add_argument("--min-m", type=float, default=0.5)
    parser.add_argument("--max-m", type=float, default=6.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    made = []
    for room, panos in sorted(panoramas(args.tour).items()):
        sets = []
        for size in (3, 2):
            combos = [
                c
                for c in itertools.combinations(range(len(panos)), size)
                if all(
                    args.min_m
                    <= np.linalg.norm(panos[i]["c2w"][:3, 3] - panos[j]["c2w"][:3, 3])
                    <= args.max_m
                    for i, j in itertools.combinations(c, 2)
                )
            ]
            rng.shuffle(combos)
            sets += combos[: args.max_per_room]
            if size == 3 and sets:
                break  # a room with triplets gives triplets only
        for c in sets:
            name = f"{room}_" + "_".join(panos[i]["image"].stem.split("_")[-1] for i in c)
            images = np.stack([read_rgb(panos[i]["image"]) for i in c])
            c2w = np.stack([panos[i]["c2w"] for i in c])
            out = args.out / name
            if (out / "transforms.json").exists():
                made.append(name)
                continue
            write_scene(
                out,
                c2w,
                np.ascontiguousarray(images.transpose(0, 3, 1, 2)),
                names=[panos[i]["image"].stem for i in c],
                metadata={
                    "source": "ZInD (academic, non-commercial use only)",
                    "labels": [panos[i]["label"] for i in c],
                },
            )
            made.append(name)
    print(f"wrote {len(made)} scenes to {args.out}")


if __name__ == "__main__":
    main()
