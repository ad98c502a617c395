"""The on-disk scene cache: built once, loaded after, rebuilt when stale or corrupt."""

from __future__ import annotations

import subprocess

import torch
from helpers.disk import fill, tiny_tmpfs
from helpers.nets import tiny_cache_models, tiny_views
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from panogrf.app.scene.cache import content_key, prepare_cached
from panogrf.renderer.methods import METHODS, Models, SourceViews


def _models() -> Models:
    return tiny_cache_models()


def _views(seed: int = 0) -> SourceViews:
    return tiny_views(seed)


def test_built_then_loaded_with_the_same_tensors(tmp_path):
    weights = tmp_path / "w.safetensors"
    weights.write_bytes(b"weights v1")
    models = _models()
    first = _views()
    r1 = prepare_cached(first, models, tmp_path / "cache", [weights])
    assert r1.status == "built" and r1.path.exists()
    second = _views()
    r2 = prepare_cached(second, models, tmp_path / "cache", [weights])
    assert r2.status == "loaded" and r2.path == r1.path
    a, b = first.caches[METHODS["panogrf"].cache_key], second.caches[METHODS["panogrf"].cache_key]
    assert torch.equal(a.maps, b.maps) and torch.equal(a.depth, b.depth)
    assert torch.equal(first.depth["full"], second.depth["full"])
    # No temporary files are left behind.
    assert [p.name for p in (tmp_path / "cache").iterdir()] == [r1.path.name]


def test_key_changes_with_pixels_poses_and_weights(tmp_path):
    w1, w2 = tmp_path / "a", tmp_path / "b"
    w1.write_bytes(b"1")
    w2.write_bytes(b"2")
    v = _views()
    k = content_key(v.images, v.c2w, [w1])
    assert content_key(v.images, v.c2w, [w1]) == k
    assert content_key(v.images, v.c2w, [w2]) != k
    moved = v.c2w.clone()
    moved[1, 2, 3] += 0.01
    assert content_key(v.images, moved, [w1]) != k
    other = v.images.clone()
    other[0, 0, 0, 0] = 1.0 - other[0, 0, 0, 0]
    assert content_key(other, v.c2w, [w1]) != k


