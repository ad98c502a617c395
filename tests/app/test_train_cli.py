"""`panogrf train depth` as a smoke test: a few steps of each stage on a tiny dataset (CI never
trains for real). Checks that weights are written with their metadata and load back."""

from __future__ import annotations

import json

import pytest
import torch
from safetensors import safe_open
from safetensors.torch import load_file

from panogrf.app.cli import main
from panogrf.app.synth.make import MakeConfig, make_dataset


@pytest.fixture(scope="module")
def tiny_train(tmp_path_factory):
    root = tmp_path_factory.mktemp("train")
    make_dataset(MakeConfig(out=root, split="train", count=4, height=64), progress=False)
    return root


@pytest.mark.gl
def test_train_mono_then_mvs_smoke(tiny_train, tmp_path, capsys):
    mono = tmp_path / "mono.safetensors"
    common = ["--data", str(tiny_train), "--steps", "2", "--batch", "2", "--height", "32"]
    assert main(["train", "depth", "--stage", "mono", "--out", str(mono), *common]) == 0
    with safe_open(str(mono), framework="pt") as f:
        meta = f.metadata()
    assert meta["network"] == "MonoDepthNet"
    assert set(json.loads(meta["final"])) >= {"val_l1", "val_rmse", "steps"}
    assert "train depth" in meta["command"] or meta["command"].startswith("panogrf")

    for preset in ("full", "mvs"):
        out = tmp_path / f"mvs_{preset}.safetensors"
        args = ["train", "depth", "--stage", "mvs", "--preset", preset, "--out", str(out)]
        wrong = ["--mono-shift", "1", "--mono-heights", "1", "--mono-warp", "1"]
        wrong += ["--mono-features-shift", "1"]
        assert main([*args, "--mono", str(mono), *wrong, *common]) == 0
        with safe_open(str(out), framework="pt") as f:
            assert f.metadata()["preset"] == preset
            assert all(torch.isfinite(f.get_tensor(k)).all() for k in f.keys())
    log = capsys.readouterr().out
    assert "step     2" in log and "final" in log


@pytest.mark.gl
def test_train_mono_with_the_pretrained_trunk(tiny_train, tmp_path):
    """--trunk fills the frozen AlexNet convolutions from the bundled LPIPS weights; training
    leaves them as they were, and the mono-guided MVS trains on the result."""
    from safetensors.torch import load_file

    from panogrf import assets
    from panogrf.app.train.depth import load_mono

    mono = tmp_path / "mono.safetensors"
    common = ["--data", str(tiny_train), "--steps", "2", "--batch", "2", "--height", "32"]
    args = ["train", "depth", "--stage", "mono", "--trunk", "2", "--out", str(mono)]
    assert main([*args, *common]) == 0
    alex = load_file(str(assets.path("lpips_alex.safetensors")))
    trained = load_file(str(mono))
    assert trained and not [k for k in trained if k.startswith("trunk.")]  # stored once: LPIPS's
    loaded = load_mono(mono)
    assert loaded.config.trunk == 2 and len(loaded.trunk.convs) == 2
    for key in ("convs.0.weight", "convs.1.bias"):
        assert torch.equal(loaded.trunk.state_dict()[key], alex[key].float())
    out = tmp_path / "full.safetensors"
    args = ["train", "depth", "--stage", "mvs", "--preset", "full", "--out", str(out)]
    assert main([*args, "--mono", str(mono), *common]) == 0
    bad = ["train", "depth", "--stage", "mono", "--trunk", "5", "--out", str(mono), *common]
    assert main(bad) == 2


def test_train_errors(tmp_path, capsys):
    assert (
        main(["train", "depth", "--data", str(tmp_path), "--stage", "mono", "--out", "x.pt"]) == 2
    )
    assert "safetensors" in capsys.readouterr().err
    out = str(tmp_path / "m.safetensors")
    assert main(["train", "depth", "--data", str(tmp_path), "--stage", "mono", "--out", out]) == 2
    assert "dataset.json" in capsys.readouterr().err
    args = ["train", "depth", "--data", str(tmp_path), "--stage", "mvs", "--out", out]
    assert main(args) == 2
    assert "--mono" in capsys.readouterr().err
    fractions = (
        "--mono-noise",
        "--mono-shift",
        "--mono-features-shift",
        "--mono-heights",
        "--mono-warp",
    )
    for flag in fractions:
        bad = ["train", "depth", "--data", str(tmp_path), "--stage", "mono", "--out", out]
        assert main([*bad, flag, "1.5"]) == 2
        assert f"{flag} is a fraction" in capsys.readouterr().err


