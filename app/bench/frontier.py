"""The Pareto frontier of cost against quality, and the bench's three pictures (matplotlib).

- ``frontier.png``: seconds per panorama (log) against WS-PSNR and against LPIPS, one small
  marker per setting and baseline, one large per setting (its mean over the baselines, named,
  with parameters and peak memory), the frontier through the large ones, the real triplet as
  stars;
- ``stability.png``: WS-PSNR and LPIPS against the baseline (0.2-5 m), a line per setting
  (the mean over the sweep's scenes) and its band (their lowest to highest);
- ``gallery.png``: the hard cases, a row each: the truth, then every setting side by side.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

BASELINE_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "h")


def pareto_front(cost: Sequence[float], quality: Sequence[float]) -> list[int]:
    """Indices of the points no other point beats: none is at most as costly and at least as
    good with one of the two strictly better. Lower cost and higher quality are better (pass
    ``-lpips`` for LPIPS); points with a NaN are never on it. Sorted by cost."""
    pts = [(c, q, i) for i, (c, q) in enumerate(zip(cost, quality, strict=True)) if _finite(c, q)]
    pts.sort(key=lambda p: (p[0], -p[1]))
    front, best = [], -math.inf
    for _, q, i in pts:
        if q > best:
            front.append(i)
            best = q
    return front


def _finite(*xs: float) -> bool:
    return all(x is not None and math.isfinite(x) for x in xs)


def _plt():
    import matplotlib

    matplotlib.use("Agg")  # files only, never a window
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path, dpi: int) -> None:
    from panogrf.app.files.atomic import atomic_output

    with atomic_output(path) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)
    _plt().close(fig)


def _colours(names: Sequence[str]) -> dict[str, tuple]:
    plt = _plt()
    cmap = plt.get_cmap("tab20")
    return {n: cmap(i % 20) for i, n in enumerate(names)}


def _human(n: int) -> str:
    return f"{n / 1e6:.2f}M" if n >= 1e5 else f"{n / 1e3:.0f}k" if n else "0"


def plot_frontier(results: dict, path: Path, title: str, time_height: int = 512) -> None:
    """``results``: setting -> {"seconds", "params", "peak_mib", "baselines": {b: scores},
    "mean": scores, "real": scores | None} with scores {"ws_psnr", "lpips"}."""
    plt = _plt()
    names = list(results)
    colour = _colours(names)
    baselines = sorted({b for r in results.values() for b in r["baselines"]}, key=float)
    fig, axes = plt.subplots(1, 2, figsize=(19, 7))
    for ax, metric, better in ((axes[0], "ws_psnr", 1), (axes[1], "lpips", -1)):
        xs = [results[n]["seconds"] for n in names]
        ys = [results[n]["mean"][metric] for n in names]
        for n, x in zip(names, xs, strict=True):
            r = results[n]
            for k, b in enumerate(baselines):
                s = r["baselines"].get(b)
                if s is not None and _finite(x, s[metric]):
                    m = BASELINE_MARKERS[k % len(BASELINE_MARKERS)]
                    ax.scatter(x, s[metric], marker=m, s=18, color=colour[n], alpha=0.55)
            if r.get("real") and _finite(x, r["real"][metric]):
                ax.scatter(x, r["real"][metric], marker="*", s=140, color=colour[n], ec="k")
        for i, (n, x, y) in enumerate(zip(names, xs, ys, strict=True)):
            if not _finite(x, y):
                continue
            ax.scatter(x, y, s=90, color=colour[n], ec="k", zorder=3)
            # A number by each mean; the names, sizes and memory in the key beside the charts
            # (names written on the points overlap where settings cost alike).
            ax.annotate(str(i + 1), (x, y), xytext=(4, 3), textcoords="offset points", fontsize=8)
        front = pareto_front(xs, [better * y for y in ys])
        ax.step(
            [xs[i] for i in front],
            [ys[i] for i in front],
            where="post",
            color="k",
            lw=1.2,
            ls="--",
            label="Pareto frontier (means)",
        )
        ax.set_xscale("log")
        ax.set_xlabel(f"seconds per {2 * time_height}x{time_height} panorama (log)")
        ax.set_ylabel(
            {"ws_psnr": "WS-PSNR (dB), higher is better", "lpips": "LPIPS, lower is better"}[metric]
        )
        ax.grid(True, which="both", alpha=0.3)
    handles = [
        plt.Line2D([], [], ls="", marker=BASELINE_MARKERS[k % 8], color="grey", label=f"{b} m")
        for k, b in enumerate(baselines)
    ]
    handles.append(plt.Line2D([], [], ls="", marker="o", ms=9, color="grey", mec="k", label="mean"))
    if any(r.get("real") for r in results.values()):
        handles.append(
            plt.Line2D(
                [], [], ls="", marker="*", ms=12, color="grey", mec="k", label="real triplet"
            )
        )
    handles.append(plt.Line2D([], [], ls="--", color="k", label="Pareto frontier"))
    axes[0].legend(handles=handles, loc="lower right", fontsize=8)
    fig.legend(handles=_setting_key(results, colour), loc="center right", fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0, 0.8, 1))
    _save(fig, path, 110)


def _setting_key(results: dict, colour: dict) -> list:
    """The key of the numbered means: number, setting, parameters and peak memory."""
    plt = _plt()
    key = []
    for i, (n, r) in enumerate(results.items()):
        label = f"{i + 1}  {n}: {_human(r['params'])} p, {r['peak_mib']:.0f} MiB"
        if r.get("time_scaled"):
            label += " (t scaled)"
        key.append(
            plt.Line2D([], [], ls="", marker="o", ms=8, color=colour[n], mec="k", label=label)
        )
    return key


def plot_stability(sweep: dict, path: Path, title: str) -> None:
    """``sweep``: setting -> {baseline (str, metres): scores}."""
    plt = _plt()
    colour = _colours(list(sweep))
    fig, axes = plt.subplots(1, 2, figsize=(14, 5.5))
    for ax, metric in ((axes[0], "ws_psnr"), (axes[1], "lpips")):
        for n, per_b in sweep.items():
            bs = sorted(per_b, key=float)
            x = [float(b) for b in bs]
            ax.plot(x, [per_b[b][metric] for b in bs], marker="o", ms=4, color=colour[n], label=n)
            if all(f"{metric}_min" in per_b[b] for b in bs):  # the spread over the scenes
                low = [per_b[b][f"{metric}_min"] for b in bs]
                high = [per_b[b][f"{metric}_max"] for b in bs]
                ax.fill_between(x, low, high, color=colour[n], alpha=0.12, lw=0)
        ax.set_xlabel("baseline: distance between the two sources (m)")
        ax.set_ylabel({"ws_psnr": "WS-PSNR (dB)", "lpips": "LPIPS (lower is better)"}[metric])
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=7, ncol=2)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    _save(fig, path, 110)


def plot_gallery(
    rows: list[tuple[str, np.ndarray, list[tuple[str, np.ndarray, float]]]], path: Path
) -> None:
    """``rows``: (case, truth [H, W, 3] uint8, [(setting, image, WS-PSNR), ...]) per case."""
    plt = _plt()
    cols = 1 + max(len(r[2]) for r in rows)
    fig, axes = plt.subplots(len(rows), cols, figsize=(2.4 * cols, 1.45 * len(rows)), squeeze=False)
    for i, (case, truth, renders) in enumerate(rows):
        tiles = [("truth", truth, None), *renders]
        for j in range(cols):
            ax = axes[i, j]
            ax.axis("off")
            if j >= len(tiles):
                continue
            name, img, score = tiles[j]
            ax.imshow(img)
            label = name if score is None else f"{name} {score:.1f} dB"
            ax.set_title(label, fontsize=7, pad=2)
            if j == 0:
                ax.text(
                    -0.04,
                    0.5,
                    case,
                    transform=ax.transAxes,
                    rotation=90,
                    ha="right",
                    va="center",
                    fontsize=8,
                )
    fig.tight_layout(pad=0.3)
    _save(fig, path, 100)
