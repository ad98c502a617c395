"""Make the real dev triplet (one Matterport3D test triplet) into a scene folder.

The public repository chengzhag/PanSplat carries one test triplet of PanoGRF's data format under
``datasets/pano_grf/png_render_test_1024x512_seq_len_3_m3d_dist_0.5/00000007/`` (views 00 01
02: ``rgb.png`` 512x1024, ``depth.png`` uint16 millimetres, ``rot.txt``, ``tran.txt``). This
script reads it from a bare git mirror of that repository (or from a folder holding the three
view folders) and writes, by default, ``data/real/`` (ignored by git)::

    data/real/dataset.json     # index read by `panogrf eval` and benchmarks/real_capture.py
    data/real/m3d_00000007/    # the scene folder: transforms.json, images/, depths/

Conventions (checked by ``panogrf scene reproject data/real/m3d_00000007``): the rotations
are the identity and ``tran.txt`` is the camera centre (0, 0, t_z) in our frame; the depth is
spherical distance. The first-to-last baseline is 1.0 m.

Matterport3D's terms allow non-commercial research use only: the data and anything derived
from it stay out of the repository, and nothing is trained on it.

Usage::

    python scripts/make_dev_triplet.py --mirror PATH/TO/PanSplat.git [--out data/real]
    python scripts/make_dev_triplet.py --folder PATH/TO/00000007 [--out data/real]
"""

from __future__ import annotations

import argparse
import io
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from PIL import Image

TRIPLET = "datasets/pano_grf/png_render_test_1024x512_seq_len_3_m3d_dist_0.5/00000007"
SCENE = "m3d_00000007"
VIEWS = ("00", "01", "02")


def _reader(args: argparse.Namespace):
    if args.mirror:

        def read(rel: str) -> bytes:
            cmd = ["git", "--git-dir", str(args.mirror), "show", f"HEAD:{TRIPLET}/{rel}"]
            done = subprocess.run(cmd, capture_output=True, check=False)
            if done.returncode:
                sys.exit(f"make_dev_triplet: {rel}: {done.stderr.decode().strip()}")
            return done.stdout

        return read
    folder = Path(args.folder)

    def read_file(rel: str) -> bytes:
        path = folder / rel
        if not path.is_file():
            sys.exit(f"make_dev_triplet: {path}: file not found")
        return path.read_bytes()

    return read_file


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    src = parser.add_mutually_exclusive_group(required=True)
    src.add_argument("--mirror", type=Path, help="bare git mirror of chengzhag/PanSplat")
    src.add_argument("--folder", type=Path, help="folder holding the view folders 00 01 02")
    parser.add_argument("--out", type=Path, default=Path("data/real"), help="output folder")
    args = parser.parse_args()
    read = _reader(args)

    from panogrf.app.scene.folder import write_scene

    images, depths, poses = [], [], []
    for v in VIEWS:
        rgb = np.asarray(Image.open(io.BytesIO(read(f"{v}/rgb.png"))).convert("RGB"))
        depth_mm = np.asarray(Image.open(io.BytesIO(read(f"{v}/depth.png")))).astype(np.float64)
        rot = np.loadtxt(io.BytesIO(read(f"{v}/rot.txt"))).reshape(3, 3)
        tran = np.loadtxt(io.BytesIO(read(f"{v}/tran.txt"))).reshape(3)
        c2w = np.eye(4)
        c2w[:3, :3] = rot
        c2w[:3, 3] = tran
        images.append(rgb.transpose(2, 0, 1))
        depths.append(depth_mm[None] / 1000.0)
        poses.append(c2w)
    write_scene(
        args.out / SCENE,
        np.stack(poses),
        np.stack(images),
        np.stack(depths),
        names=[f"view_{v}" for v in VIEWS],
        metadata={
            "source": f"chengzhag/PanSplat {TRIPLET}",
            "licence": "Matterport3D, non-commercial research",
        },
    )
    index = {"split": "real-dev", "scenes": [{"folder": SCENE, "baseline": 1.0}]}
    (args.out / "dataset.json").write_text(json.dumps(index, indent=2))
    print(f"wrote {args.out / SCENE} (3 views) and {args.out / 'dataset.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