def test_corrupt_or_truncated_cache_is_rebuilt(tmp_path):
    weights = tmp_path / "w"
    weights.write_bytes(b"w")
    models = _models()
    r = prepare_cached(_views(), models, tmp_path, [weights])
    good = r.path.read_bytes()
    r.path.write_bytes(good[: len(good) // 2])  # an interrupted copy
    again = prepare_cached(_views(), models, tmp_path, [weights])
    assert again.status.startswith("rebuilt: unreadable")
    assert prepare_cached(_views(), models, tmp_path, [weights]).status == "loaded"
    r.path.write_bytes(b"\x00" * 64)
    assert prepare_cached(_views(), models, tmp_path, [weights]).status.startswith("rebuilt")


def test_unwritable_cache_folder_costs_only_the_cache(tmp_path):
    weights = tmp_path / "w"
    weights.write_bytes(b"w")
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    views = _views()
    r = prepare_cached(views, _models(), blocker / "cache", [weights])
    assert "not saved" in r.status
    assert METHODS["panogrf"].cache_key in views.caches


def _rewrite(path, **changes) -> None:
    tensors = load_file(str(path))
    tensors.update(changes)
    save_file({k: v.contiguous() for k, v in tensors.items()}, str(path))


def test_right_key_but_wrong_contents_is_rebuilt(tmp_path):
    weights = tmp_path / "w"
    weights.write_bytes(b"w")
    models = _models()
    r = prepare_cached(_views(), models, tmp_path, [weights])
    good = load_file(str(r.path))
    depth, maps = good["depth"], good["maps"]
    bad = {
        "wrong maps shape": {"maps": maps[:, :-2]},  # channel count of other weights
        "wrong dtypes": {"maps": maps.half()},
        "wrong depth shape": {"depth": depth[..., :-2], "maps": maps[..., :-2]},  # not 2:1
        "depth out of range": {"depth": -depth, "maps": torch.cat((maps[:, :-1], -depth), 1)},
        "maps and depth disagree": {"depth": depth * 2},
    }
    for why, change in bad.items():
        _rewrite(r.path, **change)
        views = _views()
        status = prepare_cached(views, models, tmp_path, [weights]).status
        assert status.startswith(f"rebuilt: {why}"), (why, status)
        assert torch.equal(views.caches[METHODS["panogrf"].cache_key].maps, maps)
        assert prepare_cached(_views(), models, tmp_path, [weights]).status == "loaded"


def test_full_disk_costs_only_the_cache(tmp_path, monkeypatch):

    weights = tmp_path / "w"
    weights.write_bytes(b"w")

    def full(tensors, filename, metadata=None):
        with open(filename, "wb") as f:
            f.write(b"\0" * 100)  # what a full disk leaves of the write
        raise SafetensorError("Error while serializing: I/O error: No space left on device")

    monkeypatch.setattr("safetensors.torch.save_file", full)  # as the atomic writer calls it
    views = _views()
    r = prepare_cached(views, _models(), tmp_path / "cache", [weights])
    assert "not saved" in r.status and "No space left" in r.status
    assert METHODS["panogrf"].cache_key in views.caches
    assert list((tmp_path / "cache").iterdir()) == []


def test_really_full_disk_costs_only_the_cache(tmp_path):
    weights = tmp_path / "w"
    weights.write_bytes(b"w")
    with tiny_tmpfs(tmp_path / "disk") as disk:
        fill(disk)
        r = prepare_cached(_views(), _models(), disk, [weights])
        assert "not saved" in r.status
        assert [p.name for p in disk.iterdir()] == ["ballast"]


def test_a_killed_write_is_swept_by_the_next_run(tmp_path):
    weights = tmp_path / "w"
    weights.write_bytes(b"w")
    dead = subprocess.Popen(["true"])  # a process id that no longer runs
    dead.wait()
    key = content_key(_views().images, _views().c2w, [weights])
    stale = tmp_path / f".{key}.safetensors.{dead.pid}-0123abcd.panogrf-tmp.safetensors"
    stale.write_bytes(b"\0" * 1000)
    r = prepare_cached(_views(), _models(), tmp_path, [weights])
    assert [p.name for p in tmp_path.iterdir() if p.name != "w"] == [r.path.name]


def test_a_refined_scene_has_its_own_cache_and_its_own_depth(tmp_path):
    """``--refine-depth`` (`SourceViews.refine`) changes the depth, so it is keyed apart: the
    plain scene's cache is neither reused for it nor overwritten by it."""
    from panogrf.model.refine import RefineConfig

    weights = tmp_path / "w.safetensors"
    weights.write_bytes(b"weights v1")
    models = _models()
    plain = _views()
    refined = _views()
    refined.refine = RefineConfig(iterations=3, height=32, lr=0.1)
    r1 = prepare_cached(plain, models, tmp_path / "cache", [weights])
    r2 = prepare_cached(refined, models, tmp_path / "cache", [weights])
    assert r1.status == r2.status == "built" and r1.path != r2.path
    assert not torch.equal(plain.depth["full"], refined.depth["full"])
    again = _views()
    again.refine = RefineConfig(iterations=3, height=32, lr=0.1)
    r3 = prepare_cached(again, models, tmp_path / "cache", [weights])
    assert r3.status == "loaded" and r3.path == r2.path
    assert torch.equal(again.depth["full"], refined.depth["full"])


def test_plausible_but_changed_numbers_are_caught_by_the_checksum(tmp_path):
    """Issue 57 S6: a cache rewritten with plausible numbers (its key and metadata kept), or
    one flipped byte in its feature maps, was loaded and shown as the scene."""
    from safetensors import safe_open

    weights = tmp_path / "w"
    weights.write_bytes(b"w")
    models = _models()
    r = prepare_cached(_views(), models, tmp_path, [weights])
    good = load_file(str(r.path))
    with safe_open(str(r.path), framework="pt") as f:
        meta = f.metadata()
    maps = good["maps"].clone()
    maps[0, 0, 0, 0] += 1e-3  # one feature, slightly off
    depth = torch.full_like(good["depth"], 0.3)  # depth 0.3 m everywhere, maps to match
    flat = torch.cat((good["maps"][:, :-1], depth), 1)
    for change in ({"maps": maps}, {"depth": depth, "maps": flat}):
        save_file(good | change, str(r.path), metadata=meta)
        views = _views()
        status = prepare_cached(views, models, tmp_path, [weights]).status
        assert status == "rebuilt: checksum mismatch (the file was changed)", status
        assert torch.equal(views.depth["full"], good["depth"])
