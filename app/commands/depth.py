"""`panogrf depth SCENE --out DIR`: spherical depth for every view of a scene, written as a scene.

The work is `panogrf.app.scene.estimate.estimate_scene`; this module parses and reports. The
options are declared once, on the fields of `DepthConfig` (`panogrf.app.options`).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import torch

from panogrf.app.options import add_options, from_args, option
from panogrf.app.runtime import prepare_options
from panogrf.app.scene.estimate import (
    METRIC_COLUMNS,
    MODES,
    DepthRun,
    estimate_scene,
    prepare_out_dir,
)
from panogrf.model.depth_config import DepthMode

_DESCRIPTION = """\
Estimate spherical depth (metres from the camera centre) for every view of a scene folder;
each view is the reference once, with all other views as sources. Modes:
  full  mono-guided multi-view stereo (the method; default)
  mono  the 360-degree monocular network alone
  mvs   multi-view stereo without the monocular guidance

DIR becomes a scene folder of its own: images/ (copies of the panoramas), depth/ (16-bit PNG,
millimetres, the size of the images), preview/ (colour-mapped depth for people, near is
bright, one scale for all views) and transforms.json (the input's poses and metadata, each
frame's depth_file_path pointing at the estimate, and a "panogrf_depth" key with the mode,
weights, warnings, sources and the share of pixels clamped at the top of the depth range).

When the scene has ground-truth depth, L1, RMSE, WS-L1 and WS-RMSE (metres) are printed per
view and their mean. Warnings (a single view, a source at the same position) go to stderr.

The estimate is cached on disk, keyed by the panoramas, poses, weights, mode and device (the
cache `panogrf demo` shares): a second run on the same scene reads it (--no-cache: afresh)."""


@dataclass(frozen=True)
class DepthConfig:
    """Which scene `panogrf depth` estimates, how, and where the new scene goes. A field made
    with `option` is also an option of the command."""

    scene: Path = option(help="scene folder (transforms.json)", positional=True, metavar="SCENE")
    """The scene folder."""
    out: Path = option(help="output folder (a new scene)", metavar="DIR")
    """The output folder, a scene of its own."""
    mode: DepthMode = option(DepthMode.FULL, "which estimator (default full)", choices=MODES)
    """The estimator (`MODES`)."""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "depth",
        help="estimate 360-degree depth for every view of a scene",
        description=_DESCRIPTION,
        epilog="example: panogrf depth data/test_00000 --out depth_out --mode full",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_options(parser, DepthConfig, *prepare_options(nadir=False))
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from panogrf.app.runtime import resolve_device
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.weights import networks as depth_weights

    cfg = from_args(DepthConfig, args)
    device = resolve_device(args.device)
    # Scene and output folder problems first: they need no networks.
    prepare_out_dir(cfg.scene, cfg.out)
    scene = load_scene(cfg.scene, load_images=True)
    modes = depth_weights.NETWORKS[cfg.mode]
    estimator = depth_weights.load_depth_estimator(modes, str(device))
    weights = depth_weights.depth_weight_files(cfg.mode)
    result = estimate_scene(
        scene,
        cfg.out,
        estimator,
        cfg.mode,
        weights=weights,
        cache_dir=args.cache_dir,
        use_cache=not args.no_cache,
    )
    for warning in result.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    print("\n".join(_report_lines(cfg.scene, result, device)))
    return 0


def _report_lines(scene_root: Path, r: DepthRun, device: torch.device) -> list[str]:
    n = len(r.views)
    lines = [
        f"scene: {scene_root} ({n} view{'s' if n != 1 else ''}: {', '.join(r.views)})",
        f"estimated depth (mode {r.mode}) in {r.seconds:.2f} s on {device} "
        f"({r.seconds / n:.2f} s per view"
        + ("" if r.cache in (None, "built") else f"; depth cache {r.cache}")
        + ")",
    ]
    clamped = [
        f"{name} {f:.1%}" for name, f in zip(r.views, r.out_of_range_fraction, strict=True) if f > 0
    ]
    if clamped:
        lines.append(f"clamped at {r.d_max:g} m (out of range): {', '.join(clamped)}")
    if r.metrics is None:
        lines.append("no ground-truth depth in the scene: no depth metrics")
    else:
        width = max(len("mean"), *(len(v) for v in r.views))
        lines.append(f"depth error vs ground truth, metres (pixels with 0 < gt <= {r.d_max:g} m):")
        lines.append(f"  {'view':<{width}}" + "".join(f" {c:>8}" for c, _ in METRIC_COLUMNS))
        for name, m in zip(r.views, r.metrics, strict=True):
            if m is None:
                lines.append(f"  {name:<{width}}" + f" {'n/a':>8}" * len(METRIC_COLUMNS))
            else:
                values = "".join(f" {getattr(m, key):>8.3f}" for _, key in METRIC_COLUMNS)
                lines.append(f"  {name:<{width}}{values}")
        mean = r.mean_metrics
        if mean is not None:
            values = "".join(f" {mean[key]:>8.3f}" for _, key in METRIC_COLUMNS)
            lines.append(f"  {'mean':<{width}}{values}")
    lines.append(f"wrote {r.out_dir} (images/, depth/, preview/, transforms.json)")
    return lines


__all__ = ["register", "run"]
