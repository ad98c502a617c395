"""`panogrf train ...`: train the networks on the synthetic train split.

Each training's options are the fields of its settings (`panogrf.app.train.configs`), declared
there once with their defaults, help and checks; this module only names the subcommands.
"""

from __future__ import annotations

import argparse
from contextlib import contextmanager
from pathlib import Path

from panogrf.app.errors import UserError
from panogrf.app.options import add_options, from_args
from panogrf.app.train.configs import (
    RunOptions,
    TrainBlendConfig,
    TrainDepthConfig,
    TrainRendererConfig,
    TrainSelectConfig,
    refuse_training_inputs,
)


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "train",
        help="train the networks on synthetic data",
        description="Train the project's networks on the synthetic train split (CPU).",
    )
    sub = parser.add_subparsers(dest="train_command", metavar="SUBCOMMAND", required=True)
    trainings = (
        ("depth", TrainDepthConfig, run_depth, _DEPTH),
        ("renderer", TrainRendererConfig, run_renderer, _RENDERER),
        ("select", TrainSelectConfig, run_select, _SELECT),
        ("blend", TrainBlendConfig, run_blend, _BLEND),
    )
    for name, config, run, (help_, description, example) in trainings:
        command = sub.add_parser(
            name, help=help_, description=description, epilog=f"example: {example}"
        )
        add_options(command, config, RunOptions)
        command.set_defaults(func=run)


_DEPTH = (
    "train the 360-degree mono depth network or the mono-guided MVS",
    "Train the monocular depth network (--stage mono) or the mono-guided 360-degree "
    "MVS with the monocular network frozen (--stage mvs). Logs the loss curve and "
    "writes safetensors weights with the command and final figures in the metadata.",
    "panogrf train depth --data data/train --stage mono "
    "--out assets/depth_mono.safetensors --log logs/mono.log",
)
_RENDERER = (
    "train the spherical radiance field renderer (depth networks frozen)",
    "Train the generalizable spherical radiance field renderer on the synthetic train "
    "split with the shipped depth networks frozen (their estimates for every training "
    "pair are computed once and cached beside the data). Logs the loss curve and "
    "writes safetensors weights with the command and final figures in the metadata.",
    "panogrf train renderer --data data/train "
    "--out assets/renderer_panogrf.safetensors --log lab/training/renderer.log",
)
_SELECT = (
    "train the fusion's hypothesis selector (depth networks frozen)",
    "Train the learned choice between the mono-guided and the unguided MVS depth in "
    "the depth fusion (`panogrf.model.select`). Mode full runs on a seeded sample of "
    "the training scenes as at preparation, some with the monocular network out of "
    "its domain, and what the fusion sees is recorded once (cached beside the data); "
    "the selector then learns which hypothesis ends nearer the truth. Logs the loss "
    "and writes safetensors weights with the command and final figures.",
    "panogrf train select --data data/train_lit "
    "--out assets/depth_select.safetensors --log lab/training/depth_select.log",
)
_BLEND = (
    "train the blend of the fused depth with the monocular depth (all else frozen)",
    "Train the per-pixel blend of mode full's fused depth with the monocular depth "
    "(`panogrf.model.blend`). Mode full runs on a seeded sample of the training scenes "
    "as at preparation (selector included), some with the monocular network out of its "
    "domain, and what the blend sees is recorded once (cached beside the data); the "
    "blend then learns the weight of the monocular depth that brings the depth nearest "
    "the truth. Logs the L1 and writes safetensors weights with the command and final "
    "figures.",
    "panogrf train blend --data data/train_lit_wide "
    "--out assets/depth_blend.safetensors --log lab/training/depth_blend.log",
)


@contextmanager
def _training(config: type, args: argparse.Namespace, **fields):
    """The settings ``config`` from ``args`` (checked before anything runs: `UserError`) and
    a function that prints a log line and appends it to ``--log``; torch's threads set."""
    cfg = from_args(config, args, **fields)
    run = from_args(RunOptions, args)
    if run.log is not None:
        refuse_training_inputs(run.log, cfg, "--log")
        if run.log.resolve() == cfg.out.resolve():
            raise UserError(f"--log {run.log}: is the --out weights; log elsewhere")
        if run.log.is_dir():
            raise UserError(f"--log {run.log}: is a folder; the log is a file")
    if getattr(cfg, "init", None) is not None:  # read before the data: minutes may go first
        from panogrf.app.train.loop import read_weights_file

        read_weights_file(cfg.init, "--init")
    if run.threads:
        import torch

        torch.set_num_threads(run.threads)
    log, close = _logger(run.log)
    try:
        yield cfg, log
    finally:
        close()


def _logger(path: Path | None):
    """A function that prints a line and appends it to ``path``, and a closer."""
    log_file = None
    if path:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            log_file = path.open("a", encoding="utf-8")
        except OSError as exc:
            raise UserError(f"--log {path}: cannot write ({exc.strerror or exc})") from None

    def log(line: str) -> None:
        print(line, flush=True)
        if log_file:
            log_file.write(line + "\n")
            log_file.flush()

    return log, (log_file.close if log_file else lambda: None)


def run_depth(args: argparse.Namespace) -> int:
    from panogrf.app.train.depth import train_mono, train_mvs

    with _training(TrainDepthConfig, args) as (cfg, log):
        (train_mono if cfg.stage == "mono" else train_mvs)(cfg, log=log)
    return 0


def run_renderer(args: argparse.Namespace) -> int:
    from panogrf.app.train.renderer import train_renderer
    from panogrf.app.weights.networks import load_depth_estimator
    from panogrf.model.depth_config import DepthMode

    with _training(TrainRendererConfig, args, depth_height=args.height // 2) as (cfg, log):
        if cfg.depth == "shipped":
            train_renderer(cfg, log=log)
        else:
            train_renderer(cfg, load_depth_estimator((DepthMode.FULL,)), log=log)
    return 0


def run_select(args: argparse.Namespace) -> int:
    from panogrf.app.train.select import train_selector
    from panogrf.app.weights.networks import NETWORKS, load_depth_estimator
    from panogrf.model.depth_config import DepthMode

    with _training(TrainSelectConfig, args) as (cfg, log):
        train_selector(cfg, load_depth_estimator(NETWORKS[DepthMode.FULL]), log=log)
    return 0


def run_blend(args: argparse.Namespace) -> int:
    from panogrf.app.train.blend import train_blend
    from panogrf.app.weights.networks import NETWORKS, load_depth_estimator
    from panogrf.model.depth_config import DepthMode

    with _training(TrainBlendConfig, args) as (cfg, log):
        train_blend(cfg, load_depth_estimator(NETWORKS[DepthMode.FULL]), log=log)
    return 0
