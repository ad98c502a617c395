"""`panogrf scene faces`: panoramas split into the six cube faces that a COLMAP import expects.

Registered under `panogrf scene` by `panogrf.app.commands.scene`.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

from panogrf.app.commands.scene_poses import read_panoramas
from panogrf.app.errors import UserError
from panogrf.app.options import add_options, from_args, option, user_path
from panogrf.app.runtime import number


def run_faces(parsed: argparse.Namespace) -> int:
    import torch

    from panogrf.app.files.images import write_rgb
    from panogrf.model.cubemap import FACE_NAMES, erp_to_cubemap

    args = from_args(FacesOptions, parsed)
    seen: dict[str, Path] = {}
    for path in args.panoramas:  # OUT/<stem>/: two panoramas of one stem would share it
        if path.stem in seen:
            raise UserError(
                f"{path} and {seen[path.stem]} share the name {path.stem!r}: their faces would "
                "land in one folder, the second over the first; rename one"
            )
        seen[path.stem] = path
    if args.out.exists() and not args.out.is_dir():
        raise UserError(f"--out {args.out}: is a file, not a folder")
    images = read_panoramas(args.panoramas).images
    size = args.size or images.shape[3] // 4
    if size < 8 and args.size:
        raise UserError(f"--size {size}: faces need at least 8 px")
    if size < 8:  # the default, a quarter of the width
        h, w = images.shape[2:4]  # the smallest panorama's size: all are read at it
        which = args.panoramas[0] if len(args.panoramas) == 1 else "the smallest panorama"
        raise UserError(
            f"{which}: {w}x{h} is too small for cube faces (a quarter of the width, at least "
            "8 px); give --size, or larger panoramas"
        )
    try:
        for path, img in zip(args.panoramas, images, strict=True):
            erp = torch.from_numpy(img).double()[None] / 255.0
            faces = erp_to_cubemap(erp, size)[0]
            folder = args.out / path.stem
            folder.mkdir(parents=True, exist_ok=True)
            for name, face in zip(FACE_NAMES, faces, strict=True):
                write_rgb(folder / f"{name}.png", face.permute(1, 2, 0).numpy())
    except OSError as exc:
        raise UserError(f"cannot write {args.out}: {exc.strerror or exc}") from None
    print(
        f"wrote {len(images)} x 6 faces of {size}x{size} px (90 deg, f = {size / 2} px) "
        f"to {args.out}/<panorama>/<face>.png"
    )
    return 0


@dataclass(frozen=True, kw_only=True)
class FacesOptions:
    """`panogrf scene faces`' options."""

    panoramas: list[Path] = option(
        help="", positional=True, metavar="PANORAMA", nargs="+", parse=user_path
    )
    out: Path = option(help="output folder")
    size: int = option(0, help="face size in px (default W / 4)", parse=number(int, 0, 8192))


def _add_faces(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "faces",
        help="split panoramas into the six cube faces the COLMAP import expects",
        description=(
            "Write OUT/<panorama stem>/{front,right,back,left,up,down}.png: 90-degree pinhole "
            "views (focal length = size / 2 px, principal point at the centre). Run COLMAP on "
            "them (PINHOLE camera, one per size) and import its images.txt with "
            "`panogrf scene import --format colmap`."
        ),
    )
    add_options(parser, FacesOptions)
    parser.set_defaults(func=run_faces)