@pytest.mark.gl
def test_train_renderer_smoke(tiny_train, tmp_path, capsys):
    out = tmp_path / "renderer.safetensors"
    args = ["train", "renderer", "--data", str(tiny_train), "--out", str(out), "--steps", "2"]
    assert main([*args, "--scenes", "1", "--rays", "16", "--height", "64"]) == 0
    with safe_open(str(out), framework="pt") as f:
        meta = f.metadata()
        assert meta["network"] == "RendererNet" and meta["preset"] == "panogrf"
        assert all(torch.isfinite(f.get_tensor(k)).all() for k in f.keys())
    assert {"val_ws_psnr_fast", "val_ws_psnr_paper"} <= set(json.loads(meta["final"]))
    # The estimated depths of the training pairs were cached beside the data.
    assert list(tiny_train.glob(".depth_full_*.safetensors"))
    log = capsys.readouterr().out
    assert "step     2" in log and "final" in log


def test_train_renderer_errors(tmp_path, capsys):
    base = ["train", "renderer", "--data", str(tmp_path)]
    assert main([*base, "--out", "x.pt"]) == 2
    assert "safetensors" in capsys.readouterr().err
    assert main([*base, "--out", str(tmp_path / "r.safetensors"), "--height", "100"]) == 2
    assert "multiple of 64" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.gl
def test_train_select_smoke(tiny_train, tmp_path, capsys):
    """The selector records the shipped networks' fusion on a few scenes (cached beside the
    data, the second run reading the cache), trains a few steps and writes weights that
    `load_selector` reads back."""
    from panogrf.app.weights.networks import load_selector

    out = tmp_path / "select.safetensors"
    args = ["train", "select", "--data", str(tiny_train), "--out", str(out), "--height", "64"]
    assert main([*args, "--scenes", "1", "--steps", "2", "--batch", "2"]) == 0
    with safe_open(str(out), framework="pt") as f:
        meta = f.metadata()
        assert meta["network"] == "HypothesisSelector"
        assert all(torch.isfinite(f.get_tensor(k)).all() for k in f.keys())
    assert json.loads(meta["config"])["context"] is True  # the scene summary by default
    final = json.loads(meta["final"])
    assert {"l1_rule", "l1_selector", "l1_truth"} <= set(final)
    # The truth's choice is never worse than either hypothesis alone, nor than the rule.
    assert final["l1_truth"] <= min(final["l1_rule"], final["l1_guided"], final["l1_unguided"])
    caches = list(tiny_train.glob(".select_*.safetensors"))
    assert len(caches) == 2  # the training scenes and the held-back ones
    assert "final" in capsys.readouterr().out
    load_selector(out)
    stamp = [c.stat().st_mtime_ns for c in caches]
    assert main([*args, "--scenes", "1", "--steps", "1", "--batch", "2"]) == 0
    assert [c.stat().st_mtime_ns for c in caches] == stamp
    # A cache that is not a record (broken, or of another format) is rebuilt, never trusted.
    caches[0].write_bytes(b"not safetensors")
    assert main([*args, "--scenes", "1", "--steps", "1", "--batch", "2", "--no-context"]) == 0
    assert "unreadable" in capsys.readouterr().out
    assert load_selector(out).context is None  # round 14's local selector
    # Wrong room heights in the mono prior are another recording (its own cache).
    assert (
        main([*args, "--scenes", "1", "--steps", "1", "--batch", "2", "--mono-heights", "1"]) == 0
    )
    assert len(list(tiny_train.glob(".select_*.safetensors"))) == 4
    # So are the monocular features out of the domain with its depth right (round 34), and
    # what the mono-guided search ends at moves with them: the selector has something to read.
    plain = {c.name for c in tiny_train.glob(".select_*.safetensors")}
    features = [*args, "--scenes", "1", "--steps", "1", "--batch", "2"]
    assert main([*features, "--mono-shift", "0", "--mono-features-shift", "1"]) == 0
    assert main([*features, "--mono-shift", "0"]) == 0
    fresh = sorted(
        (c for c in tiny_train.glob(".select_*.safetensors") if c.name not in plain),
        key=lambda c: c.stat().st_mtime_ns,
    )
    assert len(fresh) == 4  # training and held-back scenes, with and without the features
    shifted, unshifted = load_file(str(fresh[0])), load_file(str(fresh[2]))
    assert shifted["ends"].shape == unshifted["ends"].shape
    assert not torch.equal(shifted["ends"][:, 0], unshifted["ends"][:, 0])
    assert torch.equal(shifted["ends"][:, 1], unshifted["ends"][:, 1])
    # Recording ran the rule on the shared, cached estimator; it keeps its shipped selector.
    from panogrf.app.weights.networks import load_depth_estimator

    assert load_depth_estimator(("full", "mvs")).selector is not None


