"""Suite-wide fixtures."""

from __future__ import annotations

import pytest


@pytest.fixture(autouse=True)
def quick_scene_refinement(monkeypatch):
    """The per-scene depth refinement that `view`, `render` and `eval` run by default
    (`panogrf.model.refine.PREPARE_REFINE`) shortened to a few steps at 32 rows for tests run
    in this process: they check what it reaches and changes, not its quality, which
    `benchmarks/refine_depth.py` measures with the shipped setting. Commands run as
    subprocesses keep the shipped setting."""
    from panogrf.model import refine

    quick = refine.RefineConfig(
        smooth=1.0, coarse=2, iterations=2, height=32, free_space=1.0, free_space_shrink=2
    )
    monkeypatch.setattr(refine, "PREPARE_REFINE", quick)
