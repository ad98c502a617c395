#!/usr/bin/env bash
# Type-check panogrf.model and panogrf.renderer with mypy, strict ([tool.mypy] in pyproject.toml).
# The repository's top-level folders are the `panogrf` package's subpackages (setup.py), so mypy
# runs from a temporary folder holding a `panogrf` link to the repository: it then resolves
# `panogrf.model...` from this checkout, wherever it is, installed or not.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT
ln -s "$ROOT" "$TMP/panogrf"
cd "$TMP"
MYPYPATH="$TMP" "$ROOT/.venv/bin/mypy" --config-file "$ROOT/pyproject.toml" \
  --cache-dir "$ROOT/.mypy_cache" -p panogrf.model -p panogrf.renderer "$@"