@pytest.mark.slow
@pytest.mark.gl
def test_train_blend_smoke(tiny_train, tmp_path, capsys):
    """The blend records the shipped pipeline's fusion on a few scenes (cached beside the data,
    the second run reading the cache), trains a few steps and writes weights that `load_blend`
    reads back; the shared estimator keeps what it had."""
    from panogrf.app.weights.networks import load_blend, load_depth_estimator

    before = load_depth_estimator(("full", "mvs")).blend
    out = tmp_path / "blend.safetensors"
    args = ["train", "blend", "--data", str(tiny_train), "--out", str(out), "--height", "64"]
    assert main([*args, "--scenes", "1", "--steps", "2", "--batch", "2"]) == 0
    with safe_open(str(out), framework="pt") as f:
        meta = f.metadata()
        assert meta["network"] == "DepthBlend"
        assert all(torch.isfinite(f.get_tensor(k)).all() for k in f.keys())
    final = json.loads(meta["final"])
    # The better depth per pixel is never worse than either depth alone.
    assert final["l1_better_per_pixel"] <= min(final["l1_fused"], final["l1_mono"])
    assert final["l1_blend"] > 0
    caches = list(tiny_train.glob(".blend_*.safetensors"))
    assert len(caches) == 2  # the training scenes and the held-back ones
    load_blend(out)
    stamp = [c.stat().st_mtime_ns for c in caches]
    assert main([*args, "--scenes", "1", "--steps", "1", "--batch", "2"]) == 0
    assert [c.stat().st_mtime_ns for c in caches] == stamp
    caches[0].write_bytes(b"not safetensors")
    assert main([*args, "--scenes", "1", "--steps", "1", "--batch", "2"]) == 0
    assert "unreadable" in capsys.readouterr().out
    # Wrong heights per view and one wrong room per scene are two more recordings, each of
    # the training scenes and of the held-back ones.
    heights = [*args, "--scenes", "1", "--steps", "1", "--batch", "2", "--mono-heights", "1"]
    assert main(heights) == 0
    assert main([*heights, "--mono-heights-shared"]) == 0
    assert len(list(tiny_train.glob(".blend_*.safetensors"))) == 6
    assert load_depth_estimator(("full", "mvs")).blend is before


def test_train_blend_errors(tmp_path, capsys):
    base = ["train", "blend", "--data", str(tmp_path)]
    assert main([*base, "--out", "x.pt"]) == 2
    assert "safetensors" in capsys.readouterr().err
    assert main([*base, "--out", str(tmp_path / "b.safetensors"), "--mono-shift", "2"]) == 2
    assert "0-1" in capsys.readouterr().err
    assert main([*base, "--out", str(tmp_path / "b.safetensors"), "--steps", "0"]) == 2
    assert "at least 1" in capsys.readouterr().err


def test_train_select_errors(tmp_path, capsys):
    base = ["train", "select", "--data", str(tmp_path)]
    assert main([*base, "--out", "x.pt"]) == 2
    assert "safetensors" in capsys.readouterr().err
    assert main([*base, "--out", str(tmp_path / "s.safetensors"), "--mono-shift", "2"]) == 2
    assert "0-1" in capsys.readouterr().err
    assert main([*base, "--out", str(tmp_path / "s.safetensors"), "--mono-heights", "-1"]) == 2
    assert "0-1" in capsys.readouterr().err
    assert main([*base, "--out", str(tmp_path / "s.safetensors"), "--mono-heights-shared"]) == 2
    assert "--mono-heights above 0" in capsys.readouterr().err
    assert (
        main([*base, "--out", str(tmp_path / "s.safetensors"), "--mono-features-shift", "1.5"]) == 2
    )
    assert "--mono-features-shift" in capsys.readouterr().err
    assert main([*base, "--out", str(tmp_path / "s.safetensors"), "--scenes", "0"]) == 2
    assert "at least 1" in capsys.readouterr().err
    assert main([*base, "--out", str(tmp_path / "s.safetensors"), "--height", "100"]) == 2
    assert "multiple of 32" in capsys.readouterr().err


