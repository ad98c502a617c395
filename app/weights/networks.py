"""Loading the shipped networks (safetensors in `assets/`): depth estimator and renderer.

``PANOGRF_WEIGHTS=DIR`` loads the weights files from DIR instead (the same file names), e.g.
to compare freshly trained networks with the shipped ones before replacing them.
"""

from __future__ import annotations

import json
import os
from dataclasses import replace
from functools import lru_cache
from pathlib import Path

import torch
from safetensors import SafetensorError, safe_open
from safetensors.torch import load_file

from panogrf.app.errors import UserError
from panogrf.assets import path as asset_path
from panogrf.model.blend import BlendConfig, DepthBlend
from panogrf.model.depth import DepthEstimator, DepthMode
from panogrf.model.mono import MonoDepthConfig, MonoDepthNet
from panogrf.model.mvs import PRESETS, MVSConfig, MVSNet
from panogrf.model.render_net import PRESETS as RENDERER_PRESETS
from panogrf.model.render_net import RendererNet, RendererPreset
from panogrf.model.select import HypothesisSelector, SelectorConfig

#: The depth networks' weights files, by the mode that runs each as its own: the monocular
#: network (which every mode runs first), the mono-guided and the unguided MVS network.
WEIGHTS = {
    DepthMode.MONO: "depth_mono.safetensors",
    DepthMode.FULL: "depth_mvs_full.safetensors",
    DepthMode.MVS: "depth_mvs_only.safetensors",
}

#: The fusion's learned choice between the mono-guided and the unguided depth (mode full).
SELECTOR = "depth_select.safetensors"

#: The learned blend of the fused depth with the monocular depth (mode full), used where the
#: file is there (`panogrf.model.blend`; `panogrf train blend`).
BLEND = "depth_blend.safetensors"


#: The MVS networks each depth mode runs (by the mode whose own each is, as `WEIGHTS`): mode
#: full fuses the mono-guided network's depth with the unguided one's
#: (`panogrf.model.depth.DepthEstimator.fuse`).
NETWORKS: dict[DepthMode, tuple[DepthMode, ...]] = {
    DepthMode.MONO: (),
    DepthMode.MVS: (DepthMode.MVS,),
    DepthMode.FULL: (DepthMode.FULL, DepthMode.MVS),
}

#: The shipped renderer. The ablations' weights (`RENDERER_PRESETS` no_geometry, tiny, large)
#: are experiments kept in the repository's `lab/weights`, read as
#: ``renderer_<preset>.safetensors`` from ``$PANOGRF_WEIGHTS`` (`lab/ablations.py`).
RENDERER_WEIGHTS = {RendererPreset.PANOGRF: "renderer_panogrf.safetensors"}


# Config fields added after some shipped weights were trained, with the value those weights
# implicitly have.
ADDED_DEFAULTS = {"trunk": 0, "context": False, "consistency": False}


def weights_path(name: str) -> Path:
    """Where the weights file ``name`` is read from: ``$PANOGRF_WEIGHTS/name`` or the asset."""
    folder = os.environ.get("PANOGRF_WEIGHTS")
    return Path(folder) / name if folder else asset_path(name)


def _regular(path: Path) -> None:
    """Refuse a weights path that exists but is no regular file (a pipe would block the read
    for good, a folder says nothing useful)."""
    if path.exists() and not path.is_file():
        raise UserError(
            f"{path}: not a regular file (a pipe, device or folder): put the weights file there"
        )


def _metadata(path: Path) -> dict:
    _regular(path)
    try:
        with safe_open(str(path), framework="pt") as f:
            return f.metadata() or {}
    except (SafetensorError, OSError, ValueError) as exc:
        raise UserError(f"{path}: {_unreadable(exc, path)}") from None


def _unreadable(exc: Exception, path: Path) -> str:
    return f"not a complete weights file ({type(exc).__name__}): {_restore_advice(path)}"


def _restore_advice(path: Path) -> str:
    """What to do about a weights file that is missing or wrong: where ``$PANOGRF_WEIGHTS``
    chose it, that folder is named (a retraining is not the fix); else retrain."""
    folder = os.environ.get("PANOGRF_WEIGHTS")
    if folder and Path(path).parent == Path(folder):
        state = (
            "a folder without this file"
            if Path(folder).is_dir()
            else ("not a folder" if Path(folder).exists() else "no such folder")
        )
        return (
            f"$PANOGRF_WEIGHTS is {folder} ({state}): put the weights files there, or unset it "
            "to use the shipped ones"
        )
    return "restore the file, or reproduce it with `panogrf train` (see docs/weights.md)"


