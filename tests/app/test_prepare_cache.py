"""One prepared scene for every command, and the progress of its preparation.

- Every stage of a real preparation (depth estimation's stages, the per-scene refinement,
  feature maps) reports each of its units, and the units are small: a stage per pass over the
  views, a unit per view or per step, never one long silent call.
- The terminal shows them on stderr: plain ``stage: k/n, elapsed, eta`` lines when stderr is
  not a terminal, at most one a second per stage, and a heartbeat while a unit takes long
  (checked with a fake clock); ``--quiet`` silences them.
- `scene prepare` writes what `render` then loads ("loaded", the same pixels); a corrupted
  cache file is rebuilt; networks other than the shipped ones are never cached.
"""

from __future__ import annotations

import io
import json
import re
import threading
import time

import numpy as np
import pytest
import torch
from helpers.nets import random_models

from panogrf.app import cli
from panogrf.app import progress as app_progress
from panogrf.app.files.images import read_rgb
from panogrf.app.progress import TerminalProgress
from panogrf.app.scene import session
from panogrf.app.scene.folder import load_scene, write_scene
from panogrf.assets import path as asset_path
from panogrf.model import progress

DEMO = asset_path("demo")
#: A plain progress line: ``stage: k/n, elapsed 1.2 s, eta 3.4 s`` (eta ``?`` before a unit).
LINE = re.compile(r"^(?P<name>.+): (?P<k>\d+)/(?P<n>\d+), elapsed \d+\.\d s, eta (\?|\d+\.\d s)$")


@pytest.fixture(scope="module")
def small_demo(tmp_path_factory):
    """The bundled scene at 64 rows (128 columns), with its depth."""
    scene = load_scene(DEMO, load_images=True)
    images = torch.nn.functional.interpolate(scene.images.images, size=(64, 128), mode="area")
    depths = torch.nn.functional.interpolate(scene.images.depths, size=(64, 128), mode="nearest")
    root = tmp_path_factory.mktemp("small") / "demo64"
    write_scene(root, scene.c2w, images, depths, names=[f.name for f in scene.frames])
    return root


class Recorder:
    """Every stage event, with the wall clock and the thread."""

    def __init__(self) -> None:
        self.events: list[tuple[str, str, int, int, float]] = []
        self._lock = threading.Lock()

    def _add(self, kind, stage) -> None:
        with self._lock:
            self.events.append((kind, stage.name, stage.done, stage.total, time.perf_counter()))

    def started(self, stage) -> None:
        self._add("start", stage)

    def advanced(self, stage) -> None:
        self._add("advance", stage)

    def ended(self, stage) -> None:
        self._add("end", stage)


def test_every_stage_of_a_preparation_reports_each_small_unit(small_demo):
    """A real preparation (the per-scene refinement on: conftest's short one) with seeded
    random networks: every stage starts, advances one unit at a time to its total and ends,
    and its units are per view or per step (the work of one unit is one network pass over one
    view, one view's sweep of one hypothesis, one refinement step), not wall time: on a busy
    2-core machine anything can take seconds, and the terminal's heartbeat then speaks for the
    innermost open stage (`test_plain_lines_at_most_one_a_second_and_a_heartbeat...`)."""
    from panogrf.model import refine

    recorder = Recorder()
    with progress.listening(recorder):
        prepared = session.prepare_scene(
            small_demo,
            None,
            models=random_models(),
            log=lambda *a: None,
            refine=refine.PREPARE_REFINE,
        )
    views = prepared.scene.num_views
    names = [e[1] for e in recorder.events if e[0] == "start"]
    assert names == [
        "reading the panoramas",
        session.PREPARING,  # around the others: it speaks up between them
        "depth: monocular network",
        "depth: multi-view stereo",
        "depth: photometric sweep",
        "depth refinement",
        "feature maps",
    ]
    for name in names:
        events = [e for e in recorder.events if e[1] == name]
        assert events[0][0] == "start" and events[-1][0] == "end", name
        done = [e[2] for e in events if e[0] == "advance"]
        total = events[0][3]
        assert done == list(range(1, total + 1)), (name, done, total)  # one unit at a time
    totals = {e[1]: e[3] for e in recorder.events if e[0] == "start"}
    # Mode full: the unguided network, again in the canonical world, then the guided one.
    assert totals["depth: multi-view stereo"] == 3 * views
    assert totals["depth: photometric sweep"] == 2 * views  # two hypotheses per view
    config = refine.PREPARE_REFINE
    assert totals["depth refinement"] == config.coarse + config.iterations + config.fine
    assert recorder.events[-1][:2] == ("end", session.PREPARING)


