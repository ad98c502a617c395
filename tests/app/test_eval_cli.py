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