def read_weights(path: Path) -> dict[str, torch.Tensor]:
    """The tensors of the weights file ``path``, checked: there, readable, complete and finite
    (NaN or infinite weights give NaN-free but meaningless outputs: refused); a `UserError`
    naming the file otherwise."""
    if not path.exists():
        raise UserError(f"missing weights {path}: {_restore_advice(path)}")
    _regular(path)
    try:
        tensors = load_file(str(path))
    except (SafetensorError, OSError, ValueError, RuntimeError) as exc:
        raise UserError(f"{path}: {_unreadable(exc, path)}") from None
    bad = [k for k, t in tensors.items() if t.is_floating_point() and not bool(t.isfinite().all())]
    if bad:
        more = f" and {len(bad) - 1} more" if len(bad) > 1 else ""
        raise UserError(
            f"{path}: non-finite values (NaN or inf) in {bad[0]}{more}: {_restore_advice(path)}"
        )
    return tensors


_CHECKED: set[tuple[str, int, int]] = set()  # files found sound: (path, mtime, size)


def check_weights(paths: list[Path]) -> None:
    """Every file of ``paths`` checked as `read_weights` does, before any work starts (each
    file once per process while it is unchanged)."""
    for path in paths:
        stat = path.stat() if path.exists() else None
        key = (str(path), stat.st_mtime_ns, stat.st_size) if stat else None
        if key in _CHECKED:
            continue
        read_weights(path)
        _CHECKED.add(key)


def trunk_prefixes(module: torch.nn.Module) -> list[str]:
    """State-dict prefixes (``"trunk."``) of the frozen ImageNet trunks inside ``module``: their
    weights are the bundled LPIPS AlexNet's, never trained, so weights files leave them out."""
    from panogrf.model.mono import PretrainedTrunk

    return [f"{n}." for n, m in module.named_modules() if isinstance(m, PretrainedTrunk)]


def trunk_tensors(module: torch.nn.Module) -> dict[str, torch.Tensor]:
    """The state of every frozen trunk of ``module`` from the bundled LPIPS AlexNet
    (``convs.{i}.*``, `panogrf.app.weights.lpips.ASSET_NAME`, checked as `read_weights` does)."""
    from panogrf.app.weights.lpips import ASSET_NAME

    prefixes = trunk_prefixes(module)
    if not prefixes:
        return {}
    alex = read_weights(asset_path(ASSET_NAME))
    out = {}
    for key, t in module.state_dict().items():
        prefix = next((p for p in prefixes if key.startswith(p)), None)
        if prefix is not None:
            out[key] = alex[key[len(prefix) :]].to(t.dtype)
    return out


def _load(module: torch.nn.Module, path: Path, expected_config: dict) -> None:
    tensors = read_weights(path)
    tensors = {**trunk_tensors(module), **tensors}  # older files carry the trunk: theirs is used
    stored = json.loads(_metadata(path).get("config", "{}"))
    # Tuples become lists in JSON; compare as JSON. A field added to a config after the weights
    # were trained is absent from their metadata: it matches when the code has it at its default.
    expected = json.loads(json.dumps(expected_config))
    stored = {**{k: v for k, v in ADDED_DEFAULTS.items() if k in expected}, **stored}
    if stored and expected != stored:
        differ = sorted(k for k in {*stored, *expected} if stored.get(k) != expected.get(k))
        raise UserError(
            f"{path}: not the weights of this network (its settings differ in "
            f"{', '.join(differ[:4])}{' and more' if len(differ) > 4 else ''}); "
            + _restore_advice(path)
        )
    module.load_state_dict(tensors)
    module.eval().requires_grad_(False)


def load_mono_weights(path: Path) -> MonoDepthNet:
    """The monocular network in ``path``, built as it was trained (with or without the
    pretrained trunk), frozen, in eval mode."""
    from dataclasses import asdict

    stored = json.loads(_metadata(path).get("config", "{}")) if path.exists() else {}
    try:
        mono = MonoDepthNet(MonoDepthConfig.from_dict(stored))
    except (TypeError, ValueError) as exc:
        raise UserError(f"{path}: unknown monocular network config {stored}: {exc}") from None
    _load(mono, path, asdict(mono.config))
    return mono


def _stored_mvs_config(path: Path, mode: DepthMode) -> MVSConfig:
    """The preset of ``mode`` with the trunk the weights were trained with (the rest must be
    the preset: a file of another mode is refused by the config check)."""
    stored = json.loads(_metadata(path).get("config", "{}")) if path.exists() else {}
    trunk = stored.get("trunk", 0)
    if not isinstance(trunk, int) or not 0 <= trunk <= 2:
        raise UserError(f"{path}: unknown MVS trunk {trunk!r}")
    return replace(PRESETS[mode], trunk=trunk)


