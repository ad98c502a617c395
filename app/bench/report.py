"""Writing a bench report: results.json, table.md and the three pictures."""

from __future__ import annotations

import json
import math
from pathlib import Path

from panogrf.app.bench.frontier import plot_frontier, plot_gallery, plot_stability


def _f(x, fmt: str) -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, fmt)


def _params(n: int) -> str:
    return f"{n / 1e6:.2f} M" if n >= 1e5 else f"{n / 1e3:.0f} k" if n else "0"


def format_table(report: dict) -> str:
    """The report as Markdown: the chart's points, then the sweep, then the hard cases."""
    res = report["results"]
    cfg = report["config"]
    bs = [str(b) for b in cfg["baselines"]]
    front = set(report["frontier"]["ws_psnr"])
    real = any(r["real"] for r in res.values())
    head = ["setting", f"s / pano {cfg['time_height']} rows", "params", "peak MiB"]
    head += [f"WS-PSNR {b} m" for b in bs] + ["WS-PSNR mean", "LPIPS mean"]
    head += ["WS-PSNR real"] if real else []
    head += ["frontier"]
    chain = report.get("depth_chain")
    lines = []
    if chain:
        nets = chain["networks"]
        listed = ", ".join(f"{k} {_params(v)}" for k, v in nets.items())
        prep = chain.get("prepare_s_median")
        lines += [
            f"Depth chain (mode full): {len(nets)} networks, {_params(sum(nets.values()))} "
            f"parameters ({listed}); a scene's preparation (depth, refinement, feature maps; "
            f"read back where the scene cache holds it, `--no-cache` times the work) "
            f"{_f(prep, '.2f')} s median"
            + (f" (`{chain['setting'][0]}`)" if chain.get("setting") else "")
            + ".",
            "",
        ]
    lines += [
        f"Quality: {cfg['scenes_per_baseline']} triplet(s) per baseline at {cfg['height']} rows "
        f"(middle view from the outer two); time: one render at {cfg['time_height']} rows "
        f"({report['machine']}); `*`: time predicted from the {cfg['height']}-row render "
        "(x pixel ratio), not measured at 512.",
        "",
        "| " + " | ".join(head) + " |",
        "|" + " --- |" * len(head),
    ]
    for name, r in res.items():
        row = [
            f"`{name}`",
            _f(r["seconds"], ".3g") + ("*" if r["time_scaled"] else ""),
            _params(r["params"]),
            _f(r["peak_mib"], ".0f"),
        ]
        row += [_f(r["baselines"].get(b, {}).get("ws_psnr"), ".2f") for b in bs]
        row += [_f(r["mean"]["ws_psnr"], ".2f"), _f(r["mean"]["lpips"], ".3f")]
        row += [_f(r["real"]["ws_psnr"], ".2f") if r["real"] else "-"] if real else []
        row += ["**yes**" if name in front else ""]
        lines.append("| " + " | ".join(row) + " |")
    sweep = sorted({b for r in res.values() for b in r["sweep"]}, key=float)
    if sweep:
        lines += [
            "",
            f"Stability sweep, WS-PSNR at {cfg['case_height']} rows, "
            f"{cfg.get('sweep_scenes', 1)} scene(s) per baseline: mean (lowest to highest):",
            "",
        ]
        lines += [
            "| setting | " + " | ".join(f"{b} m" for b in sweep) + " |",
            "|" + " --- |" * (len(sweep) + 1),
        ]
        for name, r in res.items():
            lines.append(
                f"| `{name}` | " + " | ".join(_spread(r["sweep"][b]) for b in sweep) + " |"
            )
    cases = list(cfg["cases"])
    if cases:
        lines += ["", f"Hard cases, WS-PSNR at {cfg['case_height']} rows:", ""]
        lines += ["| setting | " + " | ".join(cases) + " |", "|" + " --- |" * (len(cases) + 1)]
        for name, r in res.items():
            lines.append(
                f"| `{name}` | "
                + " | ".join(_f(r["cases"][c]["ws_psnr"], ".2f") for c in cases)
                + " |"
            )
    problems = report["problems"]
    lines += [
        "",
        "Renders with NaN, inf, a wrong shape or no content: "
        + (", ".join(problems) or "none")
        + ".",
    ]
    return "\n".join(lines) + "\n"


#: Every file `write_outputs` may write.
OUTPUTS = ("results.json", "table.md", "frontier.png", "stability.png", "gallery.png")


def earlier_output(out: Path) -> bool:
    """Whether ``out`` holds only what `write_outputs` writes, with a bench's results.json."""
    try:
        results = json.loads((out / "results.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    if not isinstance(results, dict) or not {"config", "results"} <= results.keys():
        return False
    return all(p.name in OUTPUTS for p in out.iterdir() if not p.name.startswith("."))


def write_outputs(report: dict, out: Path) -> list[Path]:
    """results.json, table.md, frontier.png, stability.png and gallery.png in ``out``."""
    from panogrf.app.bench.run import _u8
    from panogrf.app.files.atomic import nan_to_null, write_json_atomic, write_text_atomic

    out.mkdir(parents=True, exist_ok=True)
    gallery = report.pop("_gallery", [])
    written = [out / "results.json", out / "table.md"]
    write_json_atomic(written[0], nan_to_null(report))
    write_text_atomic(written[1], format_table(report))
    cfg = report["config"]
    title = (
        f"{cfg['data']}: {cfg['scenes_per_baseline']} triplet(s) per baseline at "
        f"{cfg['height']} rows; time at {cfg['time_height']} rows, {report['machine']}"
    )
    plot_frontier(report["results"], out / "frontier.png", title, cfg["time_height"])
    written.append(out / "frontier.png")
    sweep = {n: r["sweep"] for n, r in report["results"].items() if r["sweep"]}
    if sweep:
        plot_stability(
            sweep,
            out / "stability.png",
            f"{cfg.get('sweep_scenes', 1)} synthetic scene(s) per baseline, "
            f"{cfg['case_height']} rows: mean, and lowest to highest",
        )
        written.append(out / "stability.png")
    if gallery:
        rows = [
            (
                case.name,
                _u8(case.target[0]),
                [(s, _u8(r.image), r.scores["ws_psnr"]) for s, r in per_s.items()],
            )
            for case, per_s in gallery
        ]
        plot_gallery(rows, out / "gallery.png")
        written.append(out / "gallery.png")
    return written


def _spread(scores: dict) -> str:
    """A sweep cell: the mean WS-PSNR and, over several scenes, its lowest to highest."""
    mean = _f(scores["ws_psnr"], ".2f")
    if scores.get("n", 1) > 1 and "ws_psnr_min" in scores:
        return f"{mean} ({_f(scores['ws_psnr_min'], '.1f')}-{_f(scores['ws_psnr_max'], '.1f')})"
    return mean
