"""One scene of every panorama of a ZInD tour's floors with a scale (a home of many photos):

    python lab/zind_floor.py ZIND_TOUR_DIR OUT_DIR [--rows 512]

ZIND_TOUR_DIR as for `benchmarks/zind_scenes.py` (e.g. ``sample_tour/000`` of
github.com/zillow/zind: 32 panoramas of one floor, 14 x 8 m). ZInD's data is for academic,
non-commercial use only: keep it and everything made from it out of this repository.
"""

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
from zind_scenes import panoramas  # noqa: E402

from panogrf.app.files.images import read_rgb  # noqa: E402
from panogrf.app.scene.folder import write_scene  # noqa: E402

parser = argparse.ArgumentParser()
parser.add_argument("tour", type=Path)
parser.add_argument("out", type=Path)
parser.add_argument("--rows", type=int, default=512)
args = parser.parse_args()
rooms = panoramas(args.tour)
allp = [p for v in rooms.values() for p in v]
c = np.stack([p["c2w"][:3, 3] for p in allp])
print(f"{len(allp)} panoramas, extent {c.min(0).round(2)} to {c.max(0).round(2)} m")
out = args.out
rows = args.rows
imgs = []
for p in allp:
    im = read_rgb(p["image"])
    t = torch.from_numpy(np.ascontiguousarray(im.transpose(2, 0, 1))).float()[None]
    t = torch.nn.functional.interpolate(t, size=(rows, 2 * rows), mode="area")[0]
    imgs.append(t.round().clamp(0, 255).byte().numpy())
write_scene(
    out, np.stack([p["c2w"] for p in allp]), np.stack(imgs), names=[p["image"].stem for p in allp]
)
print("wrote", out)
