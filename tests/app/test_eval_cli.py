"""`panogrf eval` never loses its results: the output is checked before the work, undefined
metrics are written as null, and a failed write prints the results instead."""

from __future__ import annotations

import errno
import json
import shutil

import numpy as np
import pytest

from panogrf.app import cli
from panogrf.app.files import atomic
from panogrf.app.scene import session
from panogrf.assets import path as asset_path

DEMO = asset_path("demo")


@pytest.fixture
def dataset(tmp_path):
    root = tmp_path / "data"
    root.mkdir()
    shutil.copytree(DEMO, root / "a")
    (root / "dataset.json").write_text(json.dumps({"scenes": [{"folder": "a"}]}))
    return root


@pytest.fixture
def no_models(monkeypatch):
    def refuse(device=None):
        raise AssertionError("the work started before the output was checked")

    monkeypatch.setattr(session, "default_models", refuse)


def _nearest(dataset, out, height: int) -> list[str]:
    frames = json.loads((DEMO / "transforms.json").read_text())["frames"]
    p = np.array([f["transform_matrix"] for f in frames])[:, :3, 3]
    baseline = round(float(np.linalg.norm(p[2] - p[0])), 1)
    return ["eval", str(dataset), "--out", str(out), "--methods", "nearest"] + [
        "--height",
        str(height),
        "--baselines",
        str(baseline),
    ]


def test_unwritable_out_is_refused_before_the_work(dataset, tmp_path, no_models, capsys):
    (tmp_path / "r.json").mkdir()
    assert cli.main(_nearest(dataset, tmp_path / "r.json", 16)) == 2
    assert "is a folder" in capsys.readouterr().err
    assert cli.main(_nearest(dataset, tmp_path / "no" / "r.json", 16)) == 2
    assert "does not exist" in capsys.readouterr().err


def test_undefined_metric_is_written_as_null(dataset, tmp_path, capsys):
    out = tmp_path / "r.json"
    assert cli.main(_nearest(dataset, out, 16)) == 0  # LPIPS needs 31 rows
    report = json.loads(out.read_text())  # strict JSON: no NaN
    row = next(iter(report["results"]["nearest"].values()))
    assert row["lpips"] is None and np.isfinite(row["ws_psnr"])


def test_failed_write_prints_the_results(dataset, tmp_path, monkeypatch, capsys):
    def full(path, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(atomic, "write_json_atomic", full)
    assert cli.main(_nearest(dataset, tmp_path / "r.json", 16)) == 2
    captured = capsys.readouterr()
    assert "No space left on device" in captured.err and "printed above" in captured.err
    report = json.loads(captured.out[captured.out.index("\n{") :])
    assert set(report["results"]) == {"nearest"}
    assert not (tmp_path / "r.json").exists()


def test_broken_scenes_are_reported_and_the_others_scored(tmp_path, monkeypatch, capsys):
    """Issue 57 D3: a scene broken from the start, or one that breaks mid-run, is named and
    left out; the others are scored and written; the exit says the run was incomplete."""
    from panogrf.app.errors import UserError
    from panogrf.app.scene import folder as scene_folder

    root = tmp_path / "data"
    root.mkdir()
    for name in ("a", "b", "c"):
        shutil.copytree(DEMO, root / name)
    (root / "b" / "transforms.json").write_text("{ not json")
    (root / "dataset.json").write_text(
        json.dumps({"scenes": [{"folder": n} for n in ("a", "b", "c")]})
    )
    load = scene_folder.load_scene

    def breaks_mid_run(path, **kw):
        if kw.get("load_images") and str(path).endswith("c"):
            raise UserError(f"{path}: images/frame_001.png is unreadable")
        return load(path, **kw)

    monkeypatch.setattr(scene_folder, "load_scene", breaks_mid_run)
    out = tmp_path / "r.json"
    assert cli.main(_nearest(root, out, 16)) == 1
    report = json.loads(out.read_text())
    assert next(iter(report["results"]["nearest"].values()))["scenes"] == 1
    assert [s["scene"][-1] for s in report["skipped"]] == ["b", "c"]
    printed = capsys.readouterr().out
    assert "skipping" in printed and "unreadable" in printed


def test_the_settings_check_themselves_when_built_directly(tmp_path):
    from panogrf.app.commands.eval import EvalConfig
    from panogrf.app.errors import UserError

    out = tmp_path / "r.json"
    with pytest.raises(UserError, match="^--methods lists no method$"):
        EvalConfig(tmp_path, out, methods=" , ")
    with pytest.raises(UserError, match="^--baselines: expected metres, got '1,x'$"):
        EvalConfig(tmp_path, out, baselines="1,x")
    with pytest.raises(UserError, match="^--limit must be at least 1 scene per baseline"):
        EvalConfig(tmp_path, out, limit=0)
    cfg = EvalConfig(tmp_path, out, methods="panogrf:paper,nearest", baselines="1.04, 2,")
    assert cfg.method_list() == [("panogrf", "paper"), ("nearest", "fast")]
    assert cfg.baseline_list() == [1.0, 2.0] and cfg.subset_names() == set()
