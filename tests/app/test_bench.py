"""`panogrf bench`: the Pareto frontier, the hard cases are what they say, no method returns
NaN, inf or an empty image in any of them, and the command on a tiny dataset."""

from __future__ import annotations

import json
import math
import shutil
import time

import numpy as np
import pytest
import torch

from panogrf.app import cli
from panogrf.app.bench.cases import CASES, case_scene, make_cases
from panogrf.app.bench.frontier import pareto_front
from panogrf.app.bench.run import image_problems
from panogrf.app.bench.settings import SETTINGS, GLContext, release_scene, render_setting
from panogrf.assets import path as asset_path


def test_pareto_front_by_hand():
    cost = [1.0, 2.0, 3.0, 0.5, 2.0, 10.0]
    quality = [20.0, 25.0, 24.0, 10.0, 25.0, 30.0]
    # 2 is beaten by 1 (cheaper, better); 4 ties 1 exactly and comes later.
    assert pareto_front(cost, quality) == [3, 0, 1, 5]


def test_pareto_front_skips_nan_and_handles_lower_is_better():
    lpips = [0.3, math.nan, 0.1, 0.2]
    cost = [1.0, 0.1, 5.0, 6.0]
    assert pareto_front(cost, [-x for x in lpips]) == [0, 2]
    assert pareto_front([], []) == []


def test_image_problems():
    ok = torch.rand(3, 4, 8, generator=torch.Generator().manual_seed(0))
    assert image_problems(ok, 4) == []
    assert image_problems(ok, 5) == ["shape (3, 4, 8), expected (3, 5, 10)"]
    bad = ok.clone()
    bad[0, 0, 0] = math.nan
    assert image_problems(bad, 4) == ["NaN or inf"]
    bad[0, 0, 0] = math.inf
    assert image_problems(bad, 4) == ["NaN or inf"]
    assert image_problems(torch.zeros(3, 4, 8), 4) == ["empty: every pixel 0.000"]
    assert "no pixels" in image_problems(torch.zeros(3, 0, 0), 4)


@pytest.mark.parametrize("name", CASES)
def test_cases_are_what_they_say(name):
    scene, sources, target = case_scene(name, 7, n_layers=10)
    cams = scene.cameras[:, :3, 3]
    src = cams[sources]
    t = target[:3, 3]
    line = src[-1] - src[0]
    along = float(np.dot(t - src[0], line) / np.dot(line, line))
    off = np.linalg.norm(t - (src[0] + along * line))
    if name == "off_line":
        assert 0.3 <= off <= np.hypot(0.3, 0.1) + 1e-6  # the line may rise a little
    elif name == "extrapolation":
        assert along == pytest.approx(2.0) and off < 1e-6  # as far beyond as the sources span
    elif name == "at_source":
        assert np.allclose(target, scene.cameras[sources[0]])
    else:
        assert along == pytest.approx(0.5) and off < 1e-6
    if name == "textureless":
        assert {o.material.layer for o in scene.objects} == {9}
    if name == "poles":
        above = [o for o in scene.objects if o.name == "A_pole_top"][0].mesh.bounds
        below = [o for o in scene.objects if o.name == "A_pole_bottom"][0].mesh.bounds
        for b in (above, below):
            assert b[0][0] < t[0] < b[1][0] and b[0][2] < t[2] < b[1][2]  # straight over / under
        assert above[0][1] > t[1] > below[1][1]
    if name == "occlusion":
        assert len([o for o in scene.objects if o.name.startswith("A_")]) >= 6


@pytest.fixture(scope="module")
def cases():
    return make_cases(32, CASES, sweep=(0.2, 5.0))


@pytest.mark.gl
@pytest.mark.slow
def test_no_setting_returns_nan_inf_or_empty_in_any_case(cases):
    from panogrf.app.scene.session import default_models
    from panogrf.renderer.methods import SourceViews
    from panogrf.renderer.snerf import SNeRFConfig, fit_snerf

    models = default_models()
    gl = GLContext()
    assert {c.name for c in cases} == set(CASES) | {"sweep 0.2 m", "sweep 5 m"}
    failures = []
    try:
        for case in cases:
            assert torch.isfinite(case.target).all() and case.target.std() > 0
            views = SourceViews(case.images, case.c2w)
            # The real fit takes a minute: the same code with a short schedule.
            quick = SNeRFConfig(grid=(8, 8, 16), steps=5, rays=256, samples=8, fit_height=16)
            views.fitted["snerf"] = fit_snerf(views.images, views.c2w, quick)
            for s in SETTINGS:
                rgb = render_setting(s, views, case.target_c2w, 32, models, gl)
                failures += [f"{case.name}/{s.name}: {p}" for p in image_problems(rgb, 32)]
            release_scene(views)
    finally:
        gl.release()
    assert failures == []


