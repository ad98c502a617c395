"""`panogrf depth`: the output is a valid scene, metadata and metrics, warnings, errors.

The core (`estimate_scene`) runs with randomly initialised networks, so these tests do not need
the shipped weights; one test runs the real CLI with them and skips itself while they are absent.
"""

from __future__ import annotations

import json
import math
import re
import shutil

import numpy as np
import pytest
import torch

from panogrf.app import cli
from panogrf.app import progress as app_progress
from panogrf.app.files.images import read_depth, read_rgb
from panogrf.app.scene.estimate import METADATA_KEY
from panogrf.app.scene.folder import check_scene, load_scene, write_scene
from panogrf.app.scene.session import estimate_scene
from panogrf.app.weights import networks as depth_weights
from panogrf.assets import path as asset_path
from panogrf.model.depth import DepthEstimator
from panogrf.model.mono import MonoDepthConfig, MonoDepthNet
from panogrf.model.mvs import PRESETS, MVSNet

DEMO = asset_path("demo")
SHIPPED = [asset_path(name) for name in depth_weights.depth_weight_files("full").values()]
MISSING = [p.name for p in SHIPPED if not p.exists()]


def random_estimator(
    modes: tuple[str, ...] = ("full",), working_height: int = 64
) -> DepthEstimator:
    """Seeded random networks at a small working size: the plumbing, not the accuracy."""
    torch.manual_seed(0)
    mvs = {mode: MVSNet(PRESETS[mode]) for mode in modes}
    estimator = DepthEstimator(MonoDepthNet(MonoDepthConfig()), mvs, working_height=working_height)
    return estimator.eval()


@pytest.fixture
def random_weights(monkeypatch):
    """Make the CLI load random networks instead of the shipped weights."""
    monkeypatch.setattr(
        depth_weights, "load_depth_estimator", lambda modes, device: random_estimator(modes)
    )


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("depth") / "out"
    return estimate_scene(DEMO, out, random_estimator(), "full", weights={"mono": "m.safetensors"})


def test_output_is_a_valid_scene_with_the_input_poses(demo_run):
    out = demo_run.out_dir
    assert check_scene(out) == []
    scene, source = load_scene(out), load_scene(DEMO)
    assert [f.name for f in scene.frames] == [f.name for f in source.frames]
    np.testing.assert_allclose(scene.c2w, source.c2w)
    assert scene.metadata["panogrf"] == source.metadata["panogrf"]  # input metadata kept
    for frame, original in zip(scene.frames, source.frames, strict=True):
        assert frame.depth_path == out / "depth" / f"{frame.name}.png"
        assert read_depth(frame.depth_path).shape == (256, 512)
        assert (read_depth(frame.depth_path) > 0).all()
        assert frame.image_path.read_bytes() == original.image_path.read_bytes()
        assert read_rgb(out / "preview" / f"{frame.name}.png").shape == (256, 512, 3)


def test_metadata_describes_the_run(demo_run):
    meta = json.loads((demo_run.out_dir / "transforms.json").read_text())[METADATA_KEY]
    names = ["frame_000", "frame_001", "frame_002"]
    assert meta["mode"] == "full" and meta["weights"] == {"mono": "m.safetensors"}
    assert meta["clamped_at_m"] == demo_run.d_max == 10.0
    assert list(meta["out_of_range_fraction"]) == names
    assert all(0.0 <= f <= 1.0 for f in meta["out_of_range_fraction"].values())
    assert meta["sources"]["frame_001"] == ["frame_000", "frame_002"]
    assert meta["warnings"] == []


def test_metrics_are_finite_per_view_and_mean(demo_run):
    assert demo_run.metrics is not None and len(demo_run.metrics) == 3
    for m in demo_run.metrics:
        assert m is not None and m.valid > 0
        assert all(math.isfinite(x) for x in (m.l1, m.rmse, m.ws_l1, m.ws_rmse))
    mean = demo_run.mean_metrics
    assert mean["l1"] == pytest.approx(np.mean([m.l1 for m in demo_run.metrics]))
    assert demo_run.seconds > 0


def test_mono_mode_needs_no_mvs_network(tmp_path):
    run = estimate_scene(DEMO, tmp_path / "out", random_estimator(modes=()), "mono")
    assert run.sources == ((), (), ())
    assert check_scene(tmp_path / "out") == []


