"""`panogrf` command line: a thin argparse layer over subcommand modules in `app/commands/`.

Each subcommand module exposes ``register(subparsers)``, which adds its parser and sets
``func`` (called with the parsed namespace, returns an exit code). A `UserError` anywhere
becomes a one-line message on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from panogrf.app.errors import UserError
from panogrf.app.runtime import keep_freed_memory

# Order is the order shown in --help.
_COMMANDS = ("view", "render", "eval", "dataset", "scene", "depth", "compare", "train", "demo")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="panogrf",
        description="Walk through wide-baseline 360-degree panoramas (PanoGRF).",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in _COMMANDS:
        module = importlib.import_module(f"panogrf.app.commands.{name}")
        module.register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    keep_freed_memory()
    try:
        return int(args.func(args) or 0)
    except UserError as exc:
        print(f"panogrf {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"panogrf {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
