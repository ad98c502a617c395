"""`panogrf bench DATASET --out DIR`: speed against accuracy of every method, charted.

Every method and setting (nearest, the GL preview at each mesh size, meshwarp, PanoGRF draft /
fast / paper, the no-mono and no-MVS ablations, S-NeRF) renders the middle view of --scenes
test triplets per baseline from the outer two; each is timed once at --time-height rows (512 x
1024: the chart's x axis) with its peak memory. A stability sweep (--sweep-scenes synthetic
scenes per baseline, 0.2-5 m: mean and spread) and six hard cases made by the synthetic
generator (heavy occlusion, textureless walls, objects at the poles, a target off the line,
extrapolation, a pose at a source) follow, every render checked for NaN, inf and emptiness.

Writes DIR/frontier.png (seconds against WS-PSNR and LPIPS, the Pareto frontier dashed),
DIR/stability.png, DIR/gallery.png, DIR/results.json and DIR/table.md. A few minutes on two
cores with the defaults, most of it S-NeRF's per-scene fits and the paper sampling (--skip
them to go faster).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from panogrf.app.errors import UserError
from panogrf.app.runtime import (
    add_prepare_options,
    add_refine_depth,
    metres_list,
    number,
    refine_setting,
    resolve_device,
    thread_count,
)


def register(subparsers) -> None:
    from panogrf.app.bench.cases import CASES, SWEEP_BASELINES
    from panogrf.app.bench.settings import BY_NAME

    parser = subparsers.add_parser(
        "bench",
        help="chart speed against accuracy of every method; baseline sweep; hard cases",
        description="\n\n".join(__doc__.split("\n\n")[1:3]),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="example: panogrf bench data/test --out out/bench --threads 1",
    )
    parser.add_argument(
        "dataset",
        type=Path,
        metavar="DATASET_OR_SCENES",
        help="a dataset (dataset.json), a folder of triplet scene folders, or one scene folder",
    )
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--scenes", type=int, default=1, help="triplets per baseline (default 1)")
    parser.add_argument(
        "--baselines",
        type=metres_list,
        default=None,
        help="baselines (m) to score (default: 1.0,1.5,2.0 for a dataset, all for a folder)",
    )
    parser.add_argument("--height", type=int, default=256, help="rows of the quality renders")
    parser.add_argument(
        "--time-height", type=int, default=512, help="rows of the timed render (default 512)"
    )
    parser.add_argument(
        "--time-budget",
        type=number(float, 0.0, low_open=True),
        default=30.0,
        help="seconds: a setting predicted slower at --time-height is not rendered there; its "
        "time is predicted from the --height render (marked * in the table)",
    )
    parser.add_argument(
        "--settings",
        default=None,
        help=f"comma-separated settings (default: all): {','.join(BY_NAME)}",
    )
    parser.add_argument("--skip", default="", help="settings to leave out, e.g. snerf")
    parser.add_argument(
        "--real",
        type=Path,
        default=None,
        help="a dataset of real triplets, charted as stars (default: data/real if it exists; "
        "'none': none)",
    )
    parser.add_argument(
        "--case-height", type=int, default=128, help="rows of the sweep and hard cases"
    )
    parser.add_argument(
        "--sweep",
        type=metres_list,
        default=SWEEP_BASELINES,
        help=f"sweep baselines in m (default {','.join(f'{b:g}' for b in SWEEP_BASELINES)}; "
        "'' for none)",
    )
    parser.add_argument(
        "--sweep-scenes",
        type=int,
        default=5,
        help="synthetic scenes per sweep baseline: the sweep's mean and spread (default 5)",
    )
    parser.add_argument(
        "--cases",
        default=",".join(CASES),
        help=f"hard cases for the gallery (default all: {','.join(CASES)}; '' for none)",
    )
    parser.add_argument(
        "--threads", type=thread_count, default=0, help="torch threads (default: all)"
    )
    add_refine_depth(parser)
    add_prepare_options(parser, nadir=False)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from panogrf.app.bench.cases import CASES
    from panogrf.app.bench.report import write_outputs
    from panogrf.app.bench.run import BenchConfig, run_bench
    from panogrf.app.bench.settings import select
    from panogrf.app.files.atomic import check_output
    from panogrf.app.scene import session
    from panogrf.app.scene.session import MAX_HEIGHT

    for opt, h in (("--height", args.height), ("--time-height", args.time_height)):
        if not 8 <= h <= MAX_HEIGHT:
            raise UserError(f"{opt} must be between 8 and {MAX_HEIGHT}, got {h}")
    if not 8 <= args.case_height <= MAX_HEIGHT:
        raise UserError(f"--case-height must be between 8 and {MAX_HEIGHT}, got {args.case_height}")
    if args.scenes < 1:
        raise UserError(f"--scenes must be at least 1, got {args.scenes}")
    if not 1 <= args.sweep_scenes <= 100:
        raise UserError(f"--sweep-scenes must be between 1 and 100, got {args.sweep_scenes}")
    try:
        settings = select(args.settings, args.skip)
    except ValueError as exc:
        raise UserError(f"--settings / --skip: {exc}") from None
    if not settings:
        raise UserError("--settings / --skip leave no setting to run")
    cases = tuple(c.strip() for c in args.cases.split(",") if c.strip())
    unknown = [c for c in cases if c not in CASES]
    if unknown:
        raise UserError(f"--cases: unknown {unknown}; choose from {','.join(CASES)}")
    real = args.real
    if real is None:
        real = Path("data/real") if (Path("data/real") / "dataset.json").exists() else None
    elif str(real).lower() == "none":
        real = None
    if args.threads:
        torch.set_num_threads(args.threads)
    check_output(args.out, folder=True)
    cfg = BenchConfig(
        data=args.dataset,
        settings=tuple(settings),
        scenes=args.scenes,
        baselines=args.baselines,
        height=args.height,
        time_height=args.time_height,
        time_budget=args.time_budget,
        real=real,
        refine=refine_setting(args),
        cache_dir=args.cache_dir,
        use_cache=not args.no_cache,
        case_height=args.case_height,
        sweep=args.sweep,
        sweep_scenes=args.sweep_scenes,
        cases=cases,
    )
    models = session.default_models(resolve_device(args.device))
    report = run_bench(cfg, models, log=lambda s: print(s, flush=True))
    from panogrf.app.bench.report import format_table

    written = write_outputs(report, args.out)
    print(format_table(report))
    print("wrote " + ", ".join(str(p) for p in written))
    return 0
