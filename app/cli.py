"""`panogrf` command line: a thin argparse layer over subcommand modules in `app/commands/`.

Each subcommand module exposes ``register(subparsers)``, which adds its parser and sets
``func`` (called with the parsed namespace, returns an exit code). A `UserError` anywhere
becomes a one-line message on stderr and exit status 2, running out of memory (sizes asked
for that this machine cannot hold) one as well, with status 1; a reader that goes away
(``| head``) ends the command quietly. SIGTERM and SIGHUP (a service manager, a closed
terminal, ``timeout``) end it as Ctrl-C does, through every ``finally`` (temporary folders
removed, half-written outputs undone), and then by the signal itself.
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
import signal
import sys
import threading
from typing import Any, TextIO

from panogrf.app.errors import UserError
from panogrf.app.runtime import keep_freed_memory

# Order is the order shown in --help.
_COMMANDS = (
    "view",
    "render",
    "eval",
    "bench",
    "dataset",
    "scene",
    "depth",
    "compare",
    "train",
    "demo",
)


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


def _innermost_parser(parser: argparse.ArgumentParser, args: argparse.Namespace):
    """The (sub-)subcommand parser that ``args`` were parsed by, for its usage line."""
    while True:
        sub = next((a for a in parser._actions if isinstance(a, argparse._SubParsersAction)), None)
        chosen = None if sub is None else getattr(args, sub.dest, None)
        if chosen not in getattr(sub, "choices", {}):
            return parser
        parser = sub.choices[chosen]


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Parse the command line; an unknown option is reported with its subcommand's usage
    (argparse reports it with the top-level usage, which lists no option)."""
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra:
        _innermost_parser(parser, args).error(f"unrecognized arguments: {' '.join(extra)}")
    return args


