"""`panogrf train depth`: reproduce the shipped depth weights from the synthetic train split."""

from __future__ import annotations

import argparse
from pathlib import Path

from panogrf.app.errors import UserError
from panogrf.app.runtime import number, thread_count

#: ``--lr``: a positive, finite learning rate.
LR = number(float, 0.0, 1.0, low_open=True)


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "train",
        help="train the networks on synthetic data",
        description="Train the project's networks on the synthetic train split (CPU).",
    )
    sub = parser.add_subparsers(dest="train_command", metavar="SUBCOMMAND", required=True)
    depth = sub.add_parser(
        "depth",
        help="train the 360-degree mono depth network or the mono-guided MVS",
        description=(
            "Train the monocular depth network (--stage mono) or the mono-guided 360-degree "
            "MVS with the monocular network frozen (--stage mvs). Logs the loss curve and "
            "writes safetensors weights with the command and final figures in the metadata."
        ),
        epilog=(
            "example: panogrf train depth --data data/train --stage mono "
            "--out assets/depth_mono.safetensors --log logs/mono.log"
        ),
    )
    depth.add_argument("--data", type=Path, required=True, help="train-split dataset folder")
    depth.add_argument("--stage", choices=("mono", "mvs"), required=True, help="which network")
    depth.add_argument("--out", type=Path, required=True, help="output weights (.safetensors)")
    depth.add_argument("--steps", type=int, default=2500, help="optimiser steps (default 2500)")
    depth.add_argument("--batch", type=int, default=8, help="batch size (default 8)")
    depth.add_argument("--lr", type=LR, default=1e-3, help="initial learning rate")
    depth.add_argument("--height", type=int, default=128, help="working height (default 128)")
    depth.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    depth.add_argument("--mono", type=Path, default=None, help="stage mvs: mono weights")
    depth.add_argument(
        "--preset",
        choices=("full", "mvs"),
        default="full",
        help="stage mvs: full (mono-guided) or mvs (N_mono=0, N_uni=64, no mono input)",
    )
    depth.add_argument(
        "--threads", type=thread_count, default=0, help="torch threads (default: all)"
    )
    depth.add_argument("--log", type=Path, default=None, help="also append log lines here")
    depth.add_argument("--limit-scenes", type=int, default=None, help="load only N scenes")
    depth.add_argument("--init", type=Path, default=None, help="start from these weights")
    depth.add_argument(
        "--no-augment",
        action="store_true",
        help="mild exposure jitter only, instead of the real-camera corruptions",
    )
    depth.add_argument(
        "--mono-noise",
        type=float,
        default=0.5,
        help="stage mvs, full: fraction of pairs with a corrupted mono prior (default 0.5)",
    )
    depth.add_argument(
        "--mono-shift",
        type=float,
        default=0.0,
        help="stage mvs, full: fraction of pairs whose mono network sees its input out of its "
        "domain (blended with another panorama), depth and features wrong together (default 0)",
    )
    depth.add_argument(
        "--mono-features-shift",
        type=float,
        default=0.0,
        help="stage mvs, full: fraction of pairs whose mono features come from its input seen "
        "out of its domain while the mono depth stays its own (default 0)",
    )
    depth.add_argument(
        "--mono-heights",
        type=float,
        default=0.0,
        help="stage mvs, full: fraction of pairs whose mono depth has the ceiling and floor at "
        "wrong heights (the room plausible but for its height; default 0)",
    )
    depth.add_argument(
        "--mono-warp",
        type=float,
        default=0.0,
        help="stage mvs, full: fraction of pairs whose mono network sees the reference as a "
        "room of other heights, depth and features wrong together (default 0)",
    )
    depth.add_argument(
        "--trunk",
        type=int,
        default=0,
        help="frozen ImageNet AlexNet convolutions feeding the network: 0-3 for mono, 0-2 for "
        "mvs (default 0: none)",
    )
    depth.add_argument(
        "--device",
        default="cpu",
        help="torch device to train on, e.g. cuda (default cpu); the batches are drawn and "
        "corrupted on the CPU as before, so a run is the same run on any device",
    )
    depth.set_defaults(func=run_depth)

    renderer = sub.add_parser(
        "renderer",
        help="train the spherical radiance field renderer (depth networks frozen)",
        description=(
            "Train the generalizable spherical radiance field renderer on the synthetic train "
            "split with the shipped depth networks frozen (their estimates for every training "
            "pair are computed once and cached beside the data). Logs the loss curve and "
            "writes safetensors weights with the command and final figures in the metadata."
        ),
        epilog=(
            "example: panogrf train renderer --data data/train "
            "--out assets/renderer_panogrf.safetensors --log lab/training/renderer.log"
        ),
    )
    renderer.add_argument("--data", type=Path, required=True, help="train-split dataset folder")
    renderer.add_argument("--out", type=Path, required=True, help="output weights (.safetensors)")
    renderer.add_argument(
        "--preset",
        choices=("panogrf", "no_geometry", "tiny", "large"),
        default="panogrf",
        help="panogrf (default); experiments, whose weights go to lab/weights: no_geometry "
        "(no depth-derived visibility), the model-size ladder tiny (half the widths) or large "
        "(one and a half times)",
    )
    renderer.add_argument("--steps", type=int, default=2000, help="optimiser steps (default 2000)")
    renderer.add_argument("--scenes", type=int, default=2, help="scenes per step (default 2)")
    renderer.add_argument("--rays", type=int, default=256, help="rays per scene (default 256)")
    renderer.add_argument("--lr", type=LR, default=1e-3, help="initial learning rate")
    renderer.add_argument(
        "--height", type=int, default=256, help="panorama height (default 256; depth at half)"
    )
    renderer.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    renderer.add_argument(
        "--threads", type=thread_count, default=0, help="torch threads (default: all)"
    )
    renderer.add_argument("--log", type=Path, default=None, help="also append log lines here")
    renderer.add_argument("--limit-scenes", type=int, default=None, help="load only N scenes")
    renderer.add_argument("--init", type=Path, default=None, help="start from these weights")
    renderer.add_argument(
        "--depth",
        choices=("networks", "shipped"),
        default="networks",
        help="the sources' depth: networks (the depth networks alone, every pair of views; "
        "default) or shipped (what the app renders with: the fusion and the per-scene "
        "refinement, a few seconds per scene, so the outer pair only)",
    )
    renderer.add_argument(
        "--device",
        default="cpu",
        help="torch device to train on, e.g. cuda (default cpu); the samples and rays are "
        "drawn on the CPU as before, so a run draws the same samples on any device",
    )
    renderer.add_argument(
        "--no-surface-loss",
        action="store_true",
        help="train only the composited colours (not the surface colour)",
    )
    renderer.set_defaults(func=run_renderer)

    select = sub.add_parser(
        "select",
        help="train the fusion's hypothesis selector (depth networks frozen)",
        description=(
            "Train the learned choice between the mono-guided and the unguided MVS depth in "
            "the depth fusion (`panogrf.model.select`). Mode full runs on a seeded sample of "
            "the training scenes as at preparation, some with the monocular network out of "
            "its domain, and what the fusion sees is recorded once (cached beside the data); "
            "the selector then learns which hypothesis ends nearer the truth. Logs the loss "
            "and writes safetensors weights with the command and final figures."
        ),
        epilog=(
            "example: panogrf train select --data data/train_lit "
            "--out assets/depth_select.safetensors --log lab/training/depth_select.log"
        ),
    )
    _fusion_recording_args(select)
    select.add_argument(
        "--no-context",
        action="store_true",
        help="no scene-wide summary in the selector (local features only)",
    )
    select.add_argument(
        "--no-consistency",
        action="store_true",
        help="the selector does not see the cross-view consistency of the search ends",
    )
    _run_args(select)
    select.set_defaults(func=run_select)

    blend = sub.add_parser(
        "blend",
        help="train the blend of the fused depth with the monocular depth (all else frozen)",
        description=(
            "Train the per-pixel blend of mode full's fused depth with the monocular depth "
            "(`panogrf.model.blend`). Mode full runs on a seeded sample of the training scenes "
            "as at preparation (selector included), some with the monocular network out of its "
            "domain, and what the blend sees is recorded once (cached beside the data); the "
            "blend then learns the weight of the monocular depth that brings the depth nearest "
            "the truth. Logs the L1 and writes safetensors weights with the command and final "
            "figures."
        ),
        epilog=(
            "example: panogrf train blend --data data/train_lit_wide "
            "--out assets/depth_blend.safetensors --log lab/training/depth_blend.log"
        ),
    )
    _fusion_recording_args(blend)
    _run_args(blend)
    blend.set_defaults(func=run_blend)


