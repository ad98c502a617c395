"""`panogrf dataset make|pack|merge`: procedural indoor 360-degree scenes for training and
benchmarks.

Each subcommand's options are the fields of its dataclass (`MakeOptions`, `PackOptions`,
`MergeOptions`), declared once with their defaults, help and checks (`panogrf.app.options`).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, fields
from pathlib import Path

from panogrf.app.errors import UserError
from panogrf.app.options import add_options, from_args, option, user_path
from panogrf.app.runtime import metres_list, number


def _baselines(text: str) -> tuple[float, ...]:
    values = metres_list(text)
    if not values:
        raise argparse.ArgumentTypeError(f"baselines must be between 0.05 and 5 m, got {text!r}")
    return values


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


@dataclass(frozen=True)
class MakeOptions:
    """The options of `panogrf dataset make`: the dataset it renders (`config`, a
    `panogrf.app.synth.make.MakeConfig`) and how it reports."""

    out: Path = option(help="output folder")
    """Output folder."""
    split: str = option("train", "data split", choices=("train", "test"))
    """"train" or "test"."""
    count: int = option(12, "number of scenes (default {default})")
    """Number of scenes."""
    height: int = option(256, "panorama height; width = 2x")
    """Panorama height in pixels (8-4096)."""
    baselines: tuple[float, ...] = option(
        (),
        "comma-separated first-to-last distances in metres to cycle through, e.g. 1.0,1.5,2.0 "
        "(default: random in 0.2-2.0)",
        parse=_baselines,
    )
    """First-to-last distances (m) to cycle through; empty: random."""
    world: str = option(
        "classic",
        "classic rooms, or home: household materials, bright windows, rugs, sun patches, "
        "camera heights 1.0-1.8 m, baselines up to 3.5 m, middle view off the line",
        choices=("classic", "home"),
    )
    """"classic" or "home"."""
    renderer: str = option(
        "gl",
        "gl: fast unshadowed shading (default); pyrender: physically based, with "
        "shadow-casting lights, sun through the windows, glossy floors and auto exposure "
        "(about 30x slower; runs in --workers processes)",
        choices=("gl", "pyrender"),
    )
    """"gl" or "pyrender"."""
    workers: int = option(2, "pyrender worker processes (default {default})")
    """Worker processes of the "pyrender" renderer."""
    trims: float = option(
        0.0,
        "home world: the fraction of scenes whose main room has a picture rail with a "
        "frieze above it and maybe a dado with wainscot below (default 0)",
    )
    """Home world: the fraction of scenes with trimmed walls (0-1)."""
    coves: float = option(
        0.0,
        "home world: the fraction of scenes whose main room meets its ceiling in a cove or "
        "a crown moulding (default 0)",
    )
    """Home world: the fraction of scenes with a cove or crown moulding (0-1)."""
    sheers: float = option(
        0.0,
        "home world: the fraction of scenes whose windows get sheer or lace curtains, "
        "pleated and glowing in front of the glass (default 0)",
    )
    """Home world: the fraction of scenes with sheer curtains (0-1)."""
    seed: int = option(0, "base seed (default {default})", parse=number(int, 0))
    """Base seed."""
    start: int = option(0, "index of the first scene", parse=number(int, 0))
    """Index of the first scene."""
    json: bool = option(False, "print the summary as JSON")
    """Print the summary as JSON."""
    progress: bool = option(True, "no progress bar")
    """Show a progress bar."""

    def __post_init__(self) -> None:
        """Refuse no scene, more scenes than one seed has, a height outside 8-4096, no worker,
        a finish outside 0-1 or outside the home world, and an ``out`` that is a file."""
        from panogrf.app.synth.make import FINISHES, SCENES_PER_SEED

        if self.count < 1:
            raise UserError(f"--count must be at least 1, got {self.count}")
        if self.start + self.count > SCENES_PER_SEED:  # the next --seed's scenes beyond
            raise UserError(
                f"--start {self.start} + --count {self.count}: at most {SCENES_PER_SEED} scenes "
                "per --seed (beyond, the scenes of the next seed repeat)"
            )
        if self.height < 8 or self.height > 4096:
            raise UserError(f"--height must be between 8 and 4096, got {self.height}")
        if self.workers < 1:
            raise UserError(f"--workers must be at least 1, got {self.workers}")
        for name in FINISHES:
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise UserError(f"--{name} must be between 0 and 1, got {p}")
            if p > 0 and self.world != "home":
                raise UserError(f"--{name} needs --world home")
        if self.out.exists() and not self.out.is_dir():
            raise UserError(f"--out {self.out} exists and is not a folder")

    def config(self):
        """The `MakeConfig` of these options."""
        from panogrf.app.synth.make import MakeConfig

        names = {f.name for f in fields(MakeConfig)} & {f.name for f in fields(self)}
        return MakeConfig(**{name: getattr(self, name) for name in names})


@dataclass(frozen=True, kw_only=True)
class PackOptions:
    """The options of `panogrf dataset pack` (`panogrf.app.train.pack.pack_scenes`)."""

    out: Path = option(help="the pack (.safetensors)")
    """The pack (safetensors); its folder is made as the options are checked."""
    height: int = option(128, "working height (default {default})", parse=number(int, 8, 4096))
    """Working height (a multiple of 32)."""
    colour_only: bool = option(
        False,
        "leave the true depth out (a third of the size): for `panogrf train renderer`, "
        "which never reads it; a depth training refuses such a pack",
    )
    """Leave the true depth out."""
    sources: list = option(
        help="dataset folders, each FOLDER (every scene) or FOLDER:FIRST:COUNT",
        positional=True,
        nargs="+",
        parse=_pack_source,
    )
    """(folder, first scene, count; -1: all) of each source."""

    def __post_init__(self) -> None:
        """Refuse an ``out`` not ending in .safetensors or not writable (its folder made,
        as before) and a height that is no multiple of 32."""
        from panogrf.app.files.atomic import check_writable

        if self.out.suffix != ".safetensors":
            raise UserError(f"--out must end in .safetensors, got {self.out}")
        try:  # the pack's folder is made for it, as before
            self.out.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            why = exc.strerror or exc
            raise UserError(f"--out: cannot make {self.out.parent} ({why})") from None
        check_writable(self.out)  # a folder of that name, a read-only place (T13)
        if self.height % 32:
            raise UserError(f"--height must be a multiple of 32, got {self.height}")


@dataclass(frozen=True, kw_only=True)
class MergeOptions:
    """The options of `panogrf dataset merge` (`panogrf.app.synth.merge.merge_datasets`)."""

    out: Path = option(help="the merged dataset folder")
    """The merged dataset folder."""
    sources: list = option(
        help="dataset folders to merge", positional=True, nargs="+", parse=user_path
    )
    """The dataset folders to merge."""


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
    add_options(make, MakeOptions)
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
    add_options(pack, PackOptions)
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
    add_options(merge, MergeOptions)
    merge.set_defaults(func=run_merge)


def run_make(args: argparse.Namespace) -> int:
    from panogrf.app.synth.make import check_out, make_dataset

    options = from_args(MakeOptions, args)
    out = options.out
    check_out(options.config())
    try:
        summary = make_dataset(options.config(), progress=options.progress)
    except PermissionError as exc:
        raise UserError(f"cannot write to {out}: {exc.strerror}") from None
    except OSError as exc:  # a file where a scene folder goes, a full disk, ...
        where = f" ({exc.filename})" if exc.filename else ""
        raise UserError(f"cannot write to {out}: {exc.strerror or exc}{where}") from None
    if options.json:
        print(json.dumps(summary, indent=2))
    else:
        print(
            f"wrote {summary['scenes']} scenes ({summary['panoramas']} panoramas, "
            f"{summary['width']}x{summary['height']}, "
            f"at most {summary['max_triangles']} triangles) "
            f"to {out} in {summary['seconds']:.1f} s: {summary['panoramas_per_s']:.1f} "
            f"panoramas/s end to end (render {summary['render_panoramas_per_s']:.1f}/s)"
        )
    return 0


def run_pack(args: argparse.Namespace) -> int:
    from panogrf.app.train.pack import pack_scenes

    options = from_args(PackOptions, args)
    try:
        summary = pack_scenes(
            options.sources, options.out, options.height, depth=not options.colour_only
        )
    except OSError as exc:  # a full disk: the earlier pack, if any, is intact (atomic write)
        raise UserError(f"cannot write {options.out}: {exc.strerror or exc}") from None
    print(f"{options.out}: {summary['scenes']} scenes, {summary['bytes'] / 1e6:.1f} MB")
    return 0


def run_merge(args: argparse.Namespace) -> int:
    from panogrf.app.synth.merge import merge_datasets

    options = from_args(MergeOptions, args)
    summary = merge_datasets(options.out, options.sources)
    print(f"{options.out}: {summary['scenes']} scenes from {summary['sources']} datasets")
    return 0
