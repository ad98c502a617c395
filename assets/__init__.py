"""Bundled data: trained weights (safetensors) and the demo scene."""

from importlib.resources import as_file, files
from pathlib import Path


def path(name: str) -> Path:
    """Filesystem path of a bundled asset (the package is installed unzipped)."""
    with as_file(files(__name__) / name) as p:
        return Path(p)