def test_cli_prints_metrics_time_and_writes_the_scene(
    tmp_path, capsys, random_weights, monkeypatch
):
    monkeypatch.setattr(app_progress, "INTERVAL", 0.0)  # every stage shown, however short
    out = tmp_path / "out"
    assert cli.main(["depth", str(DEMO), "--out", str(out)]) == 0
    captured = capsys.readouterr()
    lines = captured.out.splitlines()
    # No warning on stderr: only the progress of the estimation's stages (not a terminal).
    progress = re.compile(r"^.+: \d+/\d+, elapsed \d+\.\d s, eta (\?|\d+\.\d s)$")
    assert [x for x in captured.err.splitlines() if not progress.match(x)] == []
    assert "depth: multi-view stereo: " in captured.err
    assert any(line.startswith("estimated depth (mode full) in ") for line in lines)
    header = next(i for i, line in enumerate(lines) if line.startswith("depth error"))
    assert "0 < gt <= 10 m" in lines[header]
    assert lines[header + 1].split() == ["view", "L1", "RMSE", "WS-L1", "WS-RMSE"]
    rows = [line.split() for line in lines[header + 2 : header + 6]]
    assert [r[0] for r in rows] == ["frame_000", "frame_001", "frame_002", "mean"]
    assert all(len(r) == 5 and all(math.isfinite(float(x)) for x in r[1:]) for r in rows)
    assert check_scene(out) == []
    weights = json.loads((out / "transforms.json").read_text())[METADATA_KEY]["weights"]
    assert weights == {
        "mono": "depth_mono.safetensors",
        "full": "depth_mvs_full.safetensors",
        "mvs": "depth_mvs_only.safetensors",  # fused with the mono-guided depth
        "select": "depth_select.safetensors",  # which of the two each pixel keeps
        "blend": "depth_blend.safetensors",  # and how much of the mono depth it takes back
    }
    # Running again into its own output folder is allowed (it is ours to overwrite).
    assert cli.main(["depth", str(DEMO), "--out", str(out), "--mode", "mono"]) == 0


def test_one_view_scene_warns_and_gives_mono_depth(tmp_path, capsys, random_weights):
    rng = np.random.default_rng(0)
    write_scene(tmp_path / "one", np.eye(4)[None], rng.random((1, 3, 16, 32), dtype=np.float32))
    args = ["depth", str(tmp_path / "one"), "--out", str(tmp_path / "out"), "--quiet"]
    assert cli.main(args) == 0  # --quiet: no progress lines, the warning alone on stderr
    captured = capsys.readouterr()
    assert captured.err.startswith("warning: one view only: monocular depth")
    assert "no ground-truth depth" in captured.out
    meta = json.loads((tmp_path / "out" / "transforms.json").read_text())[METADATA_KEY]
    assert meta["sources"] == {"view_000": []} and len(meta["warnings"]) == 1
    assert read_depth(tmp_path / "out" / "depth" / "view_000.png").shape == (16, 32)


def test_views_at_the_same_position_are_refused_by_the_scene_check(tmp_path, capsys):
    rng = np.random.default_rng(0)
    write_scene(tmp_path / "s", np.stack([np.eye(4)] * 2), rng.random((2, 3, 16, 32)))
    assert any("same position" in p for p in check_scene(tmp_path / "s"))
    assert cli.main(["depth", str(tmp_path / "s"), "--out", str(tmp_path / "out")]) == 2
    assert "same position" in capsys.readouterr().err


def test_estimator_drops_a_source_one_centimetre_away():
    images = torch.rand((2, 3, 16, 32), generator=torch.Generator().manual_seed(0))
    c2w = torch.eye(4).repeat(2, 1, 1)
    c2w[1, 0, 3] = 0.01
    est = random_estimator(working_height=32)(images, c2w, "full")
    assert torch.isfinite(est.depth).all() and est.sources == [[], []]
    assert any("within 0.05 m" in w for w in est.warnings)
    assert any("no usable source, monocular depth" in w for w in est.warnings)


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith("panogrf depth: error:") and "\n" not in err, err
    return err


def test_missing_scene_is_a_one_line_error(tmp_path, capsys, random_weights):
    assert cli.main(["depth", str(tmp_path / "nope"), "--out", str(tmp_path / "out")]) == 2
    assert "scene folder not found" in one_line_error(capsys)


