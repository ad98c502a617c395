"""`panogrf scene ...`: tools for scene folders (posed panoramas in a transforms.json).

Each sub-subcommand is one ``_add_<name>(sub)`` function listed in `_SUBCOMMANDS`: it adds its
parser and sets ``func`` to a function of the parsed arguments that returns the exit code. The
options of ``check`` and ``reproject`` are declared once, on the fields of `CheckConfig` and
`ReprojectConfig` (`panogrf.app.options`).
"""

from __future__ import annotations

import argparse
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from panogrf.app.commands import scene_faces, scene_poses, scene_poses_report, scene_prepare
from panogrf.app.errors import UserError
from panogrf.app.options import add_options, from_args, option
from panogrf.app.scene.folder import TRANSFORMS, SceneReport, inspect_scene

#: Up to this many views, every pairwise baseline is printed; beyond, a summary.
_MAX_LISTED_VIEWS = 5

_DESCRIPTION = f"""\
Scene folders hold posed 360-degree panoramas: a nerfstudio-style {TRANSFORMS} with
"camera_model": "EQUIRECTANGULAR", "w", "h" and frames[] (file_path, 4x4 camera-to-world
transform_matrix in the OpenGL frame, metres, optional 16-bit depth_file_path in mm)."""


def _baseline_lines(report: SceneReport) -> list[str]:
    scene = report.scene
    centres = scene.c2w[:, :3, 3]
    names = [f.name for f in scene.frames]
    if scene.num_views < 2:
        return ["  baselines: none (a single view)"]
    if scene.num_views <= _MAX_LISTED_VIEWS:
        pairs = itertools.combinations(range(scene.num_views), 2)
        return ["  baselines between view centres (m):"] + [
            f"    {names[a]} - {names[b]}: {np.linalg.norm(centres[a] - centres[b]):.3f}"
            for a, b in pairs
        ]
    return [f"  nearest-neighbour baselines (m): {scene_poses_report.nearest_baselines(centres)}"]


def _summary(report: SceneReport) -> list[str]:
    scene = report.scene
    with_depth = sum(f.depth_path is not None for f in scene.frames)
    lines = [
        f"scene OK: {report.root}",
        f"  views: {scene.num_views} ({', '.join(f.name for f in scene.frames)})",
        f"  size: {scene.width}x{scene.height} (width x height)",
        *_baseline_lines(report),
    ]
    if with_depth == 0:
        lines.append("  depth: none")
    elif report.depth_range_m is None:
        lines.append(f"  depth: {with_depth} of {scene.num_views} views, all pixels unknown (0)")
    else:
        lo, hi = report.depth_range_m
        lines.append(f"  depth: {with_depth} of {scene.num_views} views, {lo:.3f} to {hi:.3f} m")
    lines += [f"  note: {n}" for n in report.notes]
    lines += [f"  warning: {w}" for w in report.warnings]
    return lines


@dataclass(frozen=True)
class CheckConfig:
    """The scene `panogrf scene check` validates (its field is also its argument)."""

    dir: str = option(
        help=f"scene folder (containing {TRANSFORMS})", positional=True, metavar="DIR"
    )
    """The scene folder."""


def run_check(args: argparse.Namespace) -> int:
    report = inspect_scene(from_args(CheckConfig, args).dir)
    if report.ok:
        print("\n".join(_summary(report)))
        return 0
    n = len(report.problems)
    print(f"scene INVALID: {report.root} ({n} problem{'s' if n != 1 else ''})")
    for problem in report.problems:
        print(f"  {problem}")
    return 1


def _add_check(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "check",
        help="validate a scene folder and summarise it",
        description=(
            "Validate a scene folder, reporting every problem at once (one per line, naming the "
            "file or field), or print a summary: views, size, baselines, depth. Exit status 0 "
            "when valid, 1 when not."
        ),
        epilog="example: panogrf scene check data/val_00000",
    )
    add_options(parser, CheckConfig)
    parser.set_defaults(func=run_check)


