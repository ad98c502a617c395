#!/usr/bin/env bash
# Set up everything on a fresh Debian machine: system GL libraries for headless EGL (and Xvfb for
# the windowed tests), a virtual environment in .venv, and the package with its CPU torch.
# Safe to run again: it only installs what is missing.
#   bash scripts/setup.sh --cuda   then replaces the CPU torch by PyTorch's CUDA build of the same
#                                  version (PANOGRF_CUDA picks the build, default cu128) for an
#                                  NVIDIA GPU; every command then runs there (--device auto).
set -euo pipefail
CUDA=0
[ "${1:-}" = "--cuda" ] && CUDA=1
cd "$(dirname "$0")/.."

APT_PACKAGES=(libegl1 libgl1 libegl-mesa0 libgl1-mesa-dri xvfb xdotool libxrender1)
missing=()
for pkg in "${APT_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing system packages: ${missing[*]}"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

PYTHON=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv"
  "$PYTHON" -m venv .venv
fi
# torch is pinned to 2.13.0 in pyproject.toml: the CPU build (an unpinned torch pulls CUDA).
if ! .venv/bin/python -c "import panogrf.app.cli, torch, moderngl, pytest, pyrender, mypy" 2>/dev/null \
   || [ pyproject.toml -nt .venv/.panogrf-installed ] || [ setup.py -nt .venv/.panogrf-installed ]; then
  echo "setup: installing panogrf and its dependencies into .venv"
  .venv/bin/python -m pip install -q --disable-pip-version-check -e ".[dev]"
  touch .venv/.panogrf-installed
fi
if [ "$CUDA" = 1 ] && ! .venv/bin/python -c "import torch, sys; sys.exit(torch.version.cuda is None)"; then
  build=${PANOGRF_CUDA:-cu128}
  echo "setup: replacing the CPU torch by the CUDA build ($build)"
  version=$(.venv/bin/python -c "import torch; print(torch.__version__.split('+')[0])")
  .venv/bin/python -m pip install -q --disable-pip-version-check --force-reinstall \
    "torch==$version" --index-url "https://download.pytorch.org/whl/$build"
fi
echo "setup: ready (.venv/bin/panogrf)"
