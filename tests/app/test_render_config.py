"""`RenderConfig`, the settings of `panogrf render`: declared once as options, checked as they
are built, in the command's one-line messages."""

from __future__ import annotations

from pathlib import Path

import pytest

from panogrf.app.commands.render import RenderConfig
from panogrf.app.errors import UserError
from panogrf.app.options import flag_of, options

POSE = "1 0 0 0.3 0 1 0 1.5 0 0 1 0 0 0 0 1"


def test_every_option_has_help_and_the_targets_are_alternatives():
    found = {f.name: opt for f, opt in options(RenderConfig)}
    assert all(opt.help for opt in found.values())
    assert {name for name, opt in found.items() if opt.one_of == "target"} == {
        "target_frame",
        "c2w",
        "camera_path",
    }
    assert flag_of(RenderConfig, "scene") == "SCENE"
    assert flag_of(RenderConfig, "camera_path") == "--camera-path"


def test_the_settings_check_themselves_when_built_directly(tmp_path):
    out = tmp_path / "p.png"
    built = RenderConfig(scene=Path("s"), out=out, c2w=POSE)
    assert (built.method, built.quality, built.height) == ("panogrf", "fast", None)
    cases = [
        ({"target_frame": 1, "c2w": POSE}, "^give one of --target-frame, --c2w and"),
        ({"target_frame": 1, "height": 4}, "^--height must be between 8 and"),
        ({"c2w": "1 2 3"}, "^--c2w: expected 16 numbers, got 3$"),
        ({"target_frame": 1, "method": "nearest", "quality": "preview"}, "^--quality preview"),
        ({"camera_path": Path("p.json"), "sources": [0]}, "^--camera-path takes its size"),
    ]
    for fields, message in cases:
        with pytest.raises(UserError, match=message):
            RenderConfig(scene=Path("s"), out=out, **fields)
    with pytest.raises(UserError, match="^--out must be a .png or .jpg file"):
        RenderConfig(scene=Path("s"), out=tmp_path / "p.txt", target_frame=1)
    with pytest.raises(UserError, match="^--out: folder .* does not exist$"):
        RenderConfig(scene=Path("s"), out=tmp_path / "no" / "p.png", target_frame=1)
    video = RenderConfig(scene=Path("s"), out=tmp_path / "v.mp4", camera_path=Path("p.json"))
    assert video.camera_path == Path("p.json")
