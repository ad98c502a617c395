"""Options declared on dataclass fields (`panogrf.app.options`): a field becomes an option with
its default, help and choices, a bad value is refused in one line, and a dataclass round-trips
through its command line. Then the trainings' settings, which `panogrf train` is built from."""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass
from pathlib import Path

import pytest

from panogrf.app.cli import main
from panogrf.app.errors import UserError
from panogrf.app.options import add_options, flag_of, from_args, option, options, user_path
from panogrf.app.runtime import number
from panogrf.app.train import configs


@dataclass(frozen=True, kw_only=True)
class Toy:
    data: Path = option(help="a folder")
    steps: int = option(10, "steps (default {default})", parse=number(int, 1))
    mode: str = option("a", "which mode", choices=("a", "b"))
    weights: Path | None = option(None, "start from these", flag="--from")
    augment: bool = option(True, "no augmentation")
    shared: bool = option(False, "the same in both views")
    note: str = "not an option"

    def __post_init__(self) -> None:
        if self.mode == "b" and self.steps > 100:
            raise UserError("--mode b takes at most 100 --steps")


@dataclass(frozen=True, kw_only=True)
class Longer(Toy):
    steps: int = 20


def _parser(*classes: type) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="toy")
    add_options(parser, *classes)
    return parser


def _actions(parser: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    return {a.dest: a for a in parser._actions if a.dest != "help"}


def test_a_field_becomes_an_option_with_its_default_help_and_choices():
    actions = _actions(_parser(Toy))
    assert set(actions) == {"data", "steps", "mode", "weights", "augment", "shared"}
    assert actions["data"].option_strings == ["--data"] and actions["data"].required
    assert actions["data"].type is user_path  # a Path, with ~ expanded
    steps = actions["steps"]
    assert (steps.default, steps.help, steps.required) == (10, "steps (default 10)", False)
    assert actions["mode"].choices == ("a", "b") and actions["mode"].default == "a"
    weights = actions["weights"]
    assert weights.option_strings == ["--from"] and weights.metavar == "FROM"
    assert weights.type is user_path and weights.default is None
    assert actions["augment"].option_strings == ["--no-augment"]
    assert actions["augment"].default is True and actions["shared"].default is False
    assert flag_of(Toy, "augment") == "--no-augment" and flag_of(Toy, "weights") == "--from"
    assert flag_of(Toy, "shared") == "--shared"


def test_the_required_options_come_first_in_the_usage():
    usage = _parser(Toy).format_usage()
    assert usage.index("--data DATA") < usage.index("[--steps STEPS]")


def test_a_dataclass_round_trips_from_its_command_line():
    parser = _parser(Toy)
    assert from_args(Toy, parser.parse_args(["--data", "d"])) == Toy(data=Path("d"))
    argv = ["--data", "d", "--steps", "7", "--mode", "b", "--from", "w.safetensors"]
    args = parser.parse_args([*argv, "--no-augment", "--shared"])
    built = from_args(Toy, args, note="given")
    expected = Toy(
        data=Path("d"),
        steps=7,
        mode="b",
        weights=Path("w.safetensors"),
        augment=False,
        shared=True,
        note="given",
    )
    assert built == expected


def test_a_subclass_gives_an_inherited_option_another_default():
    steps = _actions(_parser(Longer))["steps"]
    assert (steps.default, steps.help) == (20, "steps (default 20)")
    with pytest.raises(SystemExit):
        _parser(Longer).parse_args(["--data", "d", "--steps", "0"])  # the parse is kept


def test_a_bad_value_is_refused_in_one_line(capsys):
    with pytest.raises(SystemExit) as exc:
        _parser(Toy).parse_args(["--data", "d", "--steps", "0"])
    assert exc.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1] == (
        "toy: error: argument --steps: expected at least 1, got 0"
    )
    with pytest.raises(SystemExit):
        _parser(Toy).parse_args(["--data", "d", "--mode", "c"])
    assert "invalid choice: 'c'" in capsys.readouterr().err
    args = _parser(Toy).parse_args(["--data", "d", "--mode", "b", "--steps", "101"])
    with pytest.raises(UserError, match="^--mode b takes at most 100 --steps$"):
        from_args(Toy, args)


def test_a_training_refuses_its_settings_in_one_line(tmp_path, capsys):
    argv = ["train", "select", "--data", str(tmp_path), "--out", str(tmp_path / "s.safetensors")]
    assert main([*argv, "--mono-shift", "2"]) == 2
    err = capsys.readouterr().err
    assert err.strip().splitlines() == [
        "panogrf train select: error: --mono-shift is a fraction of the scenes (0-1), got 2.0"
    ]


TRAININGS = (
    configs.TrainDepthConfig,
    configs.TrainRendererConfig,
    configs.TrainSelectConfig,
    configs.TrainBlendConfig,
)