def test_plain_lines_at_most_one_a_second_and_a_heartbeat_in_a_long_unit():
    """Not a terminal: a stage is shown once it has taken a second, then at most a line a
    second and its last; while one unit takes 5 s, the heartbeat prints a line a second (a
    fake clock)."""
    now = [0.0]
    out = io.StringIO()
    shower = TerminalProgress(out, tty=False, clock=lambda: now[0])
    stamps = []

    def tick(dt):
        now[0] += dt
        before = out.getvalue().count("\n")
        shower.beat()
        if out.getvalue().count("\n") > before:
            stamps.append(now[0])

    with progress.listening(shower):
        with progress.stage("depth refinement", 50) as s:
            stamps.append(now[0])
            for _ in range(50):
                now[0] += 0.1
                before = out.getvalue().count("\n")
                s.advance()
                if out.getvalue().count("\n") > before:
                    stamps.append(now[0])
        with progress.stage("feature maps", 1) as s:
            stamps.append(now[0])
            for _ in range(20):  # 5 s in one unit: the heartbeat every 0.25 s
                tick(0.25)
            s.advance()
    lines = out.getvalue().splitlines()
    assert all(LINE.match(line) for line in lines), lines
    refinement = [line for line in lines if line.startswith("depth refinement")]
    assert re.match(r"depth refinement: 1[01]/50", refinement[0])  # a second into it
    assert refinement[-1].startswith("depth refinement: 50/50")
    assert 5 <= len(refinement) <= 7  # 5 s of work: one line a second
    features = [line for line in lines if line.startswith("feature maps")]
    assert len(features) >= 6 and features[-1].startswith("feature maps: 1/1")
    assert max(np.diff(stamps)) <= 1.1 + 1e-9  # a second, to the units of 0.1 s


def test_the_heartbeat_speaks_for_the_innermost_open_stage():
    """Between inner stages (work outside any, e.g. loading the scene), the outer stage's
    line comes every second; while an inner stage is open, only the inner one's."""
    now = [0.0]
    out = io.StringIO()
    shower = TerminalProgress(out, tty=False, clock=lambda: now[0])

    def wait(seconds):
        for _ in range(int(seconds / 0.25)):
            now[0] += 0.25
            shower.beat()

    with progress.listening(shower):
        with progress.stage(session.PREPARING, 1) as outer:
            wait(3.0)
            with progress.stage("feature maps", 1) as inner:
                wait(3.0)
                inner.advance()
            wait(2.0)
            outer.advance()
    names = [LINE.match(line)["name"] for line in out.getvalue().splitlines()]
    # Each shown from its first second on (nothing at its start), the inner one to its end.
    assert names == [session.PREPARING] * 3 + ["feature maps"] * 4 + [session.PREPARING] * 3


def test_a_terminal_gets_a_bar_with_the_stage_name_and_eta():
    now = [0.0]
    out = io.StringIO()
    with progress.listening(TerminalProgress(out, tty=True, clock=lambda: now[0])):
        with progress.stage("rendering frames", 3) as s:
            for _ in range(3):
                now[0] += 0.6
                s.advance()
    text = out.getvalue()
    assert "rendering frames: 3/3" in text and "elapsed" in text and "eta" in text


def test_render_prints_its_stages_on_stderr_and_quiet_silences_them(
    monkeypatch, small_demo, tmp_path, capsys
):
    monkeypatch.setattr(session, "default_models", random_models)
    monkeypatch.setattr(app_progress, "INTERVAL", 0.0)  # every stage shown, however short
    args = ["render", str(small_demo), "--target-frame", "1", "--height", "16", "--json"]
    assert cli.main([*args, "--out", str(tmp_path / "a.png"), "--cache-dir", str(tmp_path)]) == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out)  # stdout stays pure JSON
    lines = captured.err.strip().splitlines()
    assert lines and all(LINE.match(line) for line in lines), lines
    seen = {LINE.match(line)["name"] for line in lines}
    assert {"depth: multi-view stereo", "depth refinement", "feature maps"} <= seen
    # Random networks are never cached under the shipped weights' key.
    assert summary["cache"]["status"] == "not cached: given networks"
    assert list(tmp_path.glob("*.safetensors")) == []
    assert cli.main([*args, "--out", str(tmp_path / "b.png"), "--quiet"]) == 0
    assert capsys.readouterr().err == ""


def _summary(capsys) -> dict:
    return json.loads(capsys.readouterr().out)


