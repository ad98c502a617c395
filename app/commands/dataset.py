"""`panogrf dataset make`: procedural indoor 360-degree scenes for training and benchmarks."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from panogrf.app.errors import UserError
from panogrf.app.runtime import metres_list, number


def _baselines(text: str) -> tuple[float, ...]:
    values = metres_list(text)
    if not values:
        raise argparse.ArgumentTypeError(f"baselines must be between 0.05 and 5 m, got {text!r}")
    return values


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "dataset",
        help="make synthetic panorama datasets",
        description="Synthetic indoor panorama datasets (the project's training and test data).",
    )
    sub = parser.add_subparsers(dest="dataset_command", metavar="SUBCOMMAND", required=True)
    make = sub.add_parser(
        "make",
        help="render synthetic scenes (three panoramas on a line, with depth)",
        description=(
            "Render procedural two-room indoor scenes headless (EGL): each scene folder holds "
            "three panoramas on a line (first-to-last baseline 0.2-2.0 m unless fixed), their "
            "spherical depth (16-bit PNG, mm) and poses in transforms.json. Deterministic from "
            "--seed; train and test use disjoint seeds and disjoint textures."
        ),
    )
    make.add_argument("--out", type=Path, required=True, help="output folder")
    make.add_argument("--split", choices=("train", "test"), default="train", help="data split")
    make.add_argument("--count", type=int, default=12, help="number of scenes (default 12)")
    make.add_argument("--height", type=int, default=256, help="panorama height; width = 2x")
    make.add_argument(
        "--baselines",
        type=_baselines,
        default=(),
        help="comma-separated first-to-last distances in metres to cycle through, e.g. 1.0,1.5,2.0 "
        "(default: random in 0.2-2.0)",
    )
    make.add_argument(
        "--world",
        choices=("classic", "home"),
        default="classic",
        help="classic rooms, or home: household materials, bright windows, rugs, sun patches, "
        "camera heights 1.0-1.8 m, baselines up to 3.5 m, middle view off the line",
    )
    make.add_argument(
        "--renderer",
        choices=("gl", "pyrender"),
        default="gl",
        help="gl: fast unshadowed shading (default); pyrender: physically based, with "
        "shadow-casting lights, sun through the windows, glossy floors and auto exposure "
        "(about 30x slower; runs in --workers processes)",
    )
    make.add_argument(
        "--workers", type=int, default=2, help="pyrender worker processes (default 2)"
    )
    make.add_argument(
        "--trims",
        type=float,
        default=0.0,
        help="home world: the fraction of scenes whose main room has a picture rail with a "
        "frieze above it and maybe a dado with wainscot below (default 0)",
    )
    make.add_argument(
        "--coves",
        type=float,
        default=0.0,
        help="home world: the fraction of scenes whose main room meets its ceiling in a cove or "
        "a crown moulding (default 0)",
    )
    make.add_argument(
        "--sheers",
        type=float,
        default=0.0,
        help="home world: the fraction of scenes whose windows get sheer or lace curtains, "
        "pleated and glowing in front of the glass (default 0)",
    )
    make.add_argument("--seed", type=number(int, 0), default=0, help="base seed (default 0)")
    make.add_argument("--start", type=number(int, 0), default=0, help="index of the first scene")
    make.add_argument("--json", action="store_true", help="print the summary as JSON")
    make.add_argument("--no-progress", action="store_true", help="no progress bar")
    make.set_defaults(func=run_make)
    pack = sub.add_parser(
        "pack",
        help="pack scenes at a working height into one small file (training elsewhere)",
        description=(
            "Pack the scenes of dataset folders at the training's working height into one "
            "safetensors file: JPEG panoramas, 16-bit depth in 5 mm steps, poses. `panogrf "
            "train depth --data` reads a pack, or a folder of packs, as it reads a dataset "
            "folder; about 60 kB a scene at 128 rows, so thousands travel where the folders "
            "cannot."
        ),
        epilog="example: panogrf dataset pack --out packs/lit.safetensors data/train_pbr "
        "data/train_mix:600:200",
    )
    pack.add_argument("--out", type=Path, required=True, help="the pack (.safetensors)")
    pack.add_argument(
        "--height", type=number(int, 8, 4096), default=128, help="working height (default 128)"
    )
    pack.add_argument(
        "--colour-only",
        action="store_true",
        help="leave the true depth out (a third of the size): for `panogrf train renderer`, "
        "which never reads it; a depth training refuses such a pack",
    )
    pack.add_argument(
        "sources",
        type=_pack_source,
        nargs="+",
        help="dataset folders, each FOLDER (every scene) or FOLDER:FIRST:COUNT",
    )
    pack.set_defaults(func=run_pack)
    merge = sub.add_parser(
        "merge",
        help="one training folder from several datasets (scene folders linked, not copied)",
        description=(
            "List the scenes of several `dataset make` folders in one dataset folder, for "
            "`panogrf train`: each scene folder is a symbolic link to its source's, and "
            "dataset.json lists them all. Scene names must be unique (make the datasets with "
            "different --start)."
        ),
    )
    merge.add_argument("--out", type=Path, required=True, help="the merged dataset folder")
    merge.add_argument("sources", type=Path, nargs="+", help="dataset folders to merge")
    merge.set_defaults(func=run_merge)


def run_make(args: argparse.Namespace) -> int:
    from panogrf.app.synth.make import MakeConfig, make_dataset

    if args.count < 1:
        raise UserError(f"--count must be at least 1, got {args.count}")
    if args.height < 8 or args.height > 4096:
        raise UserError(f"--height must be between 8 and 4096, got {args.height}")
    if args.workers < 1:
        raise UserError(f"--workers must be at least 1, got {args.workers}")
    from panogrf.app.synth.make import FINISHES

    for name in FINISHES:
        p = getattr(args, name)
        if not 0.0 <= p <= 1.0:
            raise UserError(f"--{name} must be between 0 and 1, got {p}")
        if p > 0 and args.world != "home":
            raise UserError(f"--{name} needs --world home")
    if args.out.exists() and not args.out.is_dir():
        raise UserError(f"--out {args.out} exists and is not a folder")
    cfg = MakeConfig(
        out=args.out,
        split=args.split,
        count=args.count,
        height=args.height,
        baselines=args.baselines,
        world=args.world,
        renderer=args.renderer,
        workers=args.workers,
        **{name: getattr(args, name) for name in FINISHES},
        seed=args.seed,
        start=args.start,
    )
    try:
        summary = make_dataset(cfg, progress=not args.no_progress)
    except PermissionError as exc:
        raise UserError(f"cannot write to {args.out}: {exc.strerror}") from None
    except OSError as exc:  # a file where a scene folder goes, a full disk, ...
        where = f" ({exc.filename})" if exc.filename else ""
        raise UserError(f"cannot write to {args.out}: {exc.strerror or exc}{where}") from None
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(
            f"wrote {summary['scenes']} scenes ({summary['panoramas']} panoramas, "
            f"{summary['width']}x{summary['height']}, "
            f"at most {summary['max_triangles']} triangles) "
            f"to {args.out} in {summary['seconds']:.1f} s: {summary['panoramas_per_s']:.1f} "
            f"panoramas/s end to end (render {summary['render_panoramas_per_s']:.1f}/s)"
        )
    return 0


def _pack_source(text: str) -> tuple[Path, int, int]:
    folder, _, span = text.partition(":")
    if not span:
        return Path(folder), 0, -1
    try:
        first, count = (int(x) for x in span.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected FOLDER or FOLDER:FIRST:COUNT, got {text!r}"
        ) from None
    if first < 0 or count < 1:
        raise argparse.ArgumentTypeError(f"FIRST must be >= 0 and COUNT >= 1, got {text!r}")
    return Path(folder), first, count


def run_pack(args: argparse.Namespace) -> int:
    from panogrf.app.train.pack import pack_scenes

    if args.out.suffix != ".safetensors":
        raise UserError(f"--out must end in .safetensors, got {args.out}")
    from panogrf.app.files.atomic import check_writable

    try:  # the pack's folder is made for it, as before
        args.out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"--out: cannot make {args.out.parent} ({exc.strerror or exc})") from None
    check_writable(args.out)  # a folder of that name, a read-only place (T13)
    if args.height % 32:
        raise UserError(f"--height must be a multiple of 32, got {args.height}")
    try:
        summary = pack_scenes(args.sources, args.out, args.height, depth=not args.colour_only)
    except OSError as exc:  # a full disk: the earlier pack, if any, is intact (atomic write)
        raise UserError(f"cannot write {args.out}: {exc.strerror or exc}") from None
    print(f"{args.out}: {summary['scenes']} scenes, {summary['bytes'] / 1e6:.1f} MB")
    return 0


def run_merge(args: argparse.Namespace) -> int:
    from panogrf.app.synth.make import merge_datasets

    summary = merge_datasets(args.out, args.sources)
    print(f"{args.out}: {summary['scenes']} scenes from {summary['sources']} datasets")
    return 0