def _fusion_recording_args(parser: argparse.ArgumentParser) -> None:
    """Arguments of the trainings that record mode full's fusion (select, blend)."""
    parser.add_argument("--data", type=Path, required=True, help="train-split dataset folder")
    parser.add_argument("--out", type=Path, required=True, help="output weights (.safetensors)")
    parser.add_argument(
        "--scenes", type=int, default=240, help="training scenes recorded (default 240)"
    )
    parser.add_argument("--steps", type=int, default=1500, help="optimiser steps (default 1500)")
    parser.add_argument("--batch", type=int, default=8, help="views per step (default 8)")
    parser.add_argument("--lr", type=LR, default=2e-3, help="initial learning rate")
    parser.add_argument(
        "--mono-shift",
        type=float,
        default=0.3,
        help="fraction of the scenes whose monocular network sees its input out of its "
        "domain (default 0.3)",
    )
    parser.add_argument(
        "--mono-heights",
        type=float,
        default=0.0,
        help="fraction of the scenes whose monocular depth puts the ceiling and the floor at "
        "wrong heights (default 0)",
    )
    parser.add_argument(
        "--mono-heights-shared",
        action="store_true",
        help="those scenes' wrong heights the same in both views (one wrong room per scene, "
        "as a real capture's views read it) instead of drawn per view",
    )
    parser.add_argument(
        "--mono-features-shift",
        type=float,
        default=0.0,
        help="fraction of the scenes not under --mono-shift whose monocular network gives "
        "the features of its input seen out of its domain with the depth of the input as it "
        "is (default 0)",
    )
    parser.add_argument(
        "--height",
        type=int,
        default=256,
        help="rows the panoramas are loaded at (default 256: the fusion's own)",
    )


