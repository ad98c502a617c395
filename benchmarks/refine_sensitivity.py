"""How far the per-scene refinement carries a micrometre: the CPU's own spread, against which
a GPU's refined depth is compared (`benchmarks/gpu.py --parity`).

    python benchmarks/refine_sensitivity.py --data data/loo_lit --scenes 6 \
        [--setting damping=8] --out lab/results/refine_sensitivity.json

For each scene's two outer panoramas: mode full's estimate, refined (``--setting``, read as
`refine_depth.py` reads it; `PREPARE_REFINE` by default) as it is and again after every depth
is moved by one part in a million (Gaussian, seeded); the table gives how far the input moved
and how far the refined depth moved (mean absolute, metres), on this machine's CPU. The table
is printed last.
"""

from __future__ import annotations

import argparse
import json
import platform
from pathlib import Path

import torch
from refine_depth import parse_setting


def main() -> int:
    from panogrf.app.scene.folder import load_scene
    from panogrf.app.scene.session import default_models
    from panogrf.renderer.methods import SourceViews

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, required=True, help="a dataset folder")
    p.add_argument("--scenes", type=int, default=6)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument(
        "--setting", default="shipped", help="as refine_depth.py's: shipped or field=value,..."
    )
    args = p.parse_args()
    setting = parse_setting(args.setting)
    torch.set_num_threads(args.threads)
    models = default_models("cpu")
    index = json.loads((args.data / "dataset.json").read_text())
    rows = []
    for entry in index["scenes"][: args.scenes]:
        data = load_scene(args.data / entry["folder"], load_images=True).images
        views = SourceViews(data.images[[0, 2]], data.c2w[[0, 2]], refine=None)
        with torch.no_grad():
            est = views.depth_for("full", models)
        views.refine = setting
        refined = views.refined_depth(est, "full", models)
        noise = torch.randn(est.shape, generator=torch.Generator().manual_seed(0))
        moved = est * (1 + 1e-6 * noise)
        again = views.refined_depth(moved, "full", models)
        assert refined is not None and again is not None  # nothing stops it
        rows.append(
            {
                "scene": entry["folder"],
                "input_moved_m": float((moved - est).abs().mean()),
                "refined_moved_m": float((again - refined).abs().mean()),
            }
        )
        print(rows[-1], flush=True)
    mean = sum(r["refined_moved_m"] for r in rows) / len(rows)
    out = {
        "machine": f"{platform.machine()}, {args.threads} torch threads",
        "setting": args.setting,
        "rows": rows,
    }
    args.out.write_text(json.dumps(out | {"refined_moved_mean_m": mean}, indent=1))
    print(f"\n{'scene':>14} | input moved (m) | refined depth moved (mm)")
    for r in rows:
        print(f"{r['scene']:>14} | {r['input_moved_m']:15.2e} | {r['refined_moved_m'] * 1e3:8.2f}")
    print(f"{'mean':>14} | {'':15} | {mean * 1e3:8.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
