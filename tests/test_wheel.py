"""The built wheel holds the whole program: every subcommand's ``--help`` runs from it alone.

``pip install -e`` hides a subpackage left out of the wheel (the source tree is importable
anyway), so this builds the wheel, unpacks it (a pure-Python wheel installs by unpacking) and
runs the CLI with the unpacked copy first on the path: ``panogrf`` and every module then come
from the wheel, the third-party dependencies from this environment.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _subcommands() -> list[list[str]]:
    from panogrf.app.cli import build_parser

    found = []

    def walk(parser: argparse.ArgumentParser, prefix: list[str]) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    found.append([*prefix, name])
                    walk(sub, [*prefix, name])

    walk(build_parser(), [])
    return found


@pytest.mark.slow
def test_wheel_runs_every_subcommands_help(tmp_path):
    dist = tmp_path / "dist"
    leftovers = [ROOT / "build", ROOT / "panogrf.egg-info"]
    existed = {p: p.exists() for p in leftovers}
    build = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "--no-build-isolation",
         "-q", "-w", str(dist)],
        capture_output=True, text=True, cwd=tmp_path, timeout=300,
    )  # fmt: skip
    for p, was in existed.items():  # setuptools builds in the tree: leave it as it was
        if not was:
            shutil.rmtree(p, ignore_errors=True)
    assert build.returncode == 0, build.stderr
    (wheel,) = dist.glob("panogrf-*.whl")
    site = tmp_path / "site"
    with zipfile.ZipFile(wheel) as zf:
        names = zf.namelist()
        zf.extractall(site)
    for expected in ("panogrf/app/viewer/window.py", "panogrf/shaders/", "panogrf/assets/"):
        assert any(n.startswith(expected) for n in names), expected
    # No lab code, results or ablation weights (`lab/`), no benchmarks, no tests.
    lab = [n for n in names if {"lab", "benchmarks", "tests"} & set(n.split("/")[:2])]
    assert lab == [] and not [n for n in names if "renderer_tiny" in n or "analysis.md" in n]
    env = {**os.environ, "PYTHONPATH": str(site), "OMP_NUM_THREADS": "1"}
    where = subprocess.run(
        [sys.executable, "-c", "import panogrf.app.cli as c; print(c.__file__)"],
        capture_output=True, text=True, env=env, cwd=tmp_path,
    )  # fmt: skip
    assert where.stdout.strip().startswith(str(site)), where.stdout + where.stderr
    commands = _subcommands()
    assert ["view"] in commands and ["scene", "check"] in commands
    for command in [[], *commands]:
        run = subprocess.run(
            [sys.executable, "-m", "panogrf.app.cli", *command, "--help"],
            capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120,
        )  # fmt: skip
        assert run.returncode == 0, (command, run.stderr)
        assert "usage: " in run.stdout and "Traceback" not in run.stderr, command