def _run_args(parser: argparse.ArgumentParser) -> None:
    """Seed, threads, log and scene limit of the fusion's trainings."""
    parser.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    parser.add_argument(
        "--threads", type=thread_count, default=0, help="torch threads (default: all)"
    )
    parser.add_argument("--log", type=Path, default=None, help="also append log lines here")
    parser.add_argument("--limit-scenes", type=int, default=None, help="load only N scenes")


def _logger(path: Path | None):
    """A function that prints a line and appends it to ``path``, and a closer."""
    log_file = None
    if path:
        path.parent.mkdir(parents=True, exist_ok=True)
        log_file = path.open("a", encoding="utf-8")

    def log(line: str) -> None:
        print(line, flush=True)
        if log_file:
            log_file.write(line + "\n")
            log_file.flush()

    return log, (log_file.close if log_file else lambda: None)


def _check_device(device: str) -> None:
    """A clear error for a ``--device`` this machine does not have."""
    import torch

    if device != "cpu":
        try:
            torch.empty(1, device=device)
        except (RuntimeError, AssertionError) as exc:
            raise UserError(f"--device {device}: not available here ({exc})") from None


def run_renderer(args: argparse.Namespace) -> int:
    import torch

    from panogrf.app.train.renderer import TrainRendererConfig, train_renderer
    from panogrf.app.weights.networks import load_depth_estimator

    _check_weights_out(args.out)
    if args.steps < 1 or args.scenes < 1 or args.rays < 1:
        raise UserError("--steps, --scenes and --rays must be at least 1")
    if args.height % 64:
        raise UserError(f"--height must be a multiple of 64, got {args.height}")
    _check_device(args.device)
    if args.threads:
        torch.set_num_threads(args.threads)
    log, close = _logger(args.log)
    cfg = TrainRendererConfig(
        data=args.data,
        out=args.out,
        preset=args.preset,
        steps=args.steps,
        scenes_per_step=args.scenes,
        rays=args.rays,
        lr=args.lr,
        height=args.height,
        depth_height=args.height // 2,
        seed=args.seed,
        limit_scenes=args.limit_scenes,
        init=args.init,
        surface_loss=not args.no_surface_loss,
        depth=args.depth,
        device=args.device,
    )
    try:
        if args.depth == "shipped":
            train_renderer(cfg, log=log)
        else:
            train_renderer(cfg, load_depth_estimator(("full",)), log=log)
    finally:
        close()
    return 0


