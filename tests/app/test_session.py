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
