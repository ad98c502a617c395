"""Command-line options declared on dataclass fields.

A field made with `option` is also an option: `add_options` adds the options of a dataclass to
an argparse parser, and `from_args` builds the dataclass from the parsed arguments, so a setting
is written once, with its default, its help and its checks (the dataclass's ``__post_init__``).

The option of field ``field_name`` is ``--field-name`` unless the field names its own flag. Its
value is parsed by the field's ``parse`` function, else by the field's type (``Path | None``
parses a Path; a `StrEnum` parses into its members, its ``choices`` shown and checked as their
values, so that the option takes their text and argparse names a wrong one). A bool field is a
flag that sets the opposite of its default (``--no-field-name`` for a field true by default),
or, made ``negatable``, both ``--field-name`` and ``--no-field-name``. A field without a
default is a required option. A field made without `option` is no option. A subclass gives an
inherited option another default by declaring the field again with a plain default: the option
keeps its flag, help and parse.
A ``positional`` field is an argument named by its place (shown as its ``metavar``, else its
name), with ``nargs`` as argparse's (``"+"``: one or more, a list). Options that name the same
``one_of`` group are alternatives: exactly one of them must be given; of those that name the
same ``at_most_one`` group, at most one.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import types
import typing
from collections.abc import Callable
from enum import StrEnum
from pathlib import Path
from typing import Any

_KEY = "panogrf.option"


@dataclasses.dataclass(frozen=True)
class Option:
    """The command-line side of a field (`option`)."""

    help: str
    """Help text; ``{default}`` in it reads the field's default."""
    flag: str | None = None
    """The option's name when it is not ``--field-name`` (or ``--no-field-name``)."""
    parse: Callable[[str], Any] | None = None
    """Parses the option's text (an argparse ``type``); None: the field's type."""
    choices: tuple | None = None
    """The values allowed, if only some are."""
    positional: bool = False
    """An argument named by its place, not by a flag."""
    metavar: str | None = None
    """The name shown for the value, when not the one made from the flag (or field)."""
    nargs: str | None = None
    """argparse's ``nargs`` (``"+"``: one value or more, a list)."""
    negatable: bool = False
    """A bool option given as ``--flag`` or ``--no-flag`` (argparse's BooleanOptionalAction)."""
    one_of: str | None = None
    """The name of a group of alternative options, exactly one of which must be given (an
    argparse required mutually exclusive group); None: no group."""
    at_most_one: str | None = None
    """The name of a group of alternative options, at most one of which may be given (an
    argparse mutually exclusive group); None: no group."""


def option(
    default: Any = dataclasses.MISSING,
    help: str = "",
    *,
    flag: str | None = None,
    parse: Callable[[str], Any] | None = None,
    choices: tuple | None = None,
    positional: bool = False,
    metavar: str | None = None,
    nargs: str | None = None,
    negatable: bool = False,
    one_of: str | None = None,
    at_most_one: str | None = None,
) -> Any:
    """A dataclass field that is also a command-line option (no ``default``: a required one;
    ``one_of`` / ``at_most_one``: one of a group of alternatives, see `Option`)."""
    opt = Option(
        help, flag, parse, choices, positional, metavar, nargs, negatable, one_of, at_most_one
    )
    return dataclasses.field(default=default, metadata={_KEY: opt})


def _declared(cls: type, name: str) -> Option | None:
    """The `Option` of field ``name`` of ``cls``, looked up in its bases when ``cls`` declares
    the field again without one."""
    for klass in cls.__mro__:
        found = getattr(klass, "__dataclass_fields__", {}).get(name)
        if found is not None and _KEY in found.metadata:
            return found.metadata[_KEY]
    return None


def options(cls: type) -> list[tuple[dataclasses.Field, Option]]:
    """The fields of dataclass ``cls`` that are options, in field order, with their `Option`."""
    found = ((f, _declared(cls, f.name)) for f in dataclasses.fields(cls))
    return [(f, opt) for f, opt in found if opt is not None]


def flag_of(cls: type, name: str) -> str:
    """The command-line flag of field ``name`` of ``cls`` (for messages that name it; a
    positional argument's metavar or name)."""
    field = cls.__dataclass_fields__[name]
    opt = _declared(cls, name)
    if opt is not None and opt.positional:
        return opt.metavar or name
    if opt is not None and opt.flag:
        return opt.flag
    negated = field.type in ("bool", bool) and field.default is True
    negated = negated and not (opt is not None and opt.negatable)
    return ("--no-" if negated else "--") + name.replace("_", "-")


