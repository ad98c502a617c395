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

The options are declared once, on the fields of `BenchConfig` (what is measured) and of
`BenchOptions` (the rest; `panogrf.app.options`).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

from panogrf.app.bench.run import BenchConfig
from panogrf.app.bench.settings import BY_NAME, Setting, select
from panogrf.app.errors import UserError
from panogrf.app.options import add_options, from_args, option
from panogrf.app.runtime import (
    RefineOptions,
    ThreadOptions,
    prepare_options,
    refine_setting,
    resolve_device,
)


@dataclass(frozen=True)
class BenchOptions:
    """The options of `panogrf bench` besides its measurement's settings (`BenchConfig`): where
    the outputs go, which settings run, and the real triplets (as the command line gives them)."""

    out: Path = option(help="output folder")
    """The output folder (`write_outputs`)."""
    settings: str | None = option(
        None, f"comma-separated settings (default: all): {','.join(BY_NAME)}"
    )
    """Comma-separated names of the settings to run (None: all)."""
    skip: str = option("", "settings to leave out, e.g. snerf")
    """Comma-separated names of the settings to leave out."""
    real: Path | None = option(
        None,
        "a dataset of real triplets, charted as stars (default: data/real if it exists; "
        "'none': none)",
    )
    """A dataset of real triplets (None: data/real if it holds a dataset; "none": none)."""

    def __post_init__(self) -> None:
        """Refuse a setting listed twice in ``settings``: it would run and be charted once."""
        names = [n.strip() for n in (self.settings or "").split(",") if n.strip()]
        twice = next((n for k, n in enumerate(names) if n in names[:k]), None)
        if twice is not None:
            raise UserError(f"--settings: {twice} is listed twice; give each setting once")
        real = self.real_data()
        if real is not None and not real.is_dir():
            what = "is not a folder" if real.exists() else "no such folder"
            raise UserError(f"--real {real}: {what} (a dataset of real triplets, or none)")

    def chosen(self) -> tuple[Setting, ...]:
        """The settings ``settings`` and ``skip`` name (`UserError` for an unknown name)."""
        try:
            return tuple(select(self.settings, self.skip))
        except ValueError as exc:
            raise UserError(f"--settings / --skip: {exc}") from None

    def real_data(self) -> Path | None:
        """The real triplets' dataset that ``real`` names, if any."""
        if self.real is None:
            default = Path("data/real")
            return default if (default / "dataset.json").exists() else None
        return None if str(self.real).lower() == "none" else self.real


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "bench",
        help="chart speed against accuracy of every method; baseline sweep; hard cases",
        description="\n\n".join(__doc__.split("\n\n")[1:3]),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="example: panogrf bench data/test --out out/bench --threads 1",
    )
    add_options(
        parser,
        BenchConfig,
        BenchOptions,
        ThreadOptions,
        RefineOptions,
        *prepare_options(nadir=False),
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from panogrf.app.bench.report import earlier_output, format_table, write_outputs
    from panogrf.app.bench.run import run_bench
    from panogrf.app.files.atomic import check_output, refuse_foreign_folder
    from panogrf.app.scene import session

    options = from_args(BenchOptions, args)
    cfg = from_args(
        BenchConfig,
        args,
        settings=options.chosen(),
        real=options.real_data(),
        refine=refine_setting(args),
        cache_dir=args.cache_dir,
        use_cache=not args.no_cache,
    )
    from_args(ThreadOptions, args).apply()
    check_output(options.out, folder=True)
    refuse_foreign_folder(options.out, "bench", earlier_output)  # a scene, the photos
    models = session.default_models(resolve_device(args.device))
    report = run_bench(cfg, models, log=lambda s: print(s, flush=True))
    written = write_outputs(report, options.out)
    print(format_table(report))
    print("wrote " + ", ".join(str(p) for p in written))
    return 0