@pytest.mark.gl
def test_train_renderer_on_shipped_depth(tiny_train, tmp_path, capsys):
    """--depth shipped trains on the depth the app renders with (the fusion and the per-scene
    refinement of the outer pair), cached beside the data; a broken cache is rebuilt."""
    from safetensors.torch import load_file

    from panogrf.app.scene.session import default_models
    from panogrf.app.train.data import load_triplets
    from panogrf.model.refine import PREPARE_REFINE
    from panogrf.renderer.methods import SourceViews

    out = tmp_path / "renderer.safetensors"
    args = ["train", "renderer", "--data", str(tiny_train), "--out", str(out), "--steps", "2"]
    args += ["--scenes", "1", "--rays", "16", "--height", "64", "--limit-scenes", "2"]
    assert main([*args, "--depth", "shipped"]) == 0
    with safe_open(str(out), framework="pt") as f:
        assert json.loads(f.metadata()["train"])["depth"] == "shipped"
    (cache,) = tiny_train.glob(".depth_shipped_*.safetensors")
    # Copies: the file is overwritten below, and load_file maps it.
    cached = {k: v.clone() for k, v in load_file(str(cache)).items()}
    assert set(cached) == {"r0s2", "r2s0"} and cached["r0s2"].shape[0] == 2

    # The cache holds what a scene prepared by the app has: scene 1's outer views, refined.
    data = load_triplets(tiny_train, 64, 2)
    views = SourceViews(data.images[1, [0, 2]].float() / 255, data.c2w[1, [0, 2]])
    views.refine = PREPARE_REFINE
    depth = views.depth_for("full", default_models())
    assert torch.allclose(cached["r0s2"][1].float(), depth[0], rtol=2e-3, atol=2e-3)
    assert torch.allclose(cached["r2s0"][1].float(), depth[1], rtol=2e-3, atol=2e-3)

    cache.write_bytes(b"not a safetensors file")
    capsys.readouterr()
    assert main([*args, "--depth", "shipped"]) == 0
    assert "unreadable" in capsys.readouterr().out
    rebuilt = load_file(str(cache))
    assert torch.equal(rebuilt["r0s2"], cached["r0s2"])


@pytest.mark.gl
def test_shipped_depth_resumes_after_an_interruption(tiny_train, tmp_path, monkeypatch):
    """A run stopped part-way keeps what it computed (a partial file) and the next run goes on
    from there; the result is the same as one run's."""
    from panogrf.app.scene.session import default_models
    from panogrf.app.train import renderer as tr
    from panogrf.app.train.data import load_triplets
    from panogrf.renderer.methods import SourceViews

    data = load_triplets(tiny_train, 64, 3)
    (tmp_path / "whole").mkdir()
    whole = tr.shipped_depths(default_models(), data, tmp_path / "whole", log=lambda _: None)
    monkeypatch.setattr(tr, "SAVE_EVERY", 1)
    real, calls = SourceViews.depth_for, []

    def stop_at_the_third(self, mode, models):
        calls.append(mode)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(self, mode, models)

    root = tmp_path / "stopped"
    root.mkdir()
    monkeypatch.setattr(SourceViews, "depth_for", stop_at_the_third)
    with pytest.raises(KeyboardInterrupt):
        tr.shipped_depths(default_models(), data, root, log=lambda _: None)
    assert len(list(root.glob("*.partial.safetensors"))) == 1
    lines: list[str] = []
    resumed = tr.shipped_depths(default_models(), data, root, log=lines.append)
    assert any("after 2 of 3 scenes" in line for line in lines)
    assert len(calls) == 4  # the third scene only, once more
    assert not list(root.glob("*.partial.safetensors"))
    for k in ("r0s2", "r2s0"):
        assert torch.equal(resumed[k], whole[k])


def test_outer_only_samples_render_from_the_outer_views():
    from panogrf.app.train.renderer import _configuration

    gen = torch.Generator().manual_seed(0)
    seen = {(t, tuple(s)) for t, s in (_configuration(gen, True) for _ in range(200))}
    assert seen == {(1, (0, 2)), (0, (0, 2)), (2, (0, 2))}
    seen = {(t, tuple(s)) for t, s in (_configuration(gen) for _ in range(200))}
    assert (0, (1, 2)) in seen and (2, (0, 1)) in seen
