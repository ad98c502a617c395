"""Renders replayed from a CUDA graph: the parts made not to wait for the device compute what
the eager render computes (on the CPU here), and on a GPU the replay gives the eager pixels."""

from __future__ import annotations

import copy
from dataclasses import replace

import pytest
import torch

from panogrf.app.scene.folder import load_scene
from panogrf.app.scene.session import default_models
from panogrf.assets import path as asset_path
from panogrf.model.sampling import inverse_depth_samples
from panogrf.model.splat import fill_holes
from panogrf.renderer import graphs
from panogrf.renderer.cache import build_cache, resize_erp
from panogrf.renderer.render import QUALITY, render_panorama, sample_range


@pytest.fixture(scope="module")
def demo_cache():
    """The shipped renderer and a cache of the demo's outer views at 64 rows (true depth)."""
    data = load_scene(asset_path("demo"), load_images=True).images
    assert data.depths is not None  # the demo carries its true depth
    net = default_models().renderer("panogrf")
    images, depth = resize_erp(data.images[[0, 2]], 64), data.depths[[0, 2]]
    depth = torch.nn.functional.interpolate(depth, size=(32, 64), mode="nearest")
    with torch.no_grad():
        cache = build_cache(net, images, data.c2w[[0, 2]], depth)
    return net, cache, data.c2w[1].clone()


@pytest.mark.parametrize("empty", [0.3, 0.97, 1.0])
def test_holes_filled_without_looking_are_filled_alike(empty):
    g = torch.Generator().manual_seed(int(empty * 100))
    depth = 1 + 4 * torch.rand(24, 48, generator=g)
    depth[torch.rand(24, 48, generator=g) < empty] = 0.0
    for iterations in (16, 2):  # 2: holes left for the median
        looked = fill_holes(depth, iterations)
        assert torch.equal(fill_holes(depth, iterations, look=0), looked)
        assert bool((looked > 0).all())


def test_samples_from_a_range_held_in_tensors_are_those_from_floats():
    near = torch.tensor(0.731, dtype=torch.float64)
    far = torch.tensor(9.37, dtype=torch.float64)
    want = inverse_depth_samples(5, 4, float(near), float(far))
    assert torch.equal(inverse_depth_samples(5, 4, near, far), want)


def test_a_render_reading_its_range_from_tensors_is_the_render(demo_cache):
    net, cache, c2w = demo_cache
    near, far = sample_range(cache, c2w[:3, 3])
    span = torch.tensor([near, far], dtype=torch.float64)
    sampling = replace(QUALITY["fast"], near=span[0], far=span[1])
    want = render_panorama(net, cache, c2w, 16, "fast")
    got = render_panorama(net, cache, c2w, 16, sampling)
    assert want is not None and got is not None
    assert torch.equal(got.rgb, want.rgb) and torch.equal(got.depth, want.depth)


