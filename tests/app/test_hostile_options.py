"""Hostile input, round two (issue 57): numeric options validated where they are parsed, and
weights files checked (there, complete, finite) before any work, each refused in one line."""

from __future__ import annotations

import shutil

import pytest
import torch
from safetensors import safe_open
from safetensors.torch import load_file, save_file

from panogrf.app.cli import main
from panogrf.assets import path as asset_path


@pytest.mark.parametrize(
    "argv, option",
    [
        (["scene", "import", "x.txt", "--out", "o", "--scale", "0"], "--scale"),  # S4
        (["scene", "import", "x.txt", "--out", "o", "--scale", "-2"], "--scale"),  # S4
        (["scene", "import", "x.txt", "--out", "o", "--scale", "nan"], "--scale"),  # T7
        (["scene", "import", "x.txt", "--out", "o", "--scale", "inf"], "--scale"),  # T7
        (["render", "s", "--out", "x.png", "--threads", "100000"], "--threads"),  # T5
        (["eval", "d", "--threads", "100000"], "--threads"),  # T5
        (["view", "s", "--fixed-step=-0.5"], "--fixed-step"),  # S10
        (["view", "s", "--fixed-step", "nan"], "--fixed-step"),  # T16
        (["view", "s", "--fixed-step", "inf"], "--fixed-step"),  # T16
        (["bench", "--time-budget=-1"], "--time-budget"),  # S9
        (["train", "depth", "--lr", "nan"], "--lr"),  # T15
        (["dataset", "make", "--out", "o", "--seed=-5"], "--seed"),  # T12
        (["dataset", "make", "--out", "o", "--start=-5"], "--start"),  # T12
        (["dataset", "pack", "d", "--out", "o", "--height", "0"], "--height"),  # T13
        (["dataset", "pack", "d", "--out", "o", "--height", "-32"], "--height"),  # T13
        (["scene", "faces", "a.png", "--out", "o", "--size", "-5"], "--size"),  # T11
    ],
)
def test_a_bad_number_is_refused_in_one_line(argv, option, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert f"argument {option}" in err[-1] and "Traceback" not in "\n".join(err)
    assert list(tmp_path.iterdir()) == []  # nothing written


def _broken_weights(tmp_path, name: str, how: str):
    folder = tmp_path / "weights"
    folder.mkdir()
    for f in asset_path("").glob("*.safetensors"):
        shutil.copy(f, folder / f.name)
    target = folder / name
    if how == "nan":
        with safe_open(str(target), framework="pt") as f:
            meta = f.metadata()
        tensors = load_file(str(target))
        first = next(iter(tensors))
        tensors[first] = torch.full_like(tensors[first], float("nan"))
        save_file(tensors, str(target), metadata=meta)
    elif how == "truncated":
        target.write_bytes(target.read_bytes()[:50_000])
    else:
        target.write_bytes(b"")
    return folder


@pytest.mark.parametrize(
    "name, how",
    [
        ("renderer_panogrf.safetensors", "nan"),  # S7: the renderer's, read after the depth
        ("depth_mvs_full.safetensors", "truncated"),  # T6
        ("depth_mono.safetensors", "empty"),  # T6
    ],
)
def test_broken_weights_are_refused_before_any_work(name, how, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("PANOGRF_WEIGHTS", str(_broken_weights(tmp_path, name, how)))
    out = tmp_path / "x.png"
    argv = ["render", str(asset_path("demo")), "--target-frame", "1", "--out", str(out)]
    assert main([*argv, "--height", "32", "--no-cache", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and name in err[0], err
    assert ("non-finite" in err[0]) == (how == "nan")
    assert not out.exists()