@pytest.mark.parametrize("config", TRAININGS)
def test_every_training_option_has_help_and_shares_the_run_options(config):
    found = {f.name: opt for f, opt in options(config)}
    assert all(opt.help for opt in found.values())
    assert {"data", "out", "steps", "lr", "seed", "limit_scenes"} <= set(found)
    assert found["lr"].parse is configs.LR
    required = {a.dest for a in _parser(config, configs.RunOptions)._actions if a.required}
    assert required == ({"data", "out", "stage"} if "stage" in found else {"data", "out"})


def test_the_settings_check_themselves_when_built_directly(tmp_path):
    out = tmp_path / "w.safetensors"
    with pytest.raises(UserError, match="safetensors"):
        configs.TrainDepthConfig(data=tmp_path, out=tmp_path / "w.pt", stage="mono")
    with pytest.raises(UserError, match="multiple of 64"):
        configs.TrainRendererConfig(data=tmp_path, out=out, height=100)
    with pytest.raises(UserError, match="--mono-heights above 0"):
        configs.TrainBlendConfig(data=tmp_path, out=out, heights_shared=True)
    built = configs.TrainSelectConfig(data=tmp_path, out=out)
    assert (built.steps, built.lr, built.log_every) == (1500, 2e-3, 100)
    assert "stage" not in {f.name for f in dataclasses.fields(built)}


def test_the_choices_are_the_networks_presets():
    from panogrf.model.mvs import PRESETS as MVS_PRESETS
    from panogrf.model.render_net import PRESETS as RENDERER_PRESETS

    depth = {f.name: opt for f, opt in options(configs.TrainDepthConfig)}
    assert set(depth["mvs_preset"].choices) == set(MVS_PRESETS)
    assert set(configs.RENDERER_PRESETS) == set(RENDERER_PRESETS)


@dataclass(frozen=True)
class Positional:
    data: Path = option(help="a dataset", positional=True, metavar="DATASET")
    sources: list = option(help="the sources", positional=True, nargs="+", parse=Path)
    out: Path = option(help="output")


def test_a_positional_field_is_an_argument_named_by_its_place():
    parser = _parser(Positional)
    actions = _actions(parser)
    assert actions["data"].option_strings == [] and actions["data"].metavar == "DATASET"
    assert actions["sources"].nargs == "+" and actions["sources"].type is Path
    assert flag_of(Positional, "data") == "DATASET" and flag_of(Positional, "out") == "--out"
    args = parser.parse_args(["d", "a", "b", "--out", "o"])
    built = from_args(Positional, args)
    assert built == Positional(data=Path("d"), sources=[Path("a"), Path("b")], out=Path("o"))
    assert "DATASET sources [sources ...]" in parser.format_usage()


@dataclass(frozen=True)
class Alternatives:
    near: int | None = option(None, "near", one_of="where")
    far: str | None = option(None, "far", one_of="where")


def test_options_of_one_group_are_alternatives_exactly_one_of_which_is_given(capsys):
    parser = _parser(Alternatives)
    assert from_args(Alternatives, parser.parse_args(["--near", "3"])) == Alternatives(near=3)
    for argv in ([], ["--near", "3", "--far", "x"]):
        with pytest.raises(SystemExit):
            parser.parse_args(argv)
    err = capsys.readouterr().err.splitlines()
    assert err[1] == "toy: error: one of the arguments --near --far is required"
    assert err[-1] == "toy: error: argument --far: not allowed with argument --near"


@dataclass(frozen=True)
class Optional_:
    near: int | None = option(None, "near", at_most_one="where")
    far: str | None = option(None, "far", at_most_one="where")


def test_options_of_an_at_most_one_group_exclude_each_other_and_may_all_be_left_out(capsys):
    parser = _parser(Optional_)
    assert from_args(Optional_, parser.parse_args([])) == Optional_()
    assert from_args(Optional_, parser.parse_args(["--far", "x"])) == Optional_(far="x")
    with pytest.raises(SystemExit):
        parser.parse_args(["--near", "3", "--far", "x"])
    assert capsys.readouterr().err.splitlines()[-1] == (
        "toy: error: argument --far: not allowed with argument --near"
    )


def test_a_missing_argument_is_named_in_the_order_of_the_fields(capsys):
    with pytest.raises(SystemExit):
        _parser(Positional).parse_args([])
    assert capsys.readouterr().err.splitlines()[-1] == (
        "toy: error: the following arguments are required: DATASET, sources, --out"
    )


@dataclass(frozen=True)
class Switch:
    refine: bool = option(True, "refine", negatable=True)


def test_a_negatable_switch_takes_both_flags():
    parser = _parser(Switch)
    assert flag_of(Switch, "refine") == "--refine"
    assert from_args(Switch, parser.parse_args([])) == Switch(refine=True)
    assert from_args(Switch, parser.parse_args(["--no-refine"])) == Switch(refine=False)
    assert parser.parse_args(["--no-refine", "--refine"]).refine is True


def test_an_interrupt_while_the_commands_load_is_one_line(monkeypatch, capsys):
    from panogrf.app import cli

    def interrupted(argv=None):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "parse_args", interrupted)
    assert cli.main(["view", "x"]) == 130
    assert capsys.readouterr().err == "panogrf: interrupted\n"