def _load_fusion_part(module_class, config_class, path: Path, what: str):
    """A small network of the fusion (``module_class(config_class(**stored config))``) in
    ``path``, frozen, in eval mode."""
    from dataclasses import asdict

    stored = json.loads(_metadata(path).get("config", "{}")) if path.exists() else {}
    try:
        module = module_class(config_class(**stored))
    except TypeError as exc:
        raise UserError(f"{path}: unknown {what} config {stored}: {exc}") from None
    _load(module, path, asdict(module.config))
    return module


def load_selector(path: Path) -> HypothesisSelector:
    """The fusion's hypothesis selector in ``path``, frozen, in eval mode."""
    return _load_fusion_part(HypothesisSelector, SelectorConfig, path, "selector")


def load_blend(path: Path) -> DepthBlend:
    """The depth blend in ``path``, frozen, in eval mode."""
    return _load_fusion_part(DepthBlend, BlendConfig, path, "blend")


@lru_cache(maxsize=4)
def load_depth_estimator(
    modes: tuple[DepthMode, ...] = (DepthMode.FULL, DepthMode.MVS), device: str = "cpu"
) -> DepthEstimator:
    """The depth estimator with the monocular network and the MVS networks of ``modes`` (with
    both full and mvs, also the fusion's hypothesis selector, and its blend with the
    monocular depth where that file is there)."""
    from dataclasses import asdict

    mono = load_mono_weights(weights_path(WEIGHTS[DepthMode.MONO]))
    mvs = {}
    for mode in map(DepthMode, modes):
        path = weights_path(WEIGHTS[mode])
        config = _stored_mvs_config(path, mode)
        net = MVSNet(config)
        _load(net, path, asdict(net.config))
        mvs[mode] = net
    files = [weights_path(WEIGHTS[DepthMode.MONO]), *(weights_path(WEIGHTS[m]) for m in modes)]
    selector = blend = None
    if _fuses(modes):
        selector = load_selector(weights_path(SELECTOR))
        files.append(weights_path(SELECTOR))
        if weights_path(BLEND).exists():
            blend = load_blend(weights_path(BLEND))
            files.append(weights_path(BLEND))
    # Where its networks came from: what a cached estimate of it is keyed by
    # (`panogrf.app.scene.cache.estimate_key`).
    estimator = DepthEstimator(mono, mvs, selector=selector, blend=blend, weight_files=files)
    return estimator.to(device).eval()


def _fuses(networks) -> bool:
    """The mono-guided and the unguided MVS networks are both loaded: mode full fuses their
    depth, with the selector choosing."""
    return DepthMode.FULL in networks and DepthMode.MVS in networks


def depth_weight_files(mode: DepthMode) -> dict[str, str]:
    """The weights files depth mode ``mode`` reads, by role: the monocular network
    (`DepthMode.MONO`), every MVS network it runs (by its mode, as `NETWORKS`) and, where two
    are fused (mode full), the selector ("select") and the blend with the monocular depth
    ("blend") where its file is there."""
    networks = NETWORKS[mode]
    files = {DepthMode.MONO: WEIGHTS[DepthMode.MONO], **{net: WEIGHTS[net] for net in networks}}
    if _fuses(networks):
        files["select"] = SELECTOR
        if weights_path(BLEND).exists():
            files["blend"] = BLEND
    return files


def renderer_file(preset: RendererPreset) -> str:
    """The weights file name of renderer ``preset``."""
    return RENDERER_WEIGHTS.get(preset, f"renderer_{preset}.safetensors")


@lru_cache(maxsize=4)
def load_renderer(
    preset: RendererPreset = RendererPreset.PANOGRF, device: str = "cpu"
) -> RendererNet:
    """The renderer networks of ``preset`` (PanoGRF's, or an ablation of `RENDERER_PRESETS`
    whose weights ``$PANOGRF_WEIGHTS`` holds; a `RendererPreset` or its value)."""
    from dataclasses import asdict

    if preset not in RENDERER_PRESETS:
        known = sorted(map(str, RENDERER_PRESETS))
        raise UserError(f"unknown renderer preset {str(preset)!r}: one of {known}")
    preset = RendererPreset(preset)
    net = RendererNet(RENDERER_PRESETS[preset])
    _load(net, weights_path(renderer_file(preset)), asdict(net.config))
    return net.to(device).eval()
