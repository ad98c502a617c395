"""GLSL shaders, one per file, loaded as package data."""

from importlib.resources import files


def load(name: str, defines: dict[str, object] | None = None) -> str:
    """Source text of `shaders/<name>` (e.g. ``load("erp_from_cube.frag")``), with a
    ``#define NAME value`` line after ``#version`` for each of ``defines``.

    Compile-time constants instead of uniforms matter on a CPU rasteriser (Mesa llvmpipe): it
    runs both sides of every branch and keeps dynamically indexed arrays in memory, so a
    shader specialised per mode or view count runs several times faster."""
    text = (files(__name__) / name).read_text(encoding="utf-8")
    if not defines:
        return text
    head, newline, rest = text.partition("\n")
    if not head.startswith("#version"):
        raise ValueError(f"shader {name} does not start with #version")
    lines = "".join(f"#define {key} {value}\n" for key, value in defines.items())
    return head + newline + lines + rest
