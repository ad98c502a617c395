"""Running the command line in a test: the exit code and the last error line."""

from __future__ import annotations

from panogrf.app.cli import main


def run_cli(argv: list[str], capsys) -> tuple[int, str]:
    """(exit code, the last line of stderr), asserting no traceback."""
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own errors
        code = int(exc.code or 0)
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = [x for x in err.strip().splitlines() if x.strip()]
    return code, lines[-1] if lines else ""
