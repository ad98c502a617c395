"""`panogrf demo` end to end on the bundled scene, and its errors."""

from __future__ import annotations

from panogrf.app.cli import main
from panogrf.app.files.images import read_rgb


def test_demo_runs_and_writes_a_picture(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "depth warp" in out and "rotation only" in out
    sheet = read_rgb(tmp_path / "out" / "demo_views.png")
    assert sheet.shape[1] == 512 and sheet.shape[0] > 6 * 256


def test_demo_on_a_missing_scene_is_one_line(tmp_path, capsys):
    assert main(["demo", "--scene", str(tmp_path / "nope"), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("panogrf demo: error:") and "Traceback" not in err


def test_reproject_cli(capsys):
    from panogrf.assets import path as asset_path

    assert main(["scene", "reproject", str(asset_path("demo"))]) == 0
    out = capsys.readouterr().out
    assert "frame_000" in out and "frame_002" in out and "dB" in out
    assert main(["scene", "reproject", str(asset_path("demo")), "--target", "7"]) == 2
