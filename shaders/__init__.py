"""GLSL shaders, one per file, loaded as package data."""

from importlib.resources import files


def load(name: str, defines: dict[str, object] | None = None) -> str:
    """Source text of `shaders/<name>` (e.g. ``load("erp_from_cube.frag")``), with a
    ``#define NAME value`` line after ``#version`` for each of ``defines``, and each
    ``#include "other.glsl"`` line replaced by that file's text (GLSL itself has no includes;
    code shared by two shaders lives in a ``.glsl`` file).

    Compile-time constants instead of uniforms matter on a CPU rasteriser (Mesa llvmpipe): it
    runs both sides of every branch and keeps dynamically indexed arrays in memory, so a
    shader specialised per mode or view count runs several times faster."""
    text = _with_includes(name)
    if not defines:
        return text
    head, newline, rest = text.partition("\n")
    if not head.startswith("#version"):
        raise ValueError(f"shader {name} does not start with #version")
    lines = "".join(f"#define {key} {value}\n" for key, value in defines.items())
    return head + newline + lines + rest


def _with_includes(name: str, seen: tuple[str, ...] = ()) -> str:
    if name in seen:
        raise ValueError(f"shader {name} includes itself ({' -> '.join(seen + (name,))})")
    text = (files(__name__) / name).read_text(encoding="utf-8")
    out = []
    for line in text.splitlines(keepends=True):
        words = line.split()
        if len(words) == 2 and words[0] == "#include":
            out.append(_with_includes(words[1].strip('"'), seen + (name,)))
        else:
            out.append(line)
    return "".join(out)
