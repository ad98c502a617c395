"""Scripted viewer sessions (`panogrf view --script`, tests, benchmarks): keys by frame.

"w*30,x,wait*10" holds W for 30 frames, presses X once, then waits 10 frames; "refined" waits
until the render worker has refined the still view at every level.
"""

from __future__ import annotations

from collections.abc import Callable

#: The keys the viewer reacts to (moderngl-window's names; scripts use them in lower case).
KEY_NAMES = (
    "W A S D Q E K C P O X H V F G J R TAB LEFT RIGHT UP DOWN ESCAPE MINUS EQUAL LEFT_BRACKET "
    "RIGHT_BRACKET NUMBER_1 NUMBER_2 NUMBER_3 NUMBER_4 BACKSPACE DELETE COMMA PERIOD"
).split()


def parse_script(text: str) -> list[tuple[str, int]]:
    """ "w*30,x,wait*10" -> [("W", 30), ("X", 0), ("WAIT", 10)]: hold a key for N frames, or
    press it once (no count); "refined" waits until the render worker has refined the view.
    A token that is no key of the viewer, or a count that is no whole number of frames > 0,
    raises ValueError naming it: a typo would otherwise do nothing, silently."""
    names = {str(i): f"NUMBER_{i}" for i in range(1, 5)}
    names |= {
        "[": "LEFT_BRACKET",
        "]": "RIGHT_BRACKET",
        "-": "MINUS",
        "=": "EQUAL",
        "esc": "ESCAPE",
        "tab": "TAB",
    }
    out = []
    for token in (t.strip() for t in text.split(",") if t.strip()):
        key, star, count = (t.strip() for t in token.partition("*"))
        name = names.get(key.lower(), key.upper())
        if name not in (*KEY_NAMES, "WAIT", "REFINED"):
            known = ", ".join(k.lower() for k in (*KEY_NAMES, "WAIT", "REFINED"))
            raise ValueError(f"unknown key {key!r} in {token!r} (keys: {known})")
        if star and not (count.isdigit() and int(count) > 0):
            raise ValueError(f"{token!r}: the count after * must be a whole number of frames > 0")
        out.append((name, int(count) if star else 0))
    return out


class ScriptPlayer:
    """Plays parsed steps, one per frame: presses once, holds for a count of frames."""

    def __init__(self, steps: list[tuple[str, int]]) -> None:
        self.steps = list(steps)

    def __bool__(self) -> bool:
        return bool(self.steps)

    def step(self, press: Callable[[str], None], held: set, refined: Callable[[], bool]) -> None:
        """This frame's input: ``press(name)`` for a one-shot key, ``held`` gains or loses a
        held key; ``refined()`` says whether a "refined" step may end."""
        if not self.steps:
            return
        name, frames = self.steps[0]
        if name == "REFINED":  # wait until the worker has refined every level
            if refined():
                self.steps.pop(0)
            return
        if name != "WAIT":
            if frames == 0:  # a press: one-shot action
                press(name)
            else:
                held.add(name)
        if frames <= 1:
            self.steps.pop(0)
            if name != "WAIT":
                held.discard(name)
        else:
            self.steps[0] = (name, frames - 1)