def _view_list(text: str) -> list[int]:
    try:
        return [int(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated views, got {text!r}") from None


@dataclass(frozen=True)
class ReprojectConfig:
    """The views `panogrf scene reproject` warps into each other. A field made with `option`
    is also an option of the command; the settings are checked as they are built
    (`UserError`, one line naming the option)."""

    dir: str = option(
        help=f"scene folder (containing {TRANSFORMS})", positional=True, metavar="DIR"
    )
    """The scene folder."""
    target: int | None = option(None, "target view (default: middle)")
    """The view warped into (None: the middle one)."""
    sources: list[int] | None = option(
        None, "comma-separated source views (default: all others)", parse=_view_list
    )
    """The views warped (None: all but the target)."""
    occlusion_tol: float = option(
        0.05,
        "relative depth difference above which a point counts as occluded (default 0.05)",
    )
    """Relative depth difference above which a point counts as occluded."""

    def __post_init__(self) -> None:
        """Refuse an ``occlusion_tol`` that is not a positive finite number."""
        if not (math.isfinite(self.occlusion_tol) and self.occlusion_tol > 0):
            raise UserError(
                f"--occlusion-tol must be a positive relative depth difference (e.g. 0.05), "
                f"got {self.occlusion_tol}"
            )


def run_reproject(args: argparse.Namespace) -> int:
    from panogrf.app.scene.consistency import reprojection_check
    from panogrf.app.scene.folder import load_scene

    cfg = from_args(ReprojectConfig, args)
    scene = load_scene(cfg.dir, load_images=True)
    data = scene.images
    if data.depths is None:
        raise UserError(f"{cfg.dir}: the scene has no depth maps to warp with")
    n = scene.num_views
    target = cfg.target if cfg.target is not None else n // 2
    if not 0 <= target < n:
        raise UserError(f"--target {target} is out of range: the scene has {n} views")
    sources = [i for i in range(n) if i != target] if cfg.sources is None else cfg.sources
    for i in sources:
        if not 0 <= i < n or i == target:
            raise UserError(f"--sources: {i} is not another view of the {n}-view scene")
    if len(set(sources)) != len(sources):
        raise UserError(f"--sources must list distinct views, got {sources}")
    if not sources:
        raise UserError(f"{cfg.dir}: one view; reprojection needs another to warp from")
    name = scene.frames[target].name
    if not bool((data.depths[target] > 0).any()):  # its depth decides what is occluded
        raise UserError(f"--target {target} ({name}) has no depth map: choose a view that has")
    print(f"reprojection into view {target} ({name}), {scene.width}x{scene.height}:")
    print(
        f"  {'source':<12} {'baseline m':>10} {'covered':>8} "
        f"{'PSNR depth warp':>16} {'PSNR rotation only':>19}"
    )
    for i in sources:
        if not bool((data.depths[i] > 0).any()):
            print(f"  {scene.frames[i].name:<12} no depth map to warp with")
            continue
        r = reprojection_check(data.images, data.c2w, data.depths, i, target, cfg.occlusion_tol)
        print(
            f"  {scene.frames[i].name:<12} {r.baseline_m:>10.3f} {r.covered:>8.1%} "
            f"{r.psnr_depth_warp:>13.2f} dB {r.psnr_rotation_only:>16.2f} dB"
        )
    return 0


def _add_reproject(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "reproject",
        help="check that poses, depth and pixels agree by warping views into each other",
        description=(
            "Warp source views into a target view through the target's depth and report the "
            "PSNR against the target on the pixels the source sees, next to the PSNR of the "
            "source merely rotated to the target's orientation (no parallax). Consistent "
            "poses and depth give a far higher PSNR for the depth warp."
        ),
        epilog="example: panogrf scene reproject data/test_00000 --target 1 --sources 0,2",
    )
    add_options(parser, ReprojectConfig)
    parser.set_defaults(func=run_reproject)


# Name -> function adding that sub-subcommand; the order is the order in --help.
_SUBCOMMANDS: dict[str, Callable[[argparse._SubParsersAction], None]] = {
    "check": _add_check,
    "reproject": _add_reproject,
    "prepare": scene_prepare.add_prepare,
    "from-panoramas": scene_poses._add_from_panoramas,
    "import": scene_poses._add_import,
    "faces": scene_faces._add_faces,
}


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "scene",
        help="inspect, validate and make scene folders (poses from panoramas or pose files)",
        description=_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="scene_command", metavar="SUBCOMMAND", required=True)
    for add in _SUBCOMMANDS.values():
        add(sub)