def test_refuses_to_write_into_the_input_scene(tmp_path, capsys, random_weights):
    scene = tmp_path / "demo"
    shutil.copytree(DEMO, scene)
    before = (scene / "transforms.json").read_bytes()
    assert cli.main(["depth", str(scene), "--out", str(scene / ".." / "demo")]) == 2
    assert "refusing to overwrite" in one_line_error(capsys)
    assert (scene / "transforms.json").read_bytes() == before
    # Nor over another scene that is not an output of `panogrf depth`.
    other = tmp_path / "other"
    shutil.copytree(DEMO, other)
    assert cli.main(["depth", str(scene), "--out", str(other)]) == 2
    assert "not written by `panogrf depth`" in one_line_error(capsys)


def test_refuses_to_replace_a_folder_of_other_files_or_one_holding_the_input(
    tmp_path, capsys, random_weights
):
    """The output replaces its folder whole: a folder of other files, or the folder the input
    scene is in, would be lost (found by a hostile-input pass: both exited 0)."""
    mine = tmp_path / "mine"
    (mine / "sub").mkdir(parents=True)
    (mine / "important.txt").write_text("keep")
    assert cli.main(["depth", str(DEMO), "--out", str(mine)]) == 2
    assert "is not empty" in one_line_error(capsys)
    assert (mine / "important.txt").read_text() == "keep" and (mine / "sub").is_dir()
    work = tmp_path / "work"
    shutil.copytree(DEMO, work / "scene")
    (work / "notes.txt").write_text("keep")
    assert cli.main(["depth", str(work / "scene"), "--out", str(work)]) == 2
    assert "holds the input scene" in one_line_error(capsys)
    assert (work / "scene" / "transforms.json").is_file() and (work / "notes.txt").exists()


def test_out_may_be_the_current_folder(tmp_path, monkeypatch, random_weights):
    """``--out .`` (an empty folder) is written like any other (it raised on the folder's
    empty name)."""
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    assert cli.main(["depth", str(DEMO), "--out", ".", "--quiet"]) == 0
    assert (tmp_path / "here" / "transforms.json").is_file()


def test_unwritable_out_dir_is_a_one_line_error(tmp_path, capsys, random_weights):
    blocker = tmp_path / "file.txt"
    blocker.write_text("not a folder")
    assert cli.main(["depth", str(DEMO), "--out", str(blocker)]) == 2
    assert "not a folder" in one_line_error(capsys)
    assert cli.main(["depth", str(DEMO), "--out", str(blocker / "out")]) == 2
    assert "cannot write to" in one_line_error(capsys)


