"""`ViewConfig`, the settings of `panogrf view`: declared once as options, checked as they are
built, in the command's one-line messages."""

from __future__ import annotations

from pathlib import Path

import pytest

from panogrf.app.commands.view import ViewConfig
from panogrf.app.errors import UserError
from panogrf.app.options import flag_of, options


def test_every_option_has_help_and_keeps_its_flag():
    found = {f.name: opt for f, opt in options(ViewConfig)}
    assert all(opt.help for opt in found.values())
    assert flag_of(ViewConfig, "no_sharp") == "--no-sharp"
    assert flag_of(ViewConfig, "no_refine") == "--no-refine"
    assert found["window"].choices == ("pyglet", "headless")


def test_the_settings_check_themselves_when_built_directly(monkeypatch):
    scene = Path("s")
    built = ViewConfig(scene, window="headless", script="w*3,x")
    assert (built.size, built.path_out, built.frames) == (
        (1024, 512),
        Path("camera_path.json"),
        None,
    )
    assert built.script_keys() == [("W", 3), ("X", 0)]
    cases = [
        ({"frames": 0}, "^--frames must be at least 1$"),
        ({"moving_rows": 8}, "^--moving-rows must be between 16 and 512$"),
        ({"script": "w*x"}, "^--script: 'w\\*x': the count"),
    ]
    for fields, message in cases:
        with pytest.raises(UserError, match=message):
            ViewConfig(scene, window="headless", **fields)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr("sys.platform", "linux")
    with pytest.raises(UserError, match="^no display for a window: set DISPLAY"):
        ViewConfig(scene)
    monkeypatch.setenv("DISPLAY", ":97")  # no X server answers there
    with pytest.raises(UserError, match="^cannot open a window on DISPLAY=:97: no X server"):
        ViewConfig(scene)
    monkeypatch.setattr("panogrf.app.commands.view._unreachable_display", lambda: None)
    assert ViewConfig(scene).window == "pyglet"
