"""`panogrf train ...` on a machine that has torch but not the app's GL packages.

A GPU machine with its own torch (and numpy, OpenCV, safetensors, tqdm) but no moderngl,
pyrender or trimesh cannot import the whole command line, which registers every command. This
registers `panogrf train` alone and runs it with the same arguments, so the weights record the
same command. The repository's folders are made importable as `panogrf` without installing:

    python3 lab/gpu/train_elsewhere.py train depth --data packs --stage mono --device cuda ...
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _importable() -> None:
    try:
        import panogrf.app.commands.train  # noqa: F401
    except ImportError:
        package = Path(tempfile.mkdtemp()) / "panogrf"
        package.mkdir()
        for name in ("app", "model", "renderer", "assets", "shaders"):
            (package / name).symlink_to(ROOT / name)
        sys.path.insert(0, str(package.parent))


def main(argv: list[str]) -> int:
    _importable()
    from panogrf.app.commands import train
    from panogrf.app.errors import UserError

    parser = argparse.ArgumentParser(prog="panogrf")
    train.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except UserError as exc:
        print(f"panogrf: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
