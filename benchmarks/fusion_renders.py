"""Renders with mode full's depth as shipped and as other settings of it, on validation scenes.

    python benchmarks/fusion_renders.py --data data/val_wide_home data/val_fusion_classic \
        data/val_fusion_home [--fusions shipped,short] [--out FILE.json]

For each dataset and each depth setting (``shipped``: the estimator's defaults; ``round6``: as
shipped in rounds 6 and 7, without the median after the sweep; ``short``: `SHORT_SWEEP` and the
monocular hypothesis, on top of the defaults) runs ``panogrf eval`` on every scene (every
baseline the dataset has), methods panogrf and meshwarp (the two that read mode full's depth),
in a process of its own, and prints mean WS-PSNR / LPIPS and the median preparation time.
Validation scenes only. (Round 7's ``fusion_val_renders.json`` compared the round-6 defaults,
then named ``shipped``, with ``short`` without the median.)
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

FUSIONS = ("shipped", "round6", "short")


def _run_eval(fusion: str, argv: list[str]) -> int:
    """``panogrf eval`` in this process with the depth estimator set to ``fusion``."""
    import panogrf.model.depth as depth

    attrs = {
        "shipped": {},
        "round6": {"median": 1},
        "short": {"fusion_sweep": depth.SHORT_SWEEP, "mono_hypothesis": True},
    }[fusion]
    if attrs:
        init = depth.DepthEstimator.__init__

        def _init(self, mono, mvs, config=None, **kwargs):
            init(self, mono, mvs, config, **(kwargs | attrs))

        depth.DepthEstimator.__init__ = _init
    from panogrf.app.cli import main

    return main(["eval", *argv])


def _baselines(folder: Path) -> str:
    scenes = json.loads((folder / "dataset.json").read_text())["scenes"]
    return ",".join(sorted({f"{round(s['baseline_m'], 1):g}" for s in scenes}))


def main() -> int:
    if len(sys.argv) > 2 and sys.argv[1] == "--eval-with":
        return _run_eval(sys.argv[2], sys.argv[3:])
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--fusions", default="shipped,short", help=f"comma-separated, of {FUSIONS}")
    parser.add_argument("--out", type=Path, default=Path("lab/results/fusion_val_renders.json"))
    args = parser.parse_args()
    from panogrf.app.files.atomic import write_json_atomic

    unknown = set(args.fusions.split(",")) - set(FUSIONS)
    if unknown:
        parser.error(f"unknown fusions {sorted(unknown)}; choose from {FUSIONS}")
    summary: dict[str, dict] = {}
    runs: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for folder in args.data:
            for fusion in args.fusions.split(","):
                out = Path(tmp) / f"{fusion}_{folder.name}.json"
                cmd = [sys.executable, __file__, "--eval-with", fusion, str(folder)]
                cmd += ["--baselines", _baselines(folder), "--methods", "panogrf,meshwarp"]
                cmd += ["--threads", str(args.threads), "--out", str(out)]
                subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
                result = json.loads(out.read_text())
                runs[f"{fusion}:{folder.name}"] = result
                for method, per in result["per_scene"].items():
                    rows = [r for b in per.values() for r in b]
                    summary.setdefault(folder.name, {})[f"{fusion}:{method}"] = {
                        "ws_psnr": statistics.fmean(r["ws_psnr"] for r in rows),
                        "lpips": statistics.fmean(r["lpips"] for r in rows),
                        "prepare_s_median": statistics.median(r["prepare_s"] for r in rows),
                        "n": len(rows),
                    }
    report = {"what": __doc__.split("\n\n")[0], "summary": summary, "runs": runs}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out, report)
    print(f"{'data':<20} {'fusion:method':<18} {'WS-PSNR':>8} {'LPIPS':>7} {'prep s':>7}")
    for name, rows in summary.items():
        for key, r in rows.items():
            print(
                f"{name:<20} {key:<18} {r['ws_psnr']:8.2f} {r['lpips']:7.4f} "
                f"{r['prepare_s_median']:7.2f}"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