def _value_type(cls: type, name: str) -> type:
    """The type a field holds, ``X`` for ``X | None``."""
    hint = typing.get_type_hints(cls)[name]
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        (hint,) = [arg for arg in typing.get_args(hint) if arg is not type(None)]
    return hint


def _member_of(enum: type[StrEnum]) -> Callable[[str], Any]:
    """Parses an option's text into the member of ``enum`` of that value; any other text is
    left as it is, for the option's ``choices`` to refuse with argparse's own message."""

    def parse(text: str) -> Any:
        try:
            return enum(text)
        except ValueError:
            return text

    return parse


def _parse(cls: type, field: dataclasses.Field, opt: Option) -> Callable[[str], Any]:
    """The argparse ``type`` of option ``field`` of ``cls``: its ``parse``, else its type (a
    `StrEnum`: into its members)."""
    if opt.parse is not None:
        return opt.parse
    kind = _value_type(cls, field.name)
    if kind is Path:
        return user_path
    return _member_of(kind) if isinstance(kind, type) and issubclass(kind, StrEnum) else kind


def user_path(text: str) -> Path:
    """A path as typed, ``~`` and ``~user`` at its start expanded as a shell would: the shell
    leaves ``--out=~/scene`` as it is, and a folder named ``~`` is never what was meant."""
    return Path(os.path.expanduser(text)) if text.startswith("~") else Path(text)


def _choices(opt: Option) -> tuple | None:
    """The option's choices for argparse: the values of `StrEnum` members as plain strings
    (argparse names the choices by their repr, which is a member's class and name)."""
    if opt.choices is None:
        return None
    return tuple(str(c) if isinstance(c, StrEnum) else c for c in opt.choices)


def _argument(cls: type, field: dataclasses.Field, opt: Option) -> tuple[str, dict[str, Any]]:
    """The flag (a positional argument: its name) and the `add_argument` keywords of option
    ``field`` of ``cls``."""
    if opt.positional:
        kwargs = {"type": _parse(cls, field, opt), "help": opt.help}
        extra = {"metavar": opt.metavar, "nargs": opt.nargs, "choices": _choices(opt)}
        return field.name, kwargs | {k: v for k, v in extra.items() if v is not None}
    flag = flag_of(cls, field.name)
    default = field.default
    kwargs: dict[str, Any] = {
        "dest": field.name,
        "help": opt.help.replace("{default}", str(default)),
    }
    if _value_type(cls, field.name) is bool:
        if opt.negatable:
            kwargs |= {"action": argparse.BooleanOptionalAction, "default": default}
        else:
            kwargs["action"] = "store_false" if default else "store_true"
        return flag, kwargs
    kwargs["type"] = _parse(cls, field, opt)
    if default is dataclasses.MISSING:
        kwargs["required"] = True
    else:
        kwargs["default"] = default
    if opt.choices is not None:
        kwargs["choices"] = _choices(opt)
    else:
        kwargs["metavar"] = opt.metavar or flag.lstrip("-").replace("-", "_").upper()
    if opt.nargs is not None:
        kwargs["nargs"] = opt.nargs
    return flag, kwargs


def _required(flag: str, kwargs: dict[str, Any]) -> bool:
    """Whether an argument (`_argument`) must be given: a required option, or a positional
    argument that takes at least one value."""
    if flag.startswith("-"):
        return kwargs.get("required", False)
    return kwargs.get("nargs") not in ("?", "*")


def add_options(parser: argparse.ArgumentParser, *classes: type) -> None:
    """Add the options of each dataclass in ``classes`` to ``parser`` (`option`), the positional
    arguments and the required options first, then in the order of the classes and of their
    fields; each parses into the attribute named as its field. The options of a ``one_of``
    group go into one required mutually exclusive group, those of an ``at_most_one`` group into
    one that is not required."""
    arguments = [
        (opt.one_of or opt.at_most_one, opt.one_of is not None, *_argument(cls, f, opt))
        for cls in classes
        for f, opt in options(cls)
    ]
    arguments.sort(key=lambda argument: not _required(argument[2], argument[3]))
    groups: dict[str, Any] = {}
    for group, required, flag, kwargs in arguments:
        if group is None:
            parser.add_argument(flag, **kwargs)
            continue
        if group not in groups:
            groups[group] = parser.add_mutually_exclusive_group(required=required)
        groups[group].add_argument(flag, **kwargs)


def from_args(cls: type, args: argparse.Namespace, **fields: Any) -> Any:
    """Dataclass ``cls`` from the parsed ``args`` of its options (`add_options`) and the other
    ``fields`` given; its own checks run as it is built."""
    values = {field.name: getattr(args, field.name) for field, _ in options(cls)}
    return cls(**values, **fields)
