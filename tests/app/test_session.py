"""The library layer under the commands (`panogrf.app.scene.session`)."""

from __future__ import annotations

from helpers.nets import random_models

from panogrf.app.scene import session
from panogrf.app.weights import networks as dw
from panogrf.assets import path as asset_path
from panogrf.renderer.methods import METHODS


def test_weight_files_cover_every_network_a_method_prepares_with():
    names = lambda method: [p.name for p in session.weight_files(method)]  # noqa: E731
    # Mode full fuses the mono-guided and the unguided MVS: both key the scene cache.
    assert names("panogrf") == [
        dw.WEIGHTS["mono"],
        dw.WEIGHTS["full"],
        dw.WEIGHTS["mvs"],
        dw.SELECTOR,
        dw.BLEND,
        dw.RENDERER_WEIGHTS["panogrf"],
    ]
    assert names("no_mono") == [
        dw.WEIGHTS["mono"],
        dw.WEIGHTS["mvs"],
        dw.RENDERER_WEIGHTS["panogrf"],
    ]
    assert names("meshwarp") == [
        dw.WEIGHTS["mono"],
        dw.WEIGHTS["full"],
        dw.WEIGHTS["mvs"],
        dw.SELECTOR,
        dw.BLEND,
    ]
    assert names("nearest") == []


def test_weight_files_follow_panogrf_weights(monkeypatch, tmp_path):
    monkeypatch.setenv("PANOGRF_WEIGHTS", str(tmp_path))
    assert all(p.parent == tmp_path for p in session.weight_files("panogrf"))


def test_prepare_scene_with_given_networks_leaves_the_disk_cache_alone(tmp_path):
    logged = []
    prepared = session.prepare_scene(
        asset_path("demo"), tmp_path / "cache", models=random_models(), log=logged.append
    )
    assert METHODS["panogrf"].cache_key in prepared.views.caches
    assert prepared.views.depth["full"].isfinite().all()
    assert prepared.scene.num_views == prepared.views.images.shape[0]
    assert not (tmp_path / "cache").exists()
    assert "not cached" in prepared.cache.status and logged


def test_a_deferred_refinement_opens_plain_then_caches_the_refined_scene(tmp_path):
    """The viewer's path: without a refined scene on disk, the plain one is prepared and the
    refinement left pending; `refine_prepared` refines that depth and writes the refined
    scene, which the next deferred preparation loads at once, with nothing pending."""
    import torch

    from panogrf.model import refine

    cache = tmp_path / "cache"
    config = refine.PREPARE_REFINE  # conftest's quick one
    first = session.prepare_scene(
        asset_path("demo"), cache, log=lambda *a: None, refine=config, defer_refine=True
    )
    assert first.pending_refine == config and first.views.refine is None
    plain = first.views.depth["full"]
    done = session.refine_prepared(first, log=lambda *a: None)
    assert done.pending_refine is None and done.views.refine == config
    assert done.cache.status == "built"
    refined = done.views.depth["full"]
    assert refined.shape == plain.shape and not torch.equal(refined, plain)
    assert len(list(cache.glob("*.safetensors"))) == 2  # the plain and the refined scene
    again = session.prepare_scene(
        asset_path("demo"), cache, log=lambda *a: None, refine=config, defer_refine=True
    )
    assert again.pending_refine is None and again.cache.status == "loaded"
    assert torch.equal(again.views.depth["full"], refined)


def test_a_stopped_background_refinement_writes_nothing(tmp_path):
    from panogrf.app.viewer.scene_refiner import SceneRefiner
    from panogrf.model import refine

    cache = tmp_path / "cache"
    prepared = session.prepare_scene(
        asset_path("demo"),
        cache,
        log=lambda *a: None,
        refine=refine.PREPARE_REFINE,
        defer_refine=True,
    )
    refiner = SceneRefiner(prepared, log=lambda *a: None)
    refiner.stop()  # before its first step
    refiner.start().join(60)
    assert refiner.take() is None and refiner.error is None
    assert refiner.status_text() == "depth refinement stopped"
    assert len(list(cache.glob("*.safetensors"))) == 1  # the plain scene only


def test_the_background_refinement_gives_the_thread_count_back(tmp_path):
    """`SceneRefiner` refines on one torch thread (beside the render worker's OpenMP pool, a
    second pool would outnumber 2 cores: `panogrf.app.viewer.torch_threads`) and puts the
    caller's count back when done: threads started later get the caller's, not one."""
    import threading

    import torch

    from panogrf.app.viewer.scene_refiner import SceneRefiner
    from panogrf.model import refine

    prepared = session.prepare_scene(
        asset_path("demo"),
        tmp_path / "cache",
        log=lambda *a: None,
        refine=refine.PREPARE_REFINE,
        defer_refine=True,
    )
    saved = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        seen_inside = []
        original = session.refine_prepared

        def spy(*args, **kwargs):
            seen_inside.append(torch.get_num_threads())
            return original(*args, **kwargs)

        session.refine_prepared = spy
        try:
            refiner = SceneRefiner(prepared, log=lambda *a: None).start()
            refiner.join(120)
        finally:
            session.refine_prepared = original
        assert refiner.error is None and refiner.take() is not None
        assert seen_inside == [1]
        later = []
        t = threading.Thread(target=lambda: later.append(torch.get_num_threads()))
        t.start()
        t.join()
        assert later == [2] and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(saved)
