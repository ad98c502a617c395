"""`panogrf scene from-panoramas` on a real pair of 360° photographs (`tests/data/real_pair`,
CC0): a small studio with a bare white floor and its lights moved between the shots."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from panogrf.app import cli
from panogrf.app.scene.folder import load_scene

PAIR = Path(__file__).parents[1] / "data" / "real_pair"


@pytest.fixture(autouse=True)
def only_needed_commands(monkeypatch):
    monkeypatch.setattr(cli, "_COMMANDS", ("scene",))


def test_a_real_pair_poses_level_with_a_consistent_report(tmp_path, capsys):
    images = [str(PAIR / "studio_small_03.jpg"), str(PAIR / "studio_small_07.jpg")]
    out = tmp_path / "studio"
    assert cli.main(["scene", "from-panoramas", *images, "--out", str(out)]) == 0
    report = capsys.readouterr().out
    assert "nan" not in report.lower()
    saved = json.loads((out / "poses_report.json").read_text())
    (pair,) = saved["pairs"]
    assert pair["ok"] and 30 <= pair["inliers"] <= pair["matches"]
    assert math.isfinite(pair["median_residual_deg"]) and pair["median_residual_deg"] < 1.0
    assert all(v["registered"] for v in saved["views"])
    c2w = load_scene(out).c2w
    # Poly Haven levels its panoramas: both cameras stay level (their up axis is the world's),
    # though a floor plane fitted to the few points on the bare floor is tilted by degrees.
    tilt = np.degrees(np.arccos(np.clip(c2w[:, 1, 1], -1, 1)))
    assert tilt.max() < 1.0, (tilt, saved["scale"])
    # The lights moved, the camera a step: a small turn, a small horizontal move.
    rel = c2w[0, :3, :3].T @ c2w[1, :3, :3]
    turn = np.degrees(np.arccos(np.clip((np.trace(rel) - 1) / 2, -1, 1)))
    assert turn < 5.0
    move = c2w[1, :3, 3] - c2w[0, :3, 3]
    assert 0.0 < np.linalg.norm(move) < 1.0
    assert abs(move[1]) < 0.2 * np.linalg.norm(move)
    assert cli.main(["scene", "check", str(out)]) == 0