class _Stopped(BaseException):
    """SIGTERM or SIGHUP, raised in the main thread so that every ``finally`` runs."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def _raise_stopped(signum: int, _frame) -> None:
    raise _Stopped(signum)


def main(argv: list[str] | None = None) -> int:
    """The command line; SIGTERM and SIGHUP are caught while it runs (`_Stopped`), where they
    would end the process at once (not where the user ignores them: ``nohup``)."""
    caught = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGHUP):
            if signal.getsignal(sig) is signal.SIG_DFL:
                caught[sig] = signal.signal(sig, _raise_stopped)
    try:
        return _main(argv)
    except _Stopped as stop:
        signal.signal(stop.signum, signal.SIG_DFL)
        os.kill(os.getpid(), stop.signum)  # ends as the signal would have, after the cleanup
        return 128 + stop.signum
    finally:
        for sig, old in caught.items():
            signal.signal(sig, old)


def _main(argv: list[str] | None) -> int:
    # A file name that is not valid text (a lone surrogate from the file system or a JSON
    # escape) prints escaped rather than failing in the middle of a report.
    for stream in (sys.stdout, sys.stderr):
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="backslashreplace")
    watched = None if sys.stdout is None else _Watched(sys.stdout)  # None: stdout closed
    if watched is not None:
        sys.stdout = watched  # type: ignore[assignment]
    try:
        return _run(argv, watched)
    finally:
        if watched is not None:
            sys.stdout = watched.stream
            if watched.failed is None:  # what an error's path left unflushed: said, or gone
                try:
                    watched.stream.flush()
                except OSError:
                    _drop_stdout()


def _run(argv: list[str] | None, watched: _Watched | None) -> int:
    try:  # the commands' modules import torch and OpenCV: a second or more
        args = parse_args(argv)
    except KeyboardInterrupt:
        print("panogrf: interrupted", file=sys.stderr)
        return 130
    except SystemExit as done:  # --help and usage errors: the help must reach its reader
        if (why := _stdout_failure(watched)) is not None:
            print(f"panogrf: error: {why}", file=sys.stderr)
            return 1
        raise done
    keep_freed_memory()
    # Errors name the command as typed: "panogrf scene check", not "panogrf scene".
    name = " ".join(filter(None, (args.command, getattr(args, f"{args.command}_command", None))))
    try:
        if hasattr(args, "quiet"):  # a command that prepares scenes: its stages on stderr
            from panogrf.app.progress import terminal_progress

            with terminal_progress(args.quiet):
                code = int(args.func(args) or 0)
        else:
            code = int(args.func(args) or 0)
        if watched is not None:
            watched.flush()  # here, so that a closed pipe is caught below, not at exit
        return code
    except BrokenPipeError:
        # The reader went away (`panogrf scene check DIR | head`): stop quietly like the shell
        # tools; stdout goes to /dev/null so that Python's flush at exit does not fail again.
        _drop_stdout()
        return 141  # 128 + SIGPIPE, what a shell reports for a tool killed by a closed pipe
    except UserError as exc:
        print(f"panogrf {name}: error: {exc}", file=sys.stderr)
        return 2
    except (MemoryError, RuntimeError) as exc:  # torch's allocators raise RuntimeError
        if (why := _out_of_memory(exc)) is None:
            raise
        print(
            f"panogrf {name}: error: {why}: ask for less (--height, --batch, ...)", file=sys.stderr
        )
        return 1
    except KeyboardInterrupt:
        print(f"panogrf {name}: interrupted", file=sys.stderr)
        return 130
    except OSError as exc:  # standard output on a full disk or a broken device, nothing else
        if watched is None or watched.failed is not exc:
            raise
        _drop_stdout()
        print(f"panogrf {name}: error: {_cannot_write(exc)}", file=sys.stderr)
        return 1


class _Watched:
    """Standard output as it is, remembering the error a write to it raised (`failed`): a
    full disk or /dev/full is then said in one line, not as a traceback."""

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream
        self.failed: OSError | None = None

    def write(self, text: str) -> Any:
        try:
            return self.stream.write(text)  # some streams return None
        except OSError as exc:
            self.failed = exc
            raise

    def flush(self) -> None:
        try:
            self.stream.flush()
        except OSError as exc:
            self.failed = exc
            raise

    def __getattr__(self, name: str) -> Any:
        return getattr(self.stream, name)


def _cannot_write(exc: OSError) -> str:
    return f"cannot write to standard output ({exc.strerror or exc})"


def _drop_stdout() -> None:
    """What standard output could not take is dropped: Python's own flush at exit would fail
    again, with a traceback."""
    try:
        fd = sys.stdout.fileno()
    except (OSError, ValueError, AttributeError):  # no file (io.UnsupportedOperation), None
        return
    os.dup2(os.open(os.devnull, os.O_WRONLY), fd)


def _stdout_failure(watched: _Watched | None) -> str | None:
    """Why standard output could not take what was written to it (a full disk, /dev/full, an
    I/O error; argparse drops its own write errors, `_Watched` keeps them), found by flushing
    it; None where it could, or where its reader went away (a closed pipe: quiet)."""
    if watched is None:
        return None
    try:
        watched.flush()
    except OSError:
        pass
    failed = watched.failed
    if failed is None:
        return None
    _drop_stdout()
    return None if isinstance(failed, BrokenPipeError) else _cannot_write(failed)


def _out_of_memory(exc: BaseException) -> str | None:
    """Where ``exc`` is running out of memory (Python's, or torch's CPU or CUDA allocator): a
    few words saying so, with the size asked for where the message gives it; else None."""
    text = str(exc)
    if not isinstance(exc, MemoryError) and not re.search(
        r"can't allocate memory|out of memory", text
    ):
        return None
    asked = re.search(r"allocate (\d+) bytes", text)
    return "out of memory" + (f" ({int(asked[1]) / 2**30:.1f} GiB asked for)" if asked else "")


if __name__ == "__main__":
    sys.exit(main())