def test_missing_weights_is_a_one_line_error(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(depth_weights, "asset_path", lambda name: tmp_path / name)
    depth_weights.load_depth_estimator.cache_clear()
    try:
        assert cli.main(["depth", str(DEMO), "--out", str(tmp_path / "out")]) == 2
    finally:
        depth_weights.load_depth_estimator.cache_clear()
    err = one_line_error(capsys)
    assert "missing weights" in err and "depth_mono.safetensors" in err
    assert not (tmp_path / "out" / "transforms.json").exists()


@pytest.mark.skipif(bool(MISSING), reason=f"shipped weights missing ({', '.join(MISSING)})")
def test_mode_full_chooses_with_the_shipped_selector_and_needs_it(tmp_path, monkeypatch):
    """Mode full's estimator carries the fusion's selector (`depth_select.safetensors`),
    mode mvs's none; a weights folder without the selector is refused by name."""
    from panogrf.app.errors import UserError
    from panogrf.model.select import HypothesisSelector

    assert isinstance(
        depth_weights.load_depth_estimator(("full", "mvs")).selector, HypothesisSelector
    )
    assert depth_weights.load_depth_estimator(("mvs",)).selector is None
    for path in SHIPPED:
        if path.name != depth_weights.SELECTOR:
            (tmp_path / path.name).symlink_to(path)
    monkeypatch.setenv("PANOGRF_WEIGHTS", str(tmp_path))
    depth_weights.load_depth_estimator.cache_clear()
    try:
        with pytest.raises(UserError, match="missing weights .*depth_select.safetensors"):
            depth_weights.load_depth_estimator(("full", "mvs"))
    finally:
        depth_weights.load_depth_estimator.cache_clear()


@pytest.mark.skipif(bool(MISSING), reason=f"shipped weights missing ({', '.join(MISSING)})")
def test_the_blend_is_used_and_keys_the_depth_where_its_file_is(tmp_path, monkeypatch):
    """Mode full's estimator blends with the monocular depth where `depth_blend.safetensors` is
    among the weights (and the file is then among those that key a scene's depth cache); a
    folder without it gives the fused depth alone."""
    from panogrf.app.train.loop import save_weights
    from panogrf.model.blend import BlendConfig, DepthBlend

    for path in SHIPPED:
        if path.name != depth_weights.BLEND:
            (tmp_path / path.name).symlink_to(path)
    monkeypatch.setenv("PANOGRF_WEIGHTS", str(tmp_path))
    depth_weights.load_depth_estimator.cache_clear()
    try:
        assert depth_weights.load_depth_estimator(("full", "mvs")).blend is None
        assert "blend" not in depth_weights.depth_weight_files("full")
        blend = DepthBlend(BlendConfig())
        save_weights(
            blend, tmp_path / depth_weights.BLEND, {"config": {"channels": 32, "rows": 128}}
        )
        depth_weights.load_depth_estimator.cache_clear()
        loaded = depth_weights.load_depth_estimator(("full", "mvs")).blend
        assert isinstance(loaded, DepthBlend)
        assert depth_weights.depth_weight_files("full")["blend"] == depth_weights.BLEND
        assert "blend" not in depth_weights.depth_weight_files("mvs")
        assert depth_weights.load_depth_estimator(("mvs",)).blend is None
        for name, t in blend.state_dict().items():
            torch.testing.assert_close(loaded.state_dict()[name], t)
    finally:
        depth_weights.load_depth_estimator.cache_clear()


def test_a_selector_saved_before_the_scene_summary_loads_as_a_local_one(tmp_path):
    """Round 14's selector file has no "context" in its config: it loads without the summary;
    the shipped one (round 15) has it."""
    import json

    from safetensors.torch import save_file

    from panogrf.model.select import HypothesisSelector, SelectorConfig

    old = HypothesisSelector(SelectorConfig())
    path = tmp_path / "depth_select.safetensors"
    config = {"channels": 32, "rows": 128}
    save_file(old.state_dict(), str(path), metadata={"config": json.dumps(config)})
    assert depth_weights.load_selector(path).context is None
    shipped = depth_weights.load_selector(depth_weights.weights_path(depth_weights.SELECTOR))
    assert shipped.config.context and shipped.context is not None


def test_help_has_an_example_and_depth_follows_scene(capsys):
    assert cli._COMMANDS.index("depth") == cli._COMMANDS.index("scene") + 1
    with pytest.raises(SystemExit) as exc:
        cli.main(["depth", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "example: panogrf depth" in out and "--mode" in out and "preview/" in out


@pytest.mark.slow
@pytest.mark.skipif(
    bool(MISSING), reason=f"shipped depth weights not trained yet ({', '.join(MISSING)} missing)"
)
def test_cli_with_the_shipped_weights(tmp_path, capsys):
    assert cli.main(["depth", str(DEMO), "--out", str(tmp_path / "out"), "--mode", "full"]) == 0
    out = capsys.readouterr().out
    assert "depth error vs ground truth" in out and "mean" in out
    assert check_scene(tmp_path / "out") == []


def test_a_failed_rerun_leaves_the_earlier_output_whole(
    tmp_path, capsys, random_weights, monkeypatch
):
    """Issue 57 D1: a disk filling up after the first view of a rerun left new and old views
    side by side under the old transforms.json; the output is now swapped in whole."""
    import errno

    from panogrf.app.files import images

    out = tmp_path / "out"
    assert cli.main(["depth", str(DEMO), "--out", str(out)]) == 0
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    write = images.write_depth
    calls = []

    def fills_up(path, depth):
        calls.append(path)
        if len(calls) > 1:
            raise OSError(errno.ENOSPC, "No space left on device")
        write(path, depth)

    monkeypatch.setattr(images, "write_depth", fills_up)
    assert cli.main(["depth", str(DEMO), "--out", str(out), "--mode", "mono"]) == 2
    assert "No space left on device" in capsys.readouterr().err
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before  # every file the earlier run wrote, none of the failed one's
    assert [p.name for p in tmp_path.iterdir()] == ["out"]  # no temporary left
