"""`panogrf scene check`: exit codes, summary and problem listing, --help at every level."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from panogrf.app import cli
from panogrf.app.scene.folder import write_scene

H, W = 16, 32


@pytest.fixture(autouse=True)
def only_scene_command(monkeypatch):
    # These tests are about `scene`; other subcommands' imports (GL, models) stay out of them.
    monkeypatch.setattr(cli, "_COMMANDS", ("scene",))


def make_scene(root: Path, views: int = 3, depth: bool = True) -> Path:
    rng = np.random.default_rng(0)
    c2w = np.stack([np.eye(4)] * views)
    c2w[:, 0, 3] = 0.5 * np.arange(views)
    depths = rng.uniform(0.5, 5.0, (views, 1, H, W)) if depth else None
    write_scene(root, c2w, rng.random((views, 3, H, W), dtype=np.float32), depths)
    return root


def test_valid_scene_prints_a_summary(tmp_path, capsys):
    root = make_scene(tmp_path / "s")
    assert cli.main(["scene", "check", str(root)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"scene OK: {root}\n")
    assert "views: 3 (view_000, view_001, view_002)" in out
    assert "size: 32x16 (width x height)" in out
    assert "view_000 - view_001: 0.500" in out and "view_000 - view_002: 1.000" in out
    assert "depth: 3 of 3 views, 0.5" in out and " m\n" in out


def test_summary_without_depth_and_with_many_views(tmp_path, capsys):
    root = make_scene(tmp_path / "s", views=7, depth=False)
    assert cli.main(["scene", "check", str(root)]) == 0
    out = capsys.readouterr().out
    assert "depth: none" in out
    assert "nearest-neighbour baselines (m): min 0.500, median 0.500, max 0.500" in out
    assert "largest pairwise 3.000" in out


def test_invalid_scene_lists_every_problem(tmp_path, capsys):
    root = make_scene(tmp_path / "s")
    (root / "images" / "view_001.png").unlink()
    data = json.loads((root / "transforms.json").read_text())
    data["frames"][2]["transform_matrix"][0][0] = 2.0
    (root / "transforms.json").write_text(json.dumps(data))
    assert cli.main(["scene", "check", str(root)]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == f"scene INVALID: {root} (2 problems)"
    assert lines[1] == "  frames[1].file_path (images/view_001.png): file not found"
    assert lines[2].startswith("  frames[2].transform_matrix: rotation is not orthonormal")
    assert len(lines) == 3


def test_missing_folder_is_invalid(tmp_path, capsys):
    assert cli.main(["scene", "check", str(tmp_path / "nowhere")]) == 1
    assert "scene folder not found" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["scene", "--help"], "check"),
        (["scene", "--help"], "EQUIRECTANGULAR"),
        (["scene", "check", "--help"], "DIR"),
        (["scene", "check", "--help"], "Exit status 0 when valid, 1 when not"),
    ],
)
def test_help_at_every_level(argv, expected, capsys):
    with pytest.raises(SystemExit) as info:
        cli.main(argv)
    assert info.value.code == 0
    assert expected in " ".join(capsys.readouterr().out.split())  # help text is re-wrapped


def test_scene_without_subcommand_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as info:
        cli.main(["scene"])
    assert info.value.code == 2
    assert "SUBCOMMAND" in capsys.readouterr().err
