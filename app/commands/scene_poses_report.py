"""The report of `panogrf scene from-panoramas` (`panogrf.app.commands.scene_poses`): its
printed lines, a line per pair and per view of a `panogrf.app.poses.colmap_report.ColmapEstimate`
(`pose_report`), the same in JSON in the scene folder (`REPORT`), and the advice a failure ends
with (`ADVICE`).
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np

from panogrf.app.poses.colmap import ColmapConfig

#: What to do when panoramas cannot be posed (the failure's one line ends with it).
ADVICE = (
    "try a photo between the two (each pair should share most of the room: 1-3 m apart "
    "indoors), fewer moving objects or people, or poses from another tool with "
    "`panogrf scene import --format colmap|opensfm|tum`"
)

#: The report's file in the scene folder (JSON; the printed report is its "lines").
REPORT = "poses_report.json"


#: At most this many failed pairs are printed one by one.
MAX_LISTED_FAILURES = 10


def _deg(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.3f} deg"


def shown_names(files: list[Path]) -> list[str]:
    """How the report names each photo: its file name, or as many of its last path parts as
    tell it from another photo of the same name (``a/x.jpg``, ``b/x.jpg``)."""
    for k in range(1, max(len(f.parts) for f in files) + 1):
        names = ["/".join(f.parts[-k:]) for f in files]
        clash = {n for n in names if names.count(n) > 1}
        if not clash:
            return names
    return [str(f) for f in files]  # the same path twice: refused before any report


def left_out_line(files: list[Path], registered) -> str:
    """The report's line naming the panoramas no pair posed, and what to do."""
    left = [name for name, ok in zip(shown_names(files), registered, strict=True) if not ok]
    return f"left out {len(left)} panorama(s) that could not be posed: {', '.join(left)}; " + ADVICE


def pose_report(files: list[Path], est) -> list[str]:
    """The printed report of a `ColmapEstimate`: a line per pair and per view."""
    names = shown_names(files)
    lines = [f"posing (COLMAP {est.mapper or 'mappers'}, {est.seconds:.1f} s):", "pairs:"]
    # A home of many photos has hundreds of pairs that share nothing: those are counted here
    # and each is in the report's file. A pair that failed for another reason is printed.
    least = ColmapConfig.min_pair_inliers
    few = [p for p in est.pairs if not p.ok and p.inliers < least]
    hidden = {(p.i, p.j) for p in few} if len(few) > MAX_LISTED_FAILURES else set()
    listed = [p for p in est.pairs if (p.i, p.j) not in hidden]
    for p in listed:
        state = (
            f"ok, {p.inliers} inliers, {p.shared_points} shared points, "
            f"median residual {_deg(p.residual_deg)}"
            if p.ok
            else f"FAILED: {p.reason}"
        )
        if p.level_search is not None:
            state += (
                f" (matches grown from the level-camera search: {p.level_search[0]} agree"
                f" at its peak, at most {p.level_search[1]} elsewhere)"
            )
        lines.append(f"  {names[p.i]} - {names[p.j]}: {p.matches} matches; {state}")
    if hidden:
        lines.append(
            f"  {len(hidden)} other pairs: fewer than {least} matches agree on a geometry (they "
            f"share too little; each, with its matches, is in {REPORT})"
        )
    lines.append("views:")
    lines += [f"  {names[v.index]}: {v.note}" for v in est.views]
    return lines


def _report_json(files: list[Path], est, lines: list[str]) -> dict:
    names = shown_names(files)
    return {
        "method": (
            "SIFT on cube faces, pooled and guided matching, a level-camera search for pairs"
            f" COLMAP cannot verify; COLMAP {est.mapper}"
        ),
        "seconds": round(est.seconds, 2),
        "median_residual_deg": est.residual_deg,
        "pairs": [
            {
                "a": names[p.i],
                "b": names[p.j],
                "matches": p.matches,
                "inliers": p.inliers,
                "shared_points": p.shared_points,
                "median_residual_deg": p.residual_deg,
                "ok": p.ok,
                "reason": p.reason,
                "level_search": (
                    None
                    if p.level_search is None
                    else {"peak": p.level_search[0], "elsewhere": p.level_search[1]}
                ),
            }
            for p in est.pairs
        ],
        "views": [
            {
                "file": str(files[v.index]),
                "registered": v.registered,
                "points": v.points,
                "median_residual_deg": v.residual_deg,
                "note": v.note,
            }
            for v in est.views
        ],
        "lines": lines,
    }


def _baselines(c2w: np.ndarray) -> str:
    """Every pair's distance for up to five views; for more, each view's nearest one."""
    c = c2w[:, :3, 3]
    if len(c) <= 5:
        pairs = itertools.combinations(range(len(c)), 2)
        return ", ".join(f"{i}-{j} {np.linalg.norm(c[i] - c[j]):.3f}" for i, j in pairs)
    return f"to each view's nearest {nearest_baselines(c)}"


def nearest_baselines(centres: np.ndarray) -> str:
    """The distance from each of the centres [V, 3] (two or more) to its nearest: its least,
    median and greatest, and the greatest distance of any two."""
    dist = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    largest = dist.max()
    np.fill_diagonal(dist, np.inf)
    near = dist.min(axis=1)
    return (
        f"min {near.min():.3f}, median {np.median(near):.3f}, max {near.max():.3f}; "
        f"largest pairwise {largest:.3f}"
    )