@pytest.mark.slow
def test_render_loads_what_scene_prepare_wrote_and_rebuilds_a_corrupt_cache(
    small_demo, tmp_path, capsys
):
    """The shipped networks: `scene prepare --sources 0,2` builds the cache that `render
    --target-frame 1` (sources 0 and 2) then loads, twice, with the same pixels as a render
    that prepared afresh (--no-cache); a truncated cache file is rebuilt, not trusted."""
    cache = tmp_path / "cache"
    prep = ["scene", "prepare", str(small_demo), "--sources", "0,2", "--cache-dir", str(cache)]
    assert cli.main([*prep, "--quiet"]) == 0
    assert "scene cache built" in capsys.readouterr().out
    files = list(cache.glob("*.safetensors"))
    assert len(files) == 1
    base = ["render", str(small_demo), "--target-frame", "1", "--height", "32", "--json"]
    base += ["--quiet", "--cache-dir", str(cache)]
    outs = [tmp_path / f"{n}.png" for n in ("a", "b", "fresh", "rebuilt", "again")]
    assert cli.main([*base, "--out", str(outs[0])]) == 0
    first = _summary(capsys)
    assert first["cache"]["status"] == "loaded" and first["cache"]["path"] == str(files[0])
    assert cli.main([*base, "--out", str(outs[1])]) == 0
    assert _summary(capsys)["cache"]["status"] == "loaded"
    assert cli.main([*base, "--out", str(outs[2]), "--no-cache"]) == 0
    assert _summary(capsys)["cache"]["status"] == "not cached: --no-cache"
    good = files[0].read_bytes()
    files[0].write_bytes(good[: len(good) // 3])  # an interrupted copy
    assert cli.main([*base, "--out", str(outs[3])]) == 0
    assert _summary(capsys)["cache"]["status"].startswith("rebuilt: unreadable")
    assert cli.main([*base, "--out", str(outs[4])]) == 0
    assert _summary(capsys)["cache"]["status"] == "loaded"
    pixels = [read_rgb(p) for p in outs]
    for p in pixels[1:]:
        assert np.array_equal(p, pixels[0])
    assert list(cache.glob("*.safetensors")) == files


@pytest.mark.slow
def test_scene_prepare_of_every_view_is_what_view_and_a_camera_path_load(small_demo, tmp_path):
    """Without --sources: the refined scene of every view, the key `view` and `render
    --c2w` / `--camera-path` use."""
    from panogrf.model import refine
    from panogrf.renderer.methods import SourceViews

    cache = tmp_path / "cache"
    assert cli.main(["scene", "prepare", str(small_demo), "--cache-dir", str(cache)]) == 0
    prepared = session.prepare_scene(
        small_demo, cache, log=lambda *a: None, refine=refine.PREPARE_REFINE, defer_refine=True
    )
    assert prepared.cache.status == "loaded" and prepared.pending_refine is None
    views = SourceViews(
        prepared.scene.images.images, prepared.scene.images.c2w, refine=refine.PREPARE_REFINE
    )
    result = session.prepare_views(views, session.default_models(), "meshwarp", "fast", cache)
    assert result.status == "loaded"


@pytest.mark.slow
def test_depth_reads_its_cached_estimate_the_second_time(small_demo, tmp_path, capsys):
    cache = tmp_path / "cache"
    args = ["depth", str(small_demo), "--cache-dir", str(cache), "--quiet"]
    assert cli.main([*args, "--out", str(tmp_path / "one")]) == 0
    assert "depth cache" not in capsys.readouterr().out
    assert cli.main([*args, "--out", str(tmp_path / "two")]) == 0
    assert "depth cache loaded" in capsys.readouterr().out
    for name in ("frame_000", "frame_001", "frame_002"):
        a = (tmp_path / "one" / "depth" / f"{name}.png").read_bytes()
        assert a == (tmp_path / "two" / "depth" / f"{name}.png").read_bytes()
    meta = [json.loads((tmp_path / d / "transforms.json").read_text()) for d in ("one", "two")]
    assert meta[0]["panogrf_depth"] == meta[1]["panogrf_depth"]


def test_scene_prepare_bad_input_is_one_line(tmp_path, capsys):
    assert cli.main(["scene", "prepare", str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("panogrf scene prepare: error:") and "not found" in err
    assert "Traceback" not in err and "preparing" not in err  # no stage before the error
    assert cli.main(["scene", "prepare", str(DEMO), "--sources", "0,7"]) == 2
    err = capsys.readouterr().err
    assert "frames 0..2" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("tty", [False, True])
def test_a_stage_speaks_only_once_it_takes_long(tty):
    """A stage that ends within a second adds no line (a log of a fast machine holds only
    what took time); one whose unit takes longer is shown by the heartbeat (a fake clock)."""
    now = [0.0]
    out = io.StringIO()
    shower = TerminalProgress(out, tty=tty, clock=lambda: now[0])
    with progress.listening(shower):
        with progress.stage("reading the panoramas", 3) as s:
            for _ in range(3):
                now[0] += 0.2
                shower.beat()
                s.advance()
    assert out.getvalue() == ""
    with progress.listening(shower):
        with progress.stage("reading the photos", 2) as s:
            now[0] += 0.5
            shower.beat()
            assert out.getvalue() == ""
            now[0] += 0.6  # 1.1 s into its first unit: the heartbeat shows it
            shower.beat()
            assert "reading the photos" in out.getvalue()
            s.advance()
            s.advance()
    if not tty:
        lines = out.getvalue().splitlines()
        assert lines[0].startswith("reading the photos: 0/2") and lines[-1].startswith(
            "reading the photos: 2/2"
        )


def test_prepare_of_one_source_says_its_depth_is_unrefined(small_demo, tmp_path, capsys):
    """One source has no other to refine its depth against: the summary says so."""
    prep = ["scene", "prepare", str(small_demo), "--cache-dir", str(tmp_path / "c"), "--quiet"]
    assert cli.main([*prep, "--sources", "1"]) == 0
    assert "(sources 1, unrefined depth)" in capsys.readouterr().out
    assert cli.main([*prep, "--sources", "0,2"]) == 0
    assert "(sources 0,2, refined depth)" in capsys.readouterr().out
