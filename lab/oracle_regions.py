"""Issue 56, a look: how much of a wide-baseline view's error lies where no source sees.

    python lab/oracle_regions.py --data data/loo_home data/loo_lit ZIND_SCENES... \
        --out lab/results/oracle_regions.json

For each scene the view nearest both others is rendered from the other two (`fast`, 512 rows,
the shipped preparation). `hole_fill.seen_weight` marks where some source's depth lands in the
target (the sources' estimated depth splatted; 1 seen, 0 unseen, blurred at the border). Scored
against the true view, WS-PSNR / SSIM / LPIPS:
- ``shipped``: the render;
- ``true_unseen``: the true view pasted where no source sees (an oracle fill: the best any
  hole filling could do);
- ``true_seen``: the true view pasted where some source sees (the best any blending or depth
  of the seen part could do, the render's guess kept in the holes).
A table last.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> None:
    from hole_fill import middle_views

    from panogrf.app.scene import session
    from panogrf.app.scoring import image_scores

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, nargs="+", required=True)
    p.add_argument("--rows", type=int, default=512)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=Path("lab/results/oracle_regions.json"))
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    models = session.default_models("cpu")
    names = ("shipped", "true_unseen", "true_seen")
    rows: dict[str, dict[str, list[dict]]] = {n: {} for n in names}
    for folder, group, data, rgb, w in middle_views(args.data, args.rows, models):
        true = data.images[1]
        images = {"shipped": rgb, "true_unseen": w * rgb + (1 - w) * true,
                  "true_seen": w * true + (1 - w) * rgb}  # fmt: skip
        unseen = float(1 - w.mean())
        for name, img in images.items():
            s = image_scores(img, data.images[1:2])
            row = {k: s[k] for k in ("ws_psnr", "ssim", "lpips")}
            rows[name].setdefault(group, []).append(row | {"scene": str(folder), "unseen": unseen})
        print(f"{group}/{folder.name}: unseen {unseen:.0%} " + " ".join(
            f"{n} {r[group][-1]['ws_psnr']:.2f}/{r[group][-1]['lpips']:.3f}"
            for n, r in rows.items()), flush=True)  # fmt: skip
    fields = ("ws_psnr", "ssim", "lpips")
    table = {
        n: {
            g: {k: statistics.fmean(r[k] for r in rs) for k in (*fields, "unseen")}
            for g, rs in [*per.items(), ("pooled", [r for rs in per.values() for r in rs])]
        }
        for n, per in rows.items()
    }
    args.out.write_text(json.dumps({"table": table, "rows": rows}, indent=1))
    groups = list(table["shipped"])
    print(f"\n{'variant':>12} " + " ".join(f"{g:>24}" for g in groups))
    print(f"{'unseen':>12} " + " ".join(f"{table['shipped'][g]['unseen']:>24.1%}" for g in groups))
    for n in names:
        cells = [f"{t['ws_psnr']:6.2f} / {t['ssim']:.3f} / {t['lpips']:.3f}"
                 for t in table[n].values()]  # fmt: skip
        print(f"{n:>12} " + " ".join(f"{c:>24}" for c in cells))


if __name__ == "__main__":
    main()