def run_depth(args: argparse.Namespace) -> int:
    import torch

    from panogrf.app.train.depth import TrainDepthConfig, train_mono, train_mvs

    _check_weights_out(args.out)
    if args.steps < 1 or args.batch < 1:
        raise UserError("--steps and --batch must be at least 1")
    if args.height % 32:
        raise UserError(f"--height must be a multiple of 32, got {args.height}")
    top = 3 if args.stage == "mono" else 2
    if not 0 <= args.trunk <= top:
        raise UserError(f"--trunk must be 0-{top} for stage {args.stage}, got {args.trunk}")
    fractions = (
        ("--mono-noise", args.mono_noise),
        ("--mono-shift", args.mono_shift),
        ("--mono-features-shift", args.mono_features_shift),
        ("--mono-heights", args.mono_heights),
        ("--mono-warp", args.mono_warp),
    )
    for flag, value in fractions:
        if not 0 <= value <= 1:
            raise UserError(f"{flag} is a fraction of the pairs (0-1), got {value}")
    if (
        args.stage == "mvs"
        and args.preset == "full"
        and (args.mono is None or not args.mono.exists())
    ):
        raise UserError("--stage mvs --preset full needs --mono PATH to trained mono weights")
    _check_device(args.device)
    if args.threads:
        torch.set_num_threads(args.threads)
    log, close = _logger(args.log)
    cfg = TrainDepthConfig(
        data=args.data,
        stage=args.stage,
        out=args.out,
        steps=args.steps,
        batch=args.batch,
        lr=args.lr,
        height=args.height,
        seed=args.seed,
        mono_weights=args.mono,
        mvs_preset=args.preset,
        limit_scenes=args.limit_scenes,
        init=args.init,
        augment=not args.no_augment,
        mono_noise=args.mono_noise,
        mono_shift=args.mono_shift,
        mono_features_shift=args.mono_features_shift,
        mono_heights=args.mono_heights,
        mono_warp=args.mono_warp,
        trunk=args.trunk,
        device=args.device,
    )
    try:
        (train_mono if args.stage == "mono" else train_mvs)(cfg, log=log)
    finally:
        close()
    return 0


def _check_weights_out(out: Path) -> None:
    """Refuse, before any training, a ``--out`` the weights could not be written to (issue
    57, T14: the steps trained, then the weights were lost)."""
    from panogrf.app.files.atomic import check_writable

    if out.suffix != ".safetensors":
        raise UserError(f"--out must end in .safetensors, got {out}")
    check_writable(out)


def _check_fusion_args(args: argparse.Namespace) -> None:
    """Refuse the fusion trainings' arguments out of range (`_fusion_recording_args`)."""
    import torch

    _check_weights_out(args.out)
    if args.steps < 1 or args.batch < 1 or args.scenes < 1:
        raise UserError("--steps, --batch and --scenes must be at least 1")
    if not 0 <= args.mono_shift <= 1:
        raise UserError(f"--mono-shift is a fraction of the scenes (0-1), got {args.mono_shift}")
    if not 0 <= args.mono_heights <= 1:
        raise UserError(
            f"--mono-heights is a fraction of the scenes (0-1), got {args.mono_heights}"
        )
    if args.mono_heights_shared and not args.mono_heights:
        raise UserError("--mono-heights-shared needs --mono-heights above 0")
    if not 0 <= args.mono_features_shift <= 1:
        raise UserError(
            "--mono-features-shift is a fraction of the scenes (0-1), "
            f"got {args.mono_features_shift}"
        )
    if args.height < 32 or args.height % 32:
        raise UserError(f"--height must be a multiple of 32, got {args.height}")
    if args.threads:
        torch.set_num_threads(args.threads)


def _fusion_config(args: argparse.Namespace) -> dict:
    """The fields of `FusionRecordingConfig` from `_fusion_recording_args` and `_run_args`."""
    return dict(
        data=args.data,
        out=args.out,
        scenes=args.scenes,
        steps=args.steps,
        batch=args.batch,
        lr=args.lr,
        shift=args.mono_shift,
        heights=args.mono_heights,
        heights_shared=args.mono_heights_shared,
        features_shift=args.mono_features_shift,
        height=args.height,
        seed=args.seed,
        limit_scenes=args.limit_scenes,
    )


def run_select(args: argparse.Namespace) -> int:
    from panogrf.app.train.select import TrainSelectConfig, train_selector
    from panogrf.app.weights.networks import load_depth_estimator

    _check_fusion_args(args)
    log, close = _logger(args.log)
    cfg = TrainSelectConfig(
        **_fusion_config(args),
        context=not args.no_context,
        consistency=not args.no_consistency,
    )
    try:
        train_selector(cfg, load_depth_estimator(("full", "mvs")), log=log)
    finally:
        close()
    return 0


def run_blend(args: argparse.Namespace) -> int:
    from panogrf.app.train.blend import TrainBlendConfig, train_blend
    from panogrf.app.weights.networks import load_depth_estimator

    _check_fusion_args(args)
    log, close = _logger(args.log)
    cfg = TrainBlendConfig(**_fusion_config(args))
    try:
        train_blend(cfg, load_depth_estimator(("full", "mvs")), log=log)
    finally:
        close()
    return 0
