"""The settings of `panogrf compare`, `depth`, `demo`, `scene reproject`, `scene check` and
`scene prepare`: declared once as options (each with help), checked as they are built, in the
commands' one-line messages."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from panogrf.app.commands.compare import CompareConfig
from panogrf.app.commands.demo import DemoConfig
from panogrf.app.commands.depth import DepthConfig
from panogrf.app.commands.scene import CheckConfig, ReprojectConfig
from panogrf.app.commands.scene_prepare import PrepareConfig
from panogrf.app.errors import UserError
from panogrf.app.options import add_options, from_args, options

CONFIGS = (CompareConfig, DepthConfig, DemoConfig, CheckConfig, ReprojectConfig, PrepareConfig)


@pytest.mark.parametrize("config", CONFIGS)
def test_every_option_has_help(config):
    assert all(opt.help for _, opt in options(config))


def test_the_defaults_are_the_commands():
    assert CompareConfig(Path("a"), Path("b")).device == "cpu"
    assert DepthConfig(Path("s"), out=Path("o")).mode == "full"
    assert DemoConfig() == DemoConfig(scene=None, out=Path("demo_out"))
    assert ReprojectConfig("d").occlusion_tol == 0.05
    assert PrepareConfig(Path("d")).sources is None


def test_a_config_round_trips_from_its_command_line():
    parser = argparse.ArgumentParser(prog="t")
    add_options(parser, ReprojectConfig)
    args = parser.parse_args(["d", "--target", "1", "--sources", "0,2"])
    assert from_args(ReprojectConfig, args) == ReprojectConfig("d", target=1, sources=[0, 2])


def test_the_settings_check_themselves_when_built_directly():
    with pytest.raises(UserError, match="^--device 'nope': not a device \\(auto, cpu, cuda"):
        CompareConfig(Path("a"), Path("b"), device="nope")
    for tol in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(UserError, match="^--occlusion-tol must be a positive relative"):
            ReprojectConfig("d", occlusion_tol=tol)


def test_the_preparation_options_are_composed_as_each_command_needs():
    from panogrf.app import runtime
    from panogrf.renderer.nadir import METADATA_KEY

    assert runtime.prepare_options() == (
        runtime.PrepareOptions,
        runtime.NoCacheOptions,
        runtime.NadirOptions,
    )
    assert runtime.prepare_options(no_cache=False, nadir=False) == (runtime.PrepareOptions,)
    assert repr(METADATA_KEY) in runtime.NADIR_HELP
    parser = argparse.ArgumentParser(prog="t")
    add_options(parser, runtime.RefineOptions, *runtime.prepare_options())
    args = parser.parse_args(["--no-refine-depth", "--nadir-cap", "off", "--no-cache"])
    assert (args.refine_depth, args.nadir_cap, args.no_cache, args.device) == (
        False,
        "off",
        True,
        "auto",
    )
    assert runtime.refine_setting(args) is None
    assert "(default auto)" in parser.format_help()
