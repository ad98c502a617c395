"""The store of prepared scenes: `get_or_compute` through a store in a dict, a cache hit and a
cache miss, and a prepared scene kept in memory by `prepare_views` and `prepare_scene`."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from helpers.nets import tiny_cache_models, tiny_views

from panogrf.app.scene import session
from panogrf.app.scene.cache import prepare_cached, scene_provenance
from panogrf.app.scene.store import (
    DiskStore,
    Entry,
    MemoryStore,
    Provenance,
    get_or_compute,
    read_valid,
)
from panogrf.assets import path as asset_path
from panogrf.model.refine import RefineConfig
from panogrf.renderer.methods import METHODS, Models, SourceViews


def _models(kind: type[Models] = Models) -> Models:
    return tiny_cache_models(kind)


def _views(seed: int = 0) -> SourceViews:
    return tiny_views(seed)


def _entry(value: float) -> Entry:
    return Entry({"x": torch.full((2, 3), value)}, {"note": "n"})


def test_a_miss_computes_and_puts_a_hit_reads_without_computing():
    store = MemoryStore()
    calls = []

    def compute() -> Entry:
        calls.append(1)
        return _entry(1.0)

    first = get_or_compute(store, "k", compute)
    assert first.status == "built" and calls == [1] and list(store.entries) == ["k"]
    second = get_or_compute(store, "k", lambda: pytest.fail("a hit must not compute"))
    assert second.status == "loaded" and second.entry is store.entries["k"]
    other = get_or_compute(store, "other", compute)
    assert other.status == "built" and calls == [1, 1]


def test_an_entry_failing_its_check_is_recomputed_and_replaced():
    store = MemoryStore({"k": _entry(float("nan"))})

    def check(entry: Entry) -> str | None:
        return None if entry.tensors["x"].isfinite().all() else "non-finite values"

    fetched = get_or_compute(store, "k", lambda: _entry(2.0), check)
    assert fetched.status == "rebuilt: non-finite values"
    assert torch.equal(store.entries["k"].tensors["x"], torch.full((2, 3), 2.0))
    assert read_valid(store, "k", check)[0] is store.entries["k"]
    assert read_valid(store, "missing", check) == (None, None)


def test_the_disk_store_round_trips_and_names_a_changed_file(tmp_path):
    store = DiskStore(tmp_path)
    get_or_compute(store, "k", lambda: _entry(3.0))
    back = store.read("k")
    assert torch.equal(back.tensors["x"], torch.full((2, 3), 3.0))
    assert back.meta == {"note": "n"} and back.damaged is None
    store.where("k").rename(store.where("j"))  # another entry's file under this name
    assert read_valid(store, "j") == (None, "stale (another scene or other weights)")


def test_provenance_names_pixels_poses_weights_and_setting(tmp_path):
    w = tmp_path / "w"
    w.write_bytes(b"1")
    v = _views()
    p = Provenance.of(v.images, v.c2w, [w])
    assert dataclasses.is_dataclass(p) and p.key == Provenance.of(v.images, v.c2w, [w]).key
    moved = v.c2w.clone()
    moved[1, 0, 3] += 1e-6
    changes = [
        Provenance.of(v.images, moved, [w]),
        Provenance.of(_views(1).images, v.c2w, [w]),
        Provenance.of(v.images, v.c2w, [w], "refine"),
    ]
    assert len({p.key, *(c.key for c in changes)}) == 4
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.setting = "x"


def test_the_depth_chains_settings_name_the_entry(monkeypatch, tmp_path):
    """The same photos and weights through a chain of other settings: another entry."""
    from panogrf.app.scene import store
    from panogrf.model.depth_config import DepthConfig

    w = tmp_path / "w"
    w.write_bytes(b"1")
    v = _views()
    before = Provenance.of(v.images, v.c2w, [w]).key
    monkeypatch.setattr(store, "CHAIN", repr(DepthConfig(far_from=float("inf"))))
    assert Provenance.of(v.images, v.c2w, [w]).key != before


def test_a_prepared_scene_is_a_hit_in_a_store_in_memory(tmp_path):
    """The cache miss fills the dict; a second preparation of the same views reads it back
    (the same depth and maps, nothing computed: the estimator is never called)."""
    weights = tmp_path / "w"
    weights.write_bytes(b"w")
    models, store = _models(), MemoryStore()
    first = _views()
    miss = prepare_cached(first, models, None, [weights], store)
    key = scene_provenance(first, [weights]).key
    assert miss.status == "built" and list(store.entries) == [key]
    assert not any(tmp_path.glob("*.safetensors"))

    def no_estimator(mode):
        raise AssertionError("a hit must not estimate depth")

    second = _views()
    hit = prepare_cached(
        second, dataclasses.replace(models, estimator=no_estimator), None, [weights], store
    )
    assert hit.status == "loaded"
    a, b = (v.caches[METHODS["panogrf"].cache_key] for v in (first, second))
    assert torch.equal(a.maps, b.maps) and torch.equal(second.depth["full"], first.depth["full"])


def test_prepared_scene_is_immutable_and_refinement_makes_a_new_one():
    shipped = _models(session.ShippedModels)
    store = MemoryStore()
    refine = RefineConfig(iterations=2, height=32)
    plain = session.prepare_scene(
        asset_path("demo"), None, shipped, lambda *a: None, refine, True, store=store
    )
    with pytest.raises(dataclasses.FrozenInstanceError):
        plain.pending_refine = None
    assert plain.pending_refine == refine and plain.store is store
    refined = session.refine_prepared(plain, log=lambda *a: None)
    assert refined is not plain and refined.pending_refine is None
    assert plain.pending_refine == refine  # the plain scene is as it was
    assert not torch.equal(refined.views.depth["full"], plain.views.depth["full"])
    assert len(store.entries) == 2  # the plain scene and the refined one
    again = session.prepare_scene(
        asset_path("demo"), None, shipped, lambda *a: None, refine, True, store=store
    )
    assert again.cache.status == "loaded" and again.pending_refine is None