@pytest.mark.gl
@pytest.mark.slow
def test_bench_command_on_a_tiny_dataset(tmp_path, capsys):
    demo = asset_path("demo")
    root = tmp_path / "data"
    root.mkdir()
    shutil.copytree(demo, root / "a")
    (root / "dataset.json").write_text(json.dumps({"scenes": [{"folder": "a"}]}))
    frames = json.loads((demo / "transforms.json").read_text())["frames"]
    p = np.array([f["transform_matrix"] for f in frames])[:, :3, 3]
    baseline = round(float(np.linalg.norm(p[2] - p[0])), 1)
    out = tmp_path / "bench"
    args = ["bench", str(root), "--out", str(out), "--baselines", str(baseline)]
    args += ["--height", "32", "--time-height", "48", "--case-height", "32", "--sweep", "0.5"]
    args += ["--sweep-scenes", "2"]
    args += ["--cases", "at_source", "--settings", "nearest,gl:32,panogrf:draft", "--real", "none"]
    assert cli.main(args + ["--threads", "1"]) == 0
    for name in ("results.json", "table.md", "frontier.png", "stability.png", "gallery.png"):
        assert (out / name).stat().st_size > 0, name
    report = json.loads((out / "results.json").read_text())
    assert list(report["results"]) == ["nearest", "gl:32", "panogrf:draft"]
    r = report["results"]["panogrf:draft"]
    assert r["seconds"] > 0 and r["params"] > 0 and r["time_scaled"] is False
    assert set(r["sweep"]) == {"0.5"} and set(r["cases"]) == {"at_source"}
    swept = r["sweep"]["0.5"]  # two scenes: their mean and spread
    assert swept["n"] == 2 and swept["ws_psnr_min"] <= swept["ws_psnr"] <= swept["ws_psnr_max"]
    assert swept["ws_psnr_min"] < swept["ws_psnr_max"] and swept["ws_psnr_std"] > 0
    # The cheapest setting (by the time measured in this run: any of them on a loaded
    # machine) is always on the frontier.
    cheapest = min(report["results"], key=lambda k: report["results"][k]["seconds"])
    assert cheapest in report["frontier"]["ws_psnr"]
    assert report["problems"] == {}
    from panogrf.model import refine

    # The per-scene refinement, as the CLI's default (conftest's quick one in tests).
    assert report["config"]["refine_depth"] == repr(refine.PREPARE_REFINE)
    chain = report["depth_chain"]  # the shipped chain's networks and its preparation
    assert list(chain["networks"]) == [
        "monocular",
        "MVS mono-guided",
        "MVS unguided",
        "selector",
        "blend",
    ]
    assert all(n > 0 for n in chain["networks"].values()) and chain["prepare_s_median"] > 0
    table = (out / "table.md").read_text()
    assert "`panogrf:draft`" in table and "at_source" in table
    assert table.startswith("Depth chain (mode full): 5 networks, ")
    assert "panogrf:draft" in capsys.readouterr().out


def test_bench_refuses_an_unknown_setting(tmp_path, capsys):
    args = ["bench", str(tmp_path), "--out", str(tmp_path / "o"), "--settings", "nope"]
    assert cli.main(args) == 2
    assert "unknown setting 'nope'" in capsys.readouterr().err
    for empty in (["--settings", ""], ["--settings", "no_mono", "--skip", "no_mono"]):
        assert cli.main([*args[:4], *empty]) == 2  # nothing to run is a slip, not "all"
        assert "no setting left to run" in capsys.readouterr().err


def test_peak_memory_counts_what_a_block_holds_at_once_even_in_reused_memory():
    from panogrf.app.bench.settings import PeakMemory
    from panogrf.app.runtime import heap_in_use, keep_freed_memory

    if heap_in_use() is None:
        pytest.skip("needs glibc's mallinfo2")
    keep_freed_memory()
    peaks = []
    for _ in range(2):  # the second time the allocator reuses the freed pages
        with PeakMemory(interval=0.001) as mem:
            x = torch.ones(64, 2**18)  # 64 MiB
            y = x + 1  # 64 MiB more, both alive
            time.sleep(0.02)
            del x, y
        peaks.append(mem.mib)
    assert mem.kind == "heap"
    assert all(120 <= p <= 140 for p in peaks), peaks


def test_bench_settings_check_themselves_when_built_directly(tmp_path):
    from panogrf.app.bench.run import BenchConfig
    from panogrf.app.bench.settings import SETTINGS
    from panogrf.app.errors import UserError

    with pytest.raises(UserError, match="^--time-height must be between 8 and 4096, got 4$"):
        BenchConfig(tmp_path, SETTINGS, time_height=4)
    with pytest.raises(UserError, match="^--case-height must be between 8 and 4096, got 5000$"):
        BenchConfig(tmp_path, SETTINGS, case_height=5000)
    with pytest.raises(UserError, match="leave no setting"):
        BenchConfig(tmp_path, ())
    with pytest.raises(UserError, match=r"^--cases: unknown \['nope'\]"):
        BenchConfig(tmp_path, SETTINGS, cases=("at_source", "nope"))
    assert BenchConfig(tmp_path, SETTINGS, cases=(), sweep=()).height == 256


def test_bench_parses_its_cases_and_leaves_out_blanks(tmp_path, capsys):
    args = ["bench", str(tmp_path), "--out", str(tmp_path / "o"), "--cases", "poles, x,"]
    assert cli.main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith(f"--cases: unknown ['x']; choose from {','.join(CASES)}")