def test_on_a_cpu_nothing_is_replayed(demo_cache):
    net, cache, c2w = demo_cache
    calls = []
    render = lambda *args: calls.append(args)  # noqa: E731
    for _ in range(3):
        assert graphs.replayed(render, net, cache, c2w, 32, "fast", None) is None
    assert not calls


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_on_cuda_the_replayed_render_is_the_eager_render_at_every_pose(demo_cache, monkeypatch):
    from panogrf.renderer.detail import render_detailed

    net, cache, c2w = demo_cache
    net, cache = copy.deepcopy(net).cuda(), cache.to("cuda")  # the shared models stay
    poses = [c2w.cuda()]
    poses.append(poses[0].clone())
    poses[1][:3, 3] += torch.tensor([0.2, 0.0, 0.1], device="cuda")
    monkeypatch.setattr(graphs, "ENABLED", False)
    eager = [render_detailed(net, cache, p, 64, "fast") for p in poses]
    monkeypatch.setattr(graphs, "ENABLED", True)
    monkeypatch.setattr(graphs, "_current", None)
    replays = [render_detailed(net, cache, poses[k % 2], 64, "fast") for k in range(4)]
    assert graphs._current is not None and graphs._current.graph is not None  # replayed
    for k, out in enumerate(replays):
        want = eager[k % 2]
        assert out is not None and want is not None
        torch.testing.assert_close(out.rgb, want.rgb, rtol=0, atol=1e-5)
        torch.testing.assert_close(out.depth, want.depth, rtol=0, atol=1e-4)
    assert float((replays[2].rgb - replays[3].rgb).abs().mean()) > 1e-3  # the pose is read


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_on_cuda_renders_replay_while_another_thread_captures_the_refinement(
    demo_cache, monkeypatch
):
    """The viewer's case: its render thread captures and replays while the scene's depth is
    refined (its steps captured into graphs too) in a thread of its own."""
    import threading

    from panogrf.model.refine import PREPARE_REFINE, refine_depth
    from panogrf.renderer.detail import render_detailed

    net, cache, c2w = demo_cache
    net, cache, pose = copy.deepcopy(net).cuda(), cache.to("cuda"), c2w.cuda()
    monkeypatch.setattr(graphs, "ENABLED", False)
    want = render_detailed(net, cache, pose, 64, "fast")
    monkeypatch.setattr(graphs, "ENABLED", True)
    monkeypatch.setattr(graphs, "_current", None)
    errors: list[BaseException] = []

    def refine() -> None:
        try:
            for _ in range(3):
                depth = cache.depth * 1.1
                refine_depth(cache.images, cache.c2w, depth, [[1], [0]], PREPARE_REFINE)
        except BaseException as exc:  # noqa: BLE001 (reported below)
            errors.append(exc)

    worker = threading.Thread(target=refine)
    worker.start()
    outs = [render_detailed(net, cache, pose, 64, "fast") for _ in range(12)]
    worker.join()
    assert not errors, errors
    assert want is not None
    for out in outs:
        assert out is not None
        torch.testing.assert_close(out.rgb, want.rgb, rtol=0, atol=1e-5)


class _FakeGraph:
    """Stands in for `torch.cuda.CUDAGraph` on a CPU: counts replays."""

    replays = 0

    def replay(self) -> None:
        type(self).replays += 1


def test_the_graphs_bookkeeping_with_a_stand_in_for_cuda(demo_cache, monkeypatch):
    """On a CPU, with CUDA's graph replaced by a stand-in: the first render of a key is
    launched, the second captured (the render called once, reading its range from tensors) and
    replayed, later ones replayed without calling it, each answer a copy; another key starts
    over; a capture that fails leaves that key launched for good."""
    from contextlib import nullcontext

    net, cache, c2w = demo_cache
    monkeypatch.setattr(graphs, "_captures", lambda device: True)
    monkeypatch.setattr(graphs, "_current", None)
    monkeypatch.setattr(torch.cuda, "CUDAGraph", _FakeGraph)
    monkeypatch.setattr(torch.cuda, "graph", lambda *a, **k: nullcontext())
    calls = []

    def render(net_, cache_, pose, height, sampling, config):
        calls.append(sampling)
        return render_panorama(net_, cache_, pose, height, sampling)

    assert graphs.replayed(render, net, cache, c2w, 16, "fast", None) is None  # launched
    first = graphs.replayed(render, net, cache, c2w, 16, "fast", None)  # captured, replayed
    assert first is not None and len(calls) == 1 and _FakeGraph.replays == 1
    assert isinstance(calls[0].near, torch.Tensor) and isinstance(calls[0].far, torch.Tensor)
    want = render_panorama(net, cache, c2w, 16, "fast")
    assert want is not None and torch.equal(first.rgb, want.rgb)
    again = graphs.replayed(render, net, cache, c2w, 16, "fast", None)
    assert again is not None and len(calls) == 1 and _FakeGraph.replays == 2
    assert again.rgb.data_ptr() != first.rgb.data_ptr()  # copies, not the graph's output
    assert graphs.replayed(render, net, cache, c2w, 32, "fast", None) is None  # another key
    assert graphs.replayed(render, net, cache, c2w, 16, "paper", None) is None  # not graphed

    def broken(*args):
        raise RuntimeError("operation not permitted when stream is capturing")

    assert graphs.replayed(broken, net, cache, c2w, 24, "fast", None) is None  # launched
    assert graphs.replayed(broken, net, cache, c2w, 24, "fast", None) is None  # failed
    assert graphs.replayed(render, net, cache, c2w, 24, "fast", None) is None  # for good
    assert len(calls) == 1
