"""GLSL shaders, one per file, loaded as package data."""

from importlib.resources import files


def load(name: str) -> str:
    """Source text of `shaders/<name>` (e.g. ``load("erp_from_cube.frag")``)."""
    return (files(__name__) / name).read_text(encoding="utf-8")
