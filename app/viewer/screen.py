"""What the viewer puts on screen besides the scene: the panorama's place, the overlay's text.

Pure functions (no GL): the window calls them and draws the result.
"""

from __future__ import annotations

import cv2
import numpy as np

#: Distance shown at the far end of the distance mode's colour map, metres.
MAX_DISTANCE_M = 10.0
#: Overlay text rows, pixels.
ROW = 18
OVERLAY_WIDTH = 460


def letterbox(width: int, height: int, aspect: float = 2.0) -> tuple[int, int, int, int]:
    """The largest centred (x, y, w, h) viewport of ``aspect`` in a width x height window:
    bars left and right (a wide window) or above and below (a tall one)."""
    w = min(width, round(height * aspect))
    h = min(height, round(w / aspect))
    return (width - w) // 2, (height - h) // 2, w, h


def level_weights(levels) -> np.ndarray:
    """Share of the refinement's work per level [L] (by the network's pixels: the cost grows
    with them; a level's fourth entry, when given, is the rows the network runs at)."""
    rows = np.array([float(min(lv[0], lv[3]) if len(lv) > 3 else lv[0]) for lv in levels])
    return rows**2 / (rows**2).sum()


def overall_progress(done: int, fraction: float, weights: np.ndarray) -> float:
    """Progress of the whole refinement in [0, 1]: ``done`` levels finished and ``fraction``
    of the next one, each level counted by its share of the work."""
    finished = float(weights[:done].sum())
    current = float(weights[done]) * fraction if done < len(weights) else 0.0
    return min(1.0, finished + current)


def refine_status(worker_on: bool, requested: bool, done: int, fraction: float, levels) -> str:
    """The refinement's state for the overlay (what is being done, not what is shown)."""
    if not worker_on:
        return "refinement off"
    if not requested:
        return "moving: GL preview"
    total = len(levels)
    if done >= total:
        return f"refinement done ({total}/{total} levels)"
    overall = overall_progress(done, fraction, level_weights(levels))
    return f"refining level {done + 1}/{total} ({fraction:.0%}), {overall:.0%} overall"


def shown_label(
    mode: str, refined_level: int | None, levels: int, source: int, refining: bool = True
) -> str:
    """What the screen shows: "refined" only when the refined frame itself is drawn;
    ``refining`` False: there is no refinement (``--no-refine``) to wait for."""
    if mode == "sources":
        return f"source view {source}"
    if refined_level is not None:
        return f"refined level {refined_level + 1}/{levels}"
    if mode == "distance":
        return "distance (GL preview)"
    if mode == "refined":
        return "GL preview" if not refining else "GL preview (refined frame not ready)"
    return "GL preview"


def refine_summary(log: list[tuple[int, float]], levels: int) -> list[str]:
    """Exit statistics, levels in order and numbered from 1 as on the overlay: the median
    seconds from the camera stopping to each level being shown. ``log``: (level, seconds)."""
    out = []
    for level in range(levels):
        times = [s for lv, s in log if lv == level]
        if times:
            out.append(
                f"refined level {level + 1}/{levels} {float(np.median(times)):.2f} s after "
                f"stopping (median of {len(times)})"
            )
    return out


def turbo_bar(width: int, height: int) -> np.ndarray:
    """The distance colour map, near (left) to far (right): RGBA uint8 [height, width, 4]."""
    ramp = np.linspace(0, 255, width).astype(np.uint8)[None]
    bgr = cv2.applyColorMap(ramp, cv2.COLORMAP_TURBO)[0]
    rgba = np.concatenate((bgr[:, ::-1], np.full((width, 1), 255, np.uint8)), -1)
    return np.repeat(rgba[None], height, axis=0)


#: The overlay's font (OpenCV's Hershey simplex at this scale) and its margin, pixels.
FONT, FONT_SCALE, MARGIN = cv2.FONT_HERSHEY_SIMPLEX, 0.45, 6
#: A message stays on the overlay this long (seconds); at most this many of its lines show.
MESSAGE_SECONDS, MESSAGE_LINES = 8.0, 4


def text_width(text: str) -> int:
    """Pixels ``text`` takes on the overlay."""
    return cv2.getTextSize(text, FONT, FONT_SCALE, 1)[0][0]


def wrap_to_width(line: str, width: int = OVERLAY_WIDTH - 2 * MARGIN) -> list[str]:
    """``line`` broken at spaces into lines of at most ``width`` pixels (a word longer than
    that is broken inside)."""
    out, current = [], ""
    for word in line.split():
        while text_width(word) > width:  # a path or a number longer than the box
            cut = max(1, max(k for k in range(1, len(word) + 1) if text_width(word[:k]) <= width))
            if current:
                out.append(current)
                current = ""
            out.append(word[:cut])
            word = word[cut:]
        trial = f"{current} {word}" if current else word
        if current and text_width(trial) > width:
            out.append(current)
            current = word
        else:
            current = trial
    if current or not out:
        out.append(current)
    return out


class Messages:
    """The overlay's messages: whole messages only (never the tail of one), the newest last,
    at most `MESSAGE_LINES` wrapped lines, each gone `MESSAGE_SECONDS` after it was said; a
    message said again replaces its earlier copy."""

    def __init__(self) -> None:
        self.items: list[tuple[float, str]] = []

    def add(self, text: str, now: float) -> None:
        self.items = [(t, m) for t, m in self.items if m != text] + [(now, text)]

    def lines(self, now: float) -> list[str]:
        self.items = [(t, m) for t, m in self.items if now - t < MESSAGE_SECONDS]
        shown: list[str] = []
        for _, text in reversed(self.items):
            wrapped = wrap_to_width(text)
            if shown and len(shown) + len(wrapped) > MESSAGE_LINES:
                break
            shown = wrapped[:MESSAGE_LINES] + shown
        return shown


def overlay_image(lines: list[str], legend: bool = False) -> np.ndarray:
    """The overlay: white text on a translucent box, RGBA uint8, each line wrapped inside it;
    ``legend`` adds the distance colour map under the text (0 m to `MAX_DISTANCE_M`, black
    where no source saw)."""
    lines = [part for line in lines for part in wrap_to_width(line)]
    rows = len(lines) + (1 if legend else 0)
    img = np.zeros((ROW * rows + 8, OVERLAY_WIDTH, 4), np.uint8)
    img[..., 3] = 140
    texts = [(line, MARGIN, ROW * i + 17) for i, line in enumerate(lines)]
    if legend:
        y = ROW * len(lines)
        img[y + 5 : y + 17, 40:240] = turbo_bar(200, 12)
        texts += [("0 m", 6, y + 17), (f"{MAX_DISTANCE_M:.0f} m+   black: unseen", 246, y + 17)]
    for line, x, y in texts:
        cv2.putText(img, line, (x, y), FONT, FONT_SCALE, (255, 255, 255, 255), 1, cv2.LINE_AA)
    return img
