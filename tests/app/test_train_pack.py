"""Triplet packs (`panogrf dataset pack`): scenes at the working height in one small file that
`load_triplets` reads as it reads the dataset folders, and training from them."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from safetensors import safe_open

from panogrf.app.cli import main
from panogrf.app.errors import UserError
from panogrf.app.synth.make import MakeConfig, make_dataset
from panogrf.app.train.data import load_triplets
from panogrf.app.train.pack import DEPTH_STEP_M, read_packs

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def two_sets(tmp_path_factory):
    a, b = tmp_path_factory.mktemp("a"), tmp_path_factory.mktemp("b")
    make_dataset(MakeConfig(out=a, split="train", count=3, height=64), progress=False)
    make_dataset(MakeConfig(out=b, split="train", count=3, height=64, seed=7), progress=False)
    return a, b


@pytest.mark.gl
def test_pack_reads_back_as_the_folders_do(two_sets, tmp_path, capsys):
    a, b = two_sets
    pack = tmp_path / "p.safetensors"
    assert main(["dataset", "pack", "--out", str(pack), "--height", "32", str(a), f"{b}:1:2"]) == 0
    assert "5 scenes" in capsys.readouterr().out  # 3 + 2 of them
    got = load_triplets(pack, 32)
    want_a, want_b = load_triplets(a, 32), load_triplets(b, 32, limit=2, start=1)
    assert len(got) == 5
    assert got.names == [f"{a.name}/{n}" for n in want_a.names] + [
        f"{b.name}/{n}" for n in want_b.names
    ]
    depths = torch.cat([want_a.depths, want_b.depths])
    assert (got.depths - depths).abs().max() <= DEPTH_STEP_M / 2 + 1e-5
    assert ((got.depths > 0) == (depths > 0)).all()  # unknown stays unknown
    images = torch.cat([want_a.images, want_b.images]).float()
    # JPEG quality 90: lossy, but within 3 % of the range on average at 32 rows, where the
    # textures are finest (2 levels at 128 rows)
    assert (got.images.float() - images).abs().mean() < 8
    assert torch.equal(got.c2w, torch.cat([want_a.c2w, want_b.c2w]))
    assert torch.allclose(got.baselines, torch.cat([want_a.baselines, want_b.baselines]))
    # a folder of packs reads them in name order; limit counts scenes over all of them
    (tmp_path / "z.safetensors").write_bytes(pack.read_bytes())
    both = load_triplets(tmp_path, 32)
    assert len(both) == 10 and both.names[:5] == got.names
    assert len(load_triplets(tmp_path, 32, limit=7)) == 7


@pytest.mark.gl
def test_pack_refuses_bad_input_and_keeps_what_was_there(two_sets, tmp_path, capsys):
    a, _ = two_sets
    pack = tmp_path / "p.safetensors"
    pack.write_bytes(b"an earlier pack")
    assert main(["dataset", "pack", "--out", str(pack), f"{a}:2:5"]) == 2
    assert "has 3 scenes; cannot take [2, 7)" in capsys.readouterr().err
    assert pack.read_bytes() == b"an earlier pack"  # nothing written over it
    with pytest.raises(SystemExit):
        main(["dataset", "pack", "--out", str(pack), f"{a}:x:1"])
    assert main(["dataset", "pack", "--out", str(pack), str(tmp_path / "none")]) == 2
    assert "no dataset.json" in capsys.readouterr().err
    assert pack.read_bytes() == b"an earlier pack"
    assert main(["dataset", "pack", "--out", str(tmp_path / "p.npz"), str(a)]) == 2
    assert "--out must end in .safetensors" in capsys.readouterr().err
    (tmp_path / "dir.safetensors").mkdir()  # issue 57 T13: a folder of that name
    assert main(["dataset", "pack", "--out", str(tmp_path / "dir.safetensors"), str(a)]) == 2
    assert "is a folder" in capsys.readouterr().err
    with pytest.raises(UserError, match="not a readable pack"):
        read_packs(pack, 32)
    good = tmp_path / "good.safetensors"
    main(["dataset", "pack", "--out", str(good), "--height", "32", str(a)])
    with pytest.raises(UserError, match="training asks 64"):
        load_triplets(good, 64)
    with pytest.raises(UserError, match="from its first scene"):
        load_triplets(good, 32, start=1)
    # a truncated copy (an interrupted transfer) is refused, not half read
    cut = tmp_path / "cut" / "cut.safetensors"
    cut.parent.mkdir()
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(UserError, match="not a readable pack"):
        load_triplets(cut.parent, 32)


@pytest.mark.gl
def test_training_reads_a_pack_and_refuses_a_device_it_lacks(two_sets, tmp_path, capsys):
    a, _ = two_sets
    pack = tmp_path / "p.safetensors"
    main(["dataset", "pack", "--out", str(pack), "--height", "32", str(a)])
    out = tmp_path / "mono.safetensors"
    small = ["--data", str(pack), "--out", str(out), "--steps", "2", "--batch", "2"]
    small += ["--height", "32"]
    mono = ["train", "depth", "--stage", "mono", *small]
    assert main([*mono, "--device", "cpu"]) == 0
    with safe_open(str(out), framework="pt") as f:
        assert json.loads(f.metadata()["train"])["device"] == "cpu"
    # the MVS stage on a device: the frozen monocular network runs there too
    guided = ["train", "depth", "--stage", "mvs", "--preset", "full", "--mono", str(out)]
    guided += ["--mono-warp", "0.5", "--mono-shift", "0.5"]
    mvs_out = tmp_path / "mvs.safetensors"
    guided += ["--data", str(pack), "--out", str(mvs_out), "--steps", "2", "--batch", "2"]
    guided += ["--height", "32"]
    assert main([*guided, "--device", "cpu"]) == 0
    with safe_open(str(mvs_out), framework="pt") as f:
        assert json.loads(f.metadata()["train"])["device"] == "cpu"
        assert json.loads(f.metadata()["final"])["val_l1"] > 0
    if not torch.cuda.is_available():
        assert main([*mono, "--device", "cuda"]) == 2
        assert "not available here" in capsys.readouterr().err
        assert main([*guided, "--device", "cuda"]) == 2
        assert "not available here" in capsys.readouterr().err


@pytest.mark.gl
def test_a_colour_only_pack_is_a_third_and_only_the_renderer_takes_it(two_sets, tmp_path, capsys):
    a, _ = two_sets
    full, colour = tmp_path / "full.safetensors", tmp_path / "new" / "dir" / "c.safetensors"
    assert main(["dataset", "pack", "--out", str(full), "--height", "64", str(a)]) == 0
    # the pack's folder is made when missing
    args = ["dataset", "pack", "--out", str(colour), "--height", "64", "--colour-only", str(a)]
    assert main(args) == 0
    assert colour.stat().st_size < 0.7 * full.stat().st_size
    with pytest.raises(UserError, match="colour-only pack"):
        load_triplets(colour, 64)  # a depth training asks for the depth
    got, want = load_triplets(colour, 64, depth=False), load_triplets(full, 64)
    assert torch.equal(got.images, want.images) and torch.equal(got.c2w, want.c2w)
    assert got.names == want.names and got.depths.shape == want.depths.shape
    assert not got.depths.any()  # unknown everywhere
    assert got.subset([1]).depths.shape == (1, 3, 64, 128)
    # the renderer trains on a folder of them, on the device named
    weights = tmp_path / "r.safetensors"
    train = ["train", "renderer", "--data", str(colour.parent), "--out", str(weights)]
    train += ["--steps", "2", "--height", "64", "--rays", "32", "--threads", "2"]
    capsys.readouterr()
    assert main([*train, "--device", "cpu"]) == 0
    with safe_open(str(weights), framework="pt") as f:
        assert json.loads(f.metadata()["train"])["device"] == "cpu"
        assert json.loads(f.metadata()["final"])["val_ws_psnr_fast"] > 5
    # the depth it cached beside the packs is not taken for a pack
    assert any(p.name.startswith(".depth_full_") for p in colour.parent.iterdir())
    assert load_triplets(colour.parent, 64, depth=False).names == want.names
    assert main([*train, "--steps", "1"]) == 0  # and a second run reads the cache
    if not torch.cuda.is_available():
        assert main([*train, "--device", "cuda"]) == 2
        assert "not available here" in capsys.readouterr().err


@pytest.mark.gl
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_the_renderer_trains_on_a_gpu(two_sets, tmp_path):
    a, _ = two_sets
    pack = tmp_path / "packs" / "c.safetensors"
    main(["dataset", "pack", "--out", str(pack), "--height", "64", "--colour-only", str(a)])
    out = tmp_path / "r.safetensors"
    train = ["train", "renderer", "--data", str(pack.parent), "--out", str(out), "--steps", "2"]
    assert main([*train, "--height", "64", "--rays", "32", "--device", "cuda"]) == 0
    with safe_open(str(out), framework="pt") as f:
        assert json.loads(f.metadata()["train"])["device"] == "cuda"
        assert json.loads(f.metadata()["final"])["val_ws_psnr_fast"] > 5


@pytest.mark.gl
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_the_mvs_stage_trains_on_a_gpu(two_sets, tmp_path):
    a, _ = two_sets
    pack = tmp_path / "p.safetensors"
    main(["dataset", "pack", "--out", str(pack), "--height", "32", str(a)])
    mono = tmp_path / "mono.safetensors"
    small = ["--data", str(pack), "--steps", "2", "--batch", "2", "--height", "32"]
    assert main(["train", "depth", "--stage", "mono", *small, "--out", str(mono)]) == 0
    out = tmp_path / "mvs.safetensors"
    guided = ["train", "depth", "--stage", "mvs", "--preset", "full", "--mono", str(mono)]
    guided += ["--mono-warp", "0.5", "--mono-shift", "0.5", "--device", "cuda"]
    assert main([*guided, *small, "--out", str(out)]) == 0
    with safe_open(str(out), framework="pt") as f:
        assert json.loads(f.metadata()["train"])["device"] == "cuda"
        assert json.loads(f.metadata()["final"])["val_l1"] > 0  # measured on the CPU


def test_train_elsewhere_runs_panogrf_train_alone(tmp_path):
    """The wrapper for a machine without the GL packages registers `panogrf train` only."""
    script = ROOT / "lab" / "gpu" / "train_elsewhere.py"
    done = subprocess.run(
        [sys.executable, str(script), "train", "depth", "--help"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0 and "--device" in done.stdout
    done = subprocess.run(
        [
            sys.executable,
            str(script),
            "train",
            "depth",
            "--stage",
            "mono",
            "--data",
            str(tmp_path / "missing"),
            "--out",
            str(tmp_path / "x.safetensors"),
            "--steps",
            "1",
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 2 and "no dataset.json" in done.stderr
