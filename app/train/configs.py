"""The settings of the trainings (`panogrf train depth|renderer|select|blend`), each declared
once: a field made with `option` is also the command's option (`panogrf.app.options`). A
setting is checked as it is built (`UserError`, one line naming the option), so a run refuses
bad settings before it loads anything. The weights record the settings (`save_trained`).

This module imports no torch (the command line registers `panogrf train` from it).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from panogrf.app.errors import UserError
from panogrf.app.options import flag_of, option
from panogrf.app.runtime import number, thread_count

#: ``--lr``: a positive, finite learning rate.
LR = number(float, 0.0, 1.0, low_open=True)
#: The renderer's presets (`panogrf.model.render_net.PRESETS`).
RENDERER_PRESETS = ("panogrf", "no_geometry", "tiny", "large")
#: Where the renderer's training takes the sources' depth from (`train_renderer`).
DEPTHS = ("networks", "shipped")


@dataclass(frozen=True)
class RunOptions:
    """How a training runs, besides what it trains (not among the settings the weights record)."""

    threads: int = option(0, "torch threads (default: all)", parse=thread_count)
    """Torch threads (0: torch's default, every core)."""
    log: Path | None = option(None, "also append log lines here")
    """A file the log lines are also appended to."""


@dataclass(frozen=True, kw_only=True)
class TrainRun:
    """What every training has. A training gives ``steps`` its default, and may change
    the others' (`panogrf.app.options`: the option stays the same)."""

    data: Path = option(help="train-split dataset folder")
    """Train-split dataset folder (`panogrf dataset make --split train`, or packs)."""
    out: Path = option(help="output weights (.safetensors)")
    """Where the weights go (safetensors)."""
    steps: int = option(help="optimiser steps (default {default})")
    """Optimiser steps."""
    lr: float = option(1e-3, "initial learning rate", parse=LR)
    """Adam learning rate at the start (cosine decay)."""
    seed: int = option(0, "seed (default {default})")
    """Seed of the initialisation, the batches and the samples."""
    val_scenes: int = 24
    """Scenes of the train split held back for validation (the data's last)."""
    log_every: int = 50
    """Steps between log lines."""
    limit_scenes: int | None = option(None, "load only N scenes")
    """Load only this many scenes (smoke tests)."""

    def __post_init__(self) -> None:
        """Refuse, before any training, an ``out`` the weights could not be written to (issue
        57, T14: the steps trained, then the weights were lost)."""
        from panogrf.app.files.atomic import check_writable

        if self.out.suffix != ".safetensors":
            raise UserError(f"--out must end in .safetensors, got {self.out}")
        if self.limit_scenes is not None and self.limit_scenes < 1:
            raise UserError(f"--limit-scenes must be at least 1, got {self.limit_scenes}")
        refuse_training_inputs(self.out, self, "--out")
        check_writable(self.out)

    def _fractions(self, names: tuple[str, ...], of: str) -> None:
        """Refuse a field of ``names`` outside 0-1 (a fraction of the ``of``)."""
        for name in names:
            value = getattr(self, name)
            if not 0 <= value <= 1:
                flag = flag_of(type(self), name)
                raise UserError(f"{flag} is a fraction of the {of} (0-1), got {value}")


def refuse_training_inputs(path: Path, cfg: TrainRun, option: str) -> None:
    """Refuse an output ``path`` that is the training data (a pack file or the data folder),
    a file of the data folder the training reads (its index, a pack) or the weights it starts
    from (``init``): the run would replace or append to what it reads."""
    from panogrf.app.train.pack import is_pack

    target = path.resolve()
    data = Path(cfg.data).resolve()
    read = target.exists() and (target.suffix != ".safetensors" or is_pack(target))
    if target == data or (data in target.parents and read):
        raise UserError(
            f"{option} {path}: is the training data ({cfg.data}); refusing to "
            "write over it, choose another path"
        )
    init = getattr(cfg, "init", None)
    if init is not None and Path(init).resolve() == target:
        raise UserError(f"{option} {path}: is the --init weights; write the new ones elsewhere")


def _check_device(device: str) -> None:
    """A clear error for a ``--device`` this machine does not have."""
    if device != "cpu":
        import torch

        try:
            torch.empty(1, device=device)
        except (RuntimeError, AssertionError) as exc:
            raise UserError(f"--device {device}: not available here ({exc})") from None


@dataclass(frozen=True, kw_only=True)
class TrainDepthConfig(TrainRun):
    """One training run of a depth network (`panogrf.app.train.depth`)."""

    stage: str = option(choices=("mono", "mvs"), help="which network")
    """"mono" or "mvs"."""
    steps: int = 2500
    batch: int = option(8, "batch size (default {default})")
    """Panoramas (mono) or reference/source pairs (mvs) per step."""
    height: int = option(128, "working height (default {default})")
    """Working resolution (height; width is twice this)."""
    mono_weights: Path | None = option(None, "stage mvs: mono weights", flag="--mono")
    """Stage mvs: the trained monocular network (frozen)."""
    mvs_preset: str = option(
        "full",
        "stage mvs: full (mono-guided) or mvs (N_mono=0, N_uni=64, no mono input)",
        flag="--preset",
        choices=("full", "mvs"),
    )
    """Stage mvs: "full" (mono-guided) or "mvs" (no mono guidance, N_mono = 0, N_uni = 64)."""
    init: Path | None = option(None, "start from these weights")
    """Start from these weights (same network) instead of a random initialisation."""
    augment: bool = option(
        True, "mild exposure jitter only, instead of the real-camera corruptions"
    )
    """Real-camera corruptions (`panogrf.app.train.augment.photometric`) on every view instead
    of the mild exposure / white-balance jitter."""
    mono_noise: float = option(
        0.5,
        "stage mvs, full: fraction of pairs with a corrupted mono prior (default {default})",
    )
    """Stage mvs, mono-guided: fraction of pairs whose monocular depth is corrupted
    (`corrupt_mono`), so the fusion learns to check its prior."""
    mono_shift: float = option(
        0.0,
        "stage mvs, full: fraction of pairs whose mono network sees its input out of its "
        "domain (blended with another panorama), depth and features wrong together (default 0)",
    )
    """Stage mvs, mono-guided: fraction of pairs whose monocular network sees its reference
    out of its domain (`out_of_domain`), so that its depth and its features are wrong
    together, as on real rooms; `corrupt_mono` only makes the depth wrong, and a network can
    tell that from the features it did not touch."""
    mono_heights: float = option(
        0.0,
        "stage mvs, full: fraction of pairs whose mono depth has the ceiling and floor at "
        "wrong heights (the room plausible but for its height; default 0)",
    )
    """Stage mvs, mono-guided: fraction of pairs whose monocular depth has the ceiling and the
    floor at wrong heights (`wrong_heights`, after `corrupt_mono`): plausible but for the
    room's height, and wrong exactly where a blank ceiling gives the cost volume nothing to
    correct it with, as on a real room whose ceiling is higher or lower than the rooms the
    monocular network learned."""
    mono_warp: float = option(
        0.0,
        "stage mvs, full: fraction of pairs whose mono network sees the reference as a "
        "room of other heights, depth and features wrong together (default 0)",
    )
    """Stage mvs, mono-guided: fraction of pairs whose monocular network sees the reference as
    a room of other heights (`seen_warped`, `room_factors`: log factors in +-0.3 above and
    below the camera): a plausible room of the wrong height, depth and features wrong
    together."""
    mono_features_shift: float = option(
        0.0,
        "stage mvs, full: fraction of pairs whose mono features come from its input seen "
        "out of its domain while the mono depth stays its own (default 0)",
    )
    """Stage mvs, mono-guided: fraction of pairs whose monocular *features* come from the
    reference seen out of its domain (`out_of_domain`) while the monocular depth stays the one
    of the reference as it is (then corrupted as the other options say). Measured
    (`lab/analysis.md`): the guided network reads the features more than its prior: given the
    true depth as the prior, it was still behind the unguided network on the real triplet, led
    by the features of a real image (`benchmarks/depth_fusion.py --mono-true`)."""
    trunk: int = option(
        0,
        "frozen ImageNet AlexNet convolutions feeding the network: 0-3 for mono, 0-2 for "
        "mvs (default 0: none)",
    )
    """Frozen pretrained AlexNet convolutions feeding the network (`MonoDepthConfig.trunk`,
    `MVSConfig.trunk`), filled from the bundled LPIPS weights."""
    device: str = option(
        "cpu",
        "torch device to train on, e.g. cuda (default cpu); the batches are drawn and "
        "corrupted on the CPU as before, so a run is the same run on any device",
    )
    """The torch device the network trains on (stage mvs: the frozen monocular network runs
    there too). Batches are drawn and corrupted on the CPU with the same generator, so the
    data a run sees does not depend on it; the held-back figures are measured on the CPU."""
    extra: dict = field(default_factory=dict)
    """Free-form notes stored with the weights."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.steps < 1 or self.batch < 1:
            raise UserError("--steps and --batch must be at least 1")
        if self.height < 32 or self.height % 32:
            raise UserError(f"--height must be a positive multiple of 32, got {self.height}")
        top = 3 if self.stage == "mono" else 2
        if not 0 <= self.trunk <= top:
            raise UserError(f"--trunk must be 0-{top} for stage {self.stage}, got {self.trunk}")
        mono = ("mono_noise", "mono_shift", "mono_features_shift", "mono_heights", "mono_warp")
        self._fractions(mono, "pairs")
        if self.stage == "mvs" and self.mvs_preset == "full" and self.mono_weights is None:
            raise UserError("--stage mvs --preset full needs --mono PATH to trained mono weights")
        if self.mono_weights is not None and not self.mono_weights.is_file():
            why = "is not a file" if self.mono_weights.exists() else "not found"
            raise UserError(f"--mono {self.mono_weights}: {why}")
        _check_device(self.device)


@dataclass(frozen=True, kw_only=True)
class TrainRendererConfig(TrainRun):
    """One training run of the renderer (`panogrf.app.train.renderer`)."""

    preset: str = option(
        "panogrf",
        "panogrf (default); experiments, whose weights go to lab/weights: no_geometry "
        "(no depth-derived visibility), the model-size ladder tiny (half the widths) or large "
        "(one and a half times)",
        choices=RENDERER_PRESETS,
    )
    """Renderer preset: "panogrf", the ablation "no_geometry", or "tiny" / "large"."""
    steps: int = 2000
    scenes_per_step: int = option(2, "scenes per step (default {default})", flag="--scenes")
    """Scenes (target views) per step."""
    rays: int = option(256, "rays per scene (default {default})")
    """Rays per scene per step."""
    height: int = option(256, "panorama height (default {default}; depth at half)")
    """Height of the panoramas (and of the target rays)."""
    depth_height: int = 128
    """Working height of the depth networks (the command: half ``height``)."""
    coarse: int = 32
    """Stratified coarse samples per ray while training."""
    fine: int = 32
    """Importance samples per ray while training."""
    init: Path | None = option(None, "start from these weights")
    """Start from these weights (same preset) instead of a random initialisation."""
    surface_loss: bool = option(True, "train only the composited colours (not the surface colour)")
    """Also train the depth-guided pass's surface colour (`Sampling.surface`): density that
    peaks at the surface and blend weights that pick the sources that see it."""
    depth: str = option(
        "networks",
        "the sources' depth: networks (the depth networks alone, every pair of views; "
        "default) or shipped (what the app renders with: the fusion and the per-scene "
        "refinement, a few seconds per scene, so the outer pair only)",
        choices=DEPTHS,
    )
    """The sources' depth: "networks" (the depth networks alone, every ordered pair) or
    "shipped" (what the app renders with, outer pair only; `shipped_depths`)."""
    device: str = option(
        "cpu",
        "torch device to train on, e.g. cuda (default cpu); the samples and rays are "
        "drawn on the CPU as before, so a run draws the same samples on any device",
    )
    """The torch device the renderer trains on (and, with ``depth="networks"``, where the
    depth networks estimate the training pairs' depth)."""
    extra: dict = field(default_factory=dict)
    """Free-form notes stored with the weights."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.steps < 1 or self.scenes_per_step < 1 or self.rays < 1:
            raise UserError("--steps, --scenes and --rays must be at least 1")
        if self.height < 64 or self.height % 64:
            raise UserError(f"--height must be a positive multiple of 64, got {self.height}")
        _check_device(self.device)


@dataclass(frozen=True, kw_only=True)
class FusionRecordingConfig(TrainRun):
    """What the trainings that record mode full's fusion share (`fusion_runs`)."""

    scenes: int = option(240, "training scenes recorded (default {default})")
    """Training scenes sampled (seeded) from the data, besides the held-back ones."""
    steps: int = 1500
    batch: int = option(8, "views per step (default {default})")
    """Views per step."""
    lr: float = 2e-3
    shift: float = option(
        0.3,
        "fraction of the scenes whose monocular network sees its input out of its "
        "domain (default {default})",
        flag="--mono-shift",
    )
    """Fraction of the scenes whose monocular network sees its input out of its domain."""
    photometric: float = 0.5
    """Fraction of the scenes whose views are put through the camera corruptions."""
    heights: float = option(
        0.0,
        "fraction of the scenes whose monocular depth puts the ceiling and the floor at "
        "wrong heights (default 0)",
        flag="--mono-heights",
    )
    """Fraction of the scenes whose monocular depth puts the ceiling and the floor at wrong
    heights (`wrong_heights`), drawn independently of ``shift``."""
    heights_shared: bool = option(
        False,
        "those scenes' wrong heights the same in both views (one wrong room per scene, "
        "as a real capture's views read it) instead of drawn per view",
        flag="--mono-heights-shared",
    )
    """Those scenes' wrong heights drawn once per scene, the same in both views
    (`mono_wrong_heights` ``shared``), instead of once per view."""
    features_shift: float = option(
        0.0,
        "fraction of the scenes not under --mono-shift whose monocular network gives "
        "the features of its input seen out of its domain with the depth of the input as it "
        "is (default 0)",
        flag="--mono-features-shift",
    )
    """Fraction of the scenes not under ``shift`` whose monocular network gives the features
    of its input seen out of its domain and the depth of the input as it is
    (`mono_out_of_domain` ``features_only``: on a real capture the mono-guided
    network is led astray by these features more than by the depth)."""
    height: int = option(
        256, "rows the panoramas are loaded at (default {default}: the fusion's own)"
    )
    """Rows the panoramas are loaded at (the sweep's resolution)."""
    log_every: int = 100

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.steps < 1 or self.batch < 1 or self.scenes < 1:
            raise UserError("--steps, --batch and --scenes must be at least 1")
        self._fractions(("shift", "heights"), "scenes")
        if self.heights_shared and not self.heights:
            raise UserError("--mono-heights-shared needs --mono-heights above 0")
        self._fractions(("features_shift",), "scenes")
        if self.height < 32 or self.height % 32:
            raise UserError(f"--height must be a multiple of 32, got {self.height}")

    @property
    def extra_key(self) -> list:
        """What a recording's cache key adds for ``heights_shared`` and ``features_shift``
        (nothing without them, so the recordings made before them keep their keys)."""
        key: list = ["shared"] if self.heights and self.heights_shared else []
        return key + (["features", self.features_shift] if self.features_shift else [])


@dataclass(frozen=True, kw_only=True)
class TrainSelectConfig(FusionRecordingConfig):
    """One training run of the selector (`panogrf.app.train.select`)."""

    cap: float = 0.5
    """Largest weight of a pixel (metres by which one search end is nearer the truth)."""
    context: bool = option(True, "no scene-wide summary in the selector (local features only)")
    """The selector sees a scene-wide summary of its features (`SelectorConfig.context`)."""
    consistency: bool = option(
        True, "the selector does not see the cross-view consistency of the search ends"
    )
    """The selector sees the cross-view consistency of the search ends
    (`SelectorConfig.consistency`)."""


@dataclass(frozen=True, kw_only=True)
class TrainBlendConfig(FusionRecordingConfig):
    """One training run of the blend (`panogrf.app.train.blend`; the fields are the
    selector's recording's)."""
