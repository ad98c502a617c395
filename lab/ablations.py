"""`panogrf eval` with the renderer ablations the product does not ship.

The ablations' weights live in `lab/weights` (no_geometry: the renderer without depth-derived
visibility; the model-size ladder: tiny, half the widths, and large, one and a half times; how
they were trained: `docs/weights.md`). This registers their methods beside the product's and
points ``$PANOGRF_WEIGHTS`` at a folder holding the shipped weights and these, then runs the
product's `panogrf eval` with the given arguments:

    python lab/ablations.py data/test --methods panogrf,no_geometry,panogrf_tiny,panogrf_large \
        --out lab/results/ablations.json
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: method name -> renderer preset (`panogrf.model.render_net.PRESETS`)
ABLATIONS = {"no_geometry": "no_geometry", "panogrf_tiny": "tiny", "panogrf_large": "large"}


def weights_folder() -> Path:
    """A temporary folder of links to the shipped weights and the lab's."""
    folder = Path(tempfile.mkdtemp(prefix="panogrf-lab-weights-"))
    for source in (ROOT / "assets", ROOT / "lab" / "weights"):
        for path in source.glob("*.safetensors"):
            (folder / path.name).symlink_to(path)
    return folder


def main(argv: list[str]) -> int:
    os.environ["PANOGRF_WEIGHTS"] = str(weights_folder())
    from panogrf.app.cli import main as panogrf
    from panogrf.model.depth_config import DepthMode
    from panogrf.model.render_net import RendererPreset
    from panogrf.renderer.methods import METHODS, Kind, MethodSpec

    for name, preset in ABLATIONS.items():
        METHODS[name] = MethodSpec(name, DepthMode.FULL, RendererPreset(preset), Kind.NEURAL)
    return panogrf(["eval", *argv])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
