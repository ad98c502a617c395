"""Frames of a camera path (`panogrf.app.paths.frames`): sizes, the panorama height a frame
needs, which frames cast their own rays, and agreement of the two perspective routes."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from helpers.nets import random_models
from helpers.room import pose, render

from panogrf.app.paths import frames as frames_mod
from panogrf.app.paths.frames import FrameRenderer, erp_height_for, render_camera_path
from panogrf.renderer.methods import SourceViews

SOURCES = ([-0.5, 0.0, 0.0], [0.6, 0.1, 0.0])


def test_panorama_height_a_frame_needs():
    assert erp_height_for("equirectangular", 512, 256, 90.0) == 256
    assert erp_height_for("perspective", 320, 180, 90.0) == 360  # 180 / 90 x 180 rows
    assert erp_height_for("perspective", 320, 181, 90.0) % 2 == 0
    assert erp_height_for("perspective", 4000, 3000, 30.0) == 1024  # capped
    assert erp_height_for("perspective", 16, 2, 170.0) == 16  # at least 16


@pytest.fixture(scope="module")
def renderer():
    c2w = torch.stack([pose(torch.eye(4, dtype=torch.float64)[:3, :3], p) for p in SOURCES])
    images = torch.cat([render(c)[0] for c in c2w]).float()
    frames = FrameRenderer(SourceViews(images, c2w.float()), random_models(), "draft")
    frames.prepare()
    yield frames, pose(torch.eye(3, dtype=torch.float64), [0.1, 0.0, 0.0]).numpy()
    frames.release()


def test_frames_have_the_path_size_and_type(renderer):
    frames, pose = renderer
    pano = frames.frame(pose, "equirectangular", 64, 32, 90.0)
    assert pano.shape == (32, 64, 3) and pano.dtype == np.uint8
    persp = frames.frame(pose, "perspective", 48, 36, 70.0)
    assert persp.shape == (36, 48, 3) and persp.dtype == np.uint8


def test_small_perspective_frames_cast_their_own_rays_large_ones_cut_a_panorama(
    renderer, monkeypatch
):
    frames, pose = renderer
    calls = []
    real = frames_mod.render_perspective_view

    def spy(*args, **kw):
        calls.append(args[3:5])  # (width, height)
        return real(*args, **kw)

    monkeypatch.setattr(frames_mod, "render_perspective_view", spy)
    frames.frame(pose, "perspective", 48, 36, 70.0)
    assert calls == [(48, 36)]
    calls.clear()
    # More pixels than the network pass of the panorama it would cut: the panorama route.
    frames.frame(pose, "perspective", 400, 340, 150.0)
    assert calls == []


def test_both_perspective_routes_show_the_same_view(renderer):
    frames, pose = renderer
    own = frames.frame(pose, "perspective", 48, 36, 70.0).astype(np.float64)
    pano = frames.panorama(pose, erp_height_for("perspective", 48, 36, 70.0))
    cut = frames_mod.to_uint8(frames_mod.erp_to_perspective(pano, 48, 36, 70.0))
    mse = ((own - cut.astype(np.float64)) ** 2).mean() / 255.0**2
    assert 10 * np.log10(1 / mse) > 20  # the same camera, by two samplings


def test_camera_path_goes_through_every_pose_in_order(renderer):
    frames, pose = renderer

    class Path:
        poses = [pose, pose]
        camera_type, render_width, render_height = "equirectangular", 64, 32
        fov = [90.0, 90.0]

    class Sink:
        got: list = []

        def write(self, frame):
            self.got.append(frame)

    done = []
    sink = Sink()
    render_camera_path(frames, Path, sink, done.append)
    assert len(sink.got) == 2 and done == [1, 2]
    assert np.array_equal(sink.got[0], sink.got[1])


def test_unknown_quality_is_refused():
    with pytest.raises(ValueError, match="quality"):
        FrameRenderer(None, None, "ultra")
