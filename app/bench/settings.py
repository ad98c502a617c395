"""The methods and settings `panogrf bench` charts, behind one render function.

A `Setting` is a method of `panogrf.renderer.methods.METHODS` with its sampling (PanoGRF's
draft / fast / paper, the ablations at fast), or the GL depth-mesh preview with its mesh rows.
`render_setting` renders a target pose with any of them from a `SourceViews`; what does not
depend on the pose is memoised in the `SourceViews` (depth, caches, fits, GL meshes).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np
import psutil
import torch
from torch import Tensor

from panogrf.app.runtime import heap_in_use
from panogrf.model.depth_config import DepthMode
from panogrf.renderer.methods import METHODS, Kind, Models, SourceViews, prepare, render_view
from panogrf.renderer.render import Quality


@dataclass(frozen=True)
class Setting:
    """One point of the chart: a method and how it samples."""

    name: str
    """Label on the chart and key in the results, e.g. ``panogrf:fast`` or ``gl:64``."""
    method: str
    """A name of `METHODS`, or ``gl`` (the viewer's GL preview)."""
    quality: Quality = Quality.FAST
    """Sampling of the neural methods (`panogrf.renderer.render.QUALITY`)."""
    mesh_rows: int = 0
    """Rows of the GL preview's depth meshes (``gl`` only)."""
    slow: bool = False
    """Tens of seconds per scene here (paper sampling, a per-scene fit)."""


#: Every setting, cheapest first. The GL preview's rows are those `benchmarks/preview_quality.py`
#: measured; 64 is the viewer's.
SETTINGS: tuple[Setting, ...] = (
    Setting("nearest", "nearest"),
    *(Setting(f"gl:{r}", "gl", mesh_rows=r) for r in (32, 48, 64, 96, 128)),
    Setting("meshwarp", "meshwarp"),
    Setting("panogrf:draft", "panogrf", Quality.DRAFT),
    Setting("panogrf:fast", "panogrf", Quality.FAST),
    Setting("no_mono", "no_mono", Quality.FAST),
    Setting("no_mvs", "no_mvs", Quality.FAST),
    Setting("panogrf:paper", "panogrf", Quality.PAPER, slow=True),
    Setting("snerf", "snerf", slow=True),
)
BY_NAME = {s.name: s for s in SETTINGS}
#: The viewer's three stages: GL preview while moving, draft, then fast when still.
VIEWER_DEFAULTS = ("gl:64", "panogrf:draft", "panogrf:fast")


def select(names: str | None, skip: str = "") -> list[Setting]:
    """The settings named in a comma-separated list (all: None), less those in ``skip``."""
    chosen = list(SETTINGS) if names is None else [_get(n) for n in names.split(",") if n.strip()]
    dropped = {_get(n).name for n in skip.split(",") if n.strip()}
    out = [s for s in chosen if s.name not in dropped]
    if not out:  # an empty --settings is a slip, not "all of them" (and nothing to measure)
        raise ValueError("no setting left to run")
    return out


def _get(name: str) -> Setting:
    name = name.strip()
    if name not in BY_NAME:
        raise ValueError(f"unknown setting {name!r}: one of {', '.join(BY_NAME)}")
    return BY_NAME[name]


class GLContext:
    """The headless GL context of the previews, made on first use and released explicitly."""

    def __init__(self) -> None:
        self.ctx = None

    def get(self):
        if self.ctx is None:
            from panogrf.renderer.gl_preview import create_headless_context

            self.ctx = create_headless_context()
        return self.ctx

    def release(self) -> None:
        if self.ctx is not None:
            self.ctx.release()
            self.ctx = None


def prepare_setting(setting: Setting, views: SourceViews, models: Models, gl: GLContext) -> None:
    """Compute (once per scene) what ``setting`` needs that does not depend on the pose."""
    if setting.method != "gl":
        prepare(setting.method, views, models)
        return
    key = setting.name
    if key not in views.fitted:
        from panogrf.app.files.images import to_uint8
        from panogrf.renderer.gl_preview import PreviewRenderer

        depth = views.depth_for(DepthMode.FULL, models)[:, 0].cpu().numpy()
        start = time.perf_counter()
        views.fitted[key] = PreviewRenderer(
            gl.get(),
            to_uint8(views.images),
            depth,
            views.c2w.cpu().numpy(),
            setting.mesh_rows,
        )
        views.seconds[f"mesh:{key}"] = time.perf_counter() - start


def render_setting(
    setting: Setting,
    views: SourceViews,
    tgt_c2w: Tensor,  # [4, 4]
    height: int,
    models: Models,
    gl: GLContext,
) -> Tensor:
    """The panorama [3, H, 2H] in [0, 1] seen from ``tgt_c2w`` with ``setting``."""
    prepare_setting(setting, views, models, gl)
    if setting.method != "gl":
        return render_view(setting.method, views, tgt_c2w, height, models, setting.quality)
    rgb, _ = views.fitted[setting.name].render(tgt_c2w.double().cpu().numpy(), height)
    return torch.from_numpy(rgb).permute(2, 0, 1).float() / 255.0


def release_scene(views: SourceViews) -> None:
    """Free the GL meshes a scene's previews hold (the context stays)."""
    for key in [k for k in views.fitted if k.startswith("gl:")]:
        views.fitted.pop(key).release()


def parameters(setting: Setting, models: Models) -> int:
    """Learned parameters behind a setting: depth network + renderer, or the per-scene grid."""
    if setting.method == "nearest":
        return 0
    if setting.method == "snerf":
        from panogrf.renderer.snerf import SNeRFConfig

        return 4 * int(np.prod(SNeRFConfig().grid))  # density + colour per cell
    spec = METHODS.get(setting.method)
    mode = spec.depth_mode if spec is not None else DepthMode.FULL
    total = _count(models.estimator(mode))
    if spec is not None and spec.kind is Kind.NEURAL:
        total += _count(models.renderer(spec.renderer))
    return total


def depth_networks(models: Models) -> dict[str, int]:
    """The shipped depth chain's (mode full) networks and their parameters, in the order it runs
    them: the monocular network, the mono-guided and the unguided MVS, the selector, the blend."""
    est = models.estimator(DepthMode.FULL)
    nets = {"monocular": est.mono}
    names = {DepthMode.FULL: "MVS mono-guided", DepthMode.MVS: "MVS unguided"}
    nets |= {names.get(k, f"MVS {k}"): net for k, net in est.mvs.items()}
    nets |= {"selector": est.selector, "blend": est.blend}
    return {name: _count(net) for name, net in nets.items() if net is not None}


def _count(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


class PeakMemory:
    """Peak memory a block needs at once (MiB): the most the C allocator had handed out above
    its level on entry (`panogrf.app.runtime.heap_in_use`), polled by a thread every
    ``interval`` seconds while the block runs. Tensors, the meshes and Mesa's CPU rasteriser
    (it lives in this process) all allocate there. Off glibc: the resident size above entry, a
    lower bound (memory the allocator reuses from earlier blocks is not counted)."""

    def __init__(self, interval: float = 0.002) -> None:
        self.interval = interval
        self.mib = 0.0
        self.kind = "heap" if heap_in_use() is not None else "rss"

    def _now(self) -> int:
        if self.kind == "heap":
            return heap_in_use()
        return self._proc.memory_info().rss

    def __enter__(self) -> PeakMemory:
        self._proc = psutil.Process()
        self._start = self._peak = self._now()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._poll, daemon=True)
        self._thread.start()
        return self

    def _poll(self) -> None:
        while not self._stop.wait(self.interval):
            self._peak = max(self._peak, self._now())

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        self._peak = max(self._peak, self._now())
        self.mib = (self._peak - self._start) / 2**20
