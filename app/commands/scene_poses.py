"""`panogrf scene import | from-panoramas`: scene folders from one's own captures.

Registered under `panogrf scene` by `panogrf.app.commands.scene`. The pose work lives in
`panogrf.app.poses`; this module reads the panoramas, parses options, writes the scene folder
(`panogrf.app.scene.folder.write_scene`) and prints the report (its lines and its JSON:
`panogrf.app.commands.scene_poses_report`).
"""

from __future__ import annotations

import argparse
import re
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from panogrf.app.commands import scene_poses_report as rep
from panogrf.app.errors import UserError
from panogrf.app.files.images import read_rgb, turned_note
from panogrf.app.options import add_options, from_args, option, user_path
from panogrf.app.poses import scale as sc
from panogrf.app.runtime import number

_CONVENTIONS = """\
Written poses: camera-to-world 4x4, OpenGL camera frame (x right, y up, looking down -z),
world y up (levelled so the cameras' mean up axis is +y), the first view at x = z = 0 facing
-z, metres once scaled."""


class Panoramas(NamedTuple):
    """Panorama files read at one size."""

    images: np.ndarray  # uint8 [V, 3, H, W]
    resized: list[bool]  # which were area-averaged down to that size (the others as they are)
    originals: list[np.ndarray]  # uint8 [H', W', 3] each, as read

    def kept(self, keep: np.ndarray) -> Panoramas:
        """Views ``keep`` only, at the smallest of their own sizes (a photo left out no longer
        sets the scene's size)."""
        return _at_smallest([self.originals[k] for k in keep])

    def note(self, paths: list[Path]) -> str | None:
        """The line that says which were resized, if any."""
        if not any(self.resized):
            return None
        h, w = self.images.shape[2:]
        names = ", ".join(p.name for p, r in zip(paths, self.resized, strict=True) if r)
        return f"resized to the smallest photo's {w}x{h}: {names}"


def read_panoramas(paths: list[Path], least_rows: int = 1) -> Panoramas:
    """Panorama files -> uint8 [V, 3, H, W] at the smallest one's size (larger ones
    area-averaged down: photos from two cameras, or one re-exported, still make a scene);
    UserError naming the file for any bad one (or one under ``least_rows``)."""
    from panogrf.model.progress import stage

    images = []
    with stage("reading the photos", len(paths)) as progress:
        for path in paths:
            img = read_rgb(path)  # ImageReadError (a UserError) names the file
            h, w = img.shape[:2]
            if w != 2 * h:
                raise UserError(f"{path}: {w}x{h} is not a 2:1 panorama{turned_note(path)}")
            if h < least_rows:
                least = f"{2 * least_rows}x{least_rows}"
                raise UserError(f"{path}: {w}x{h} is too small to pose (at least {least})")
            images.append(img)
            progress.advance()
    return _at_smallest(images)


def _at_smallest(originals: list[np.ndarray]) -> Panoramas:
    import cv2

    rows = min(img.shape[0] for img in originals)
    resized = [img.shape[0] > rows for img in originals]
    images = [
        cv2.resize(img, (2 * rows, rows), interpolation=cv2.INTER_AREA) if r else img
        for img, r in zip(originals, resized, strict=True)
    ]
    return Panoramas(np.stack(images).transpose(0, 3, 1, 2), resized, originals)


def _view_names(paths: list[Path]) -> list[str]:
    """The photos' stems, or ``view_000``... if two share one or one is not plain (``.jpg``; bytes
    that are not text, lone surrogates here, which transforms.json cannot hold)."""
    names = [p.stem for p in paths]
    if len(set(names)) != len(names) or any(
        not n.isprintable() or n[:1] in ("", ".") for n in names
    ):
        names = [f"view_{k:03d}" for k in range(len(paths))]
    return names


def _check_out(out: Path) -> None:
    try:
        held = (out / "transforms.json").exists()
    except OSError as exc:  # a name too long for the file system
        raise UserError(f"--out {out}: {exc.strerror or exc}") from None
    if held:
        raise UserError(f"{out}: already holds a scene (transforms.json); choose another --out")
    if out.exists() and not out.is_dir():
        raise UserError(f"{out}: exists and is not a folder")
    if out.is_dir() and any(out.iterdir()):  # its files could be overwritten
        raise UserError(f"{out}: a folder that is not empty; choose a new or empty --out")
    if not out.exists() and out.parent.is_dir():  # before the posing, not after it
        try:
            out.mkdir()
            out.rmdir()
        except OSError as exc:
            raise UserError(f"{out}: cannot make this folder ({exc.strerror or exc})") from None


# --- import -------------------------------------------------------------------------------


def _match_images(fmt: str, pose_file: Path, names: list[str] | None, given: list[Path] | None):
    """Image files in pose order, and the index of the pose each belongs to."""
    if names is None:  # TUM: images in file order
        if not given:
            raise UserError(f"{pose_file}: a TUM trajectory has no image names; pass --images")
        return given, list(range(len(given)))
    if given is None:
        if fmt != "opensfm":
            raise UserError(f"{pose_file}: pass the panoramas with --images")
        given = [pose_file.parent / "images" / name for name in names]
        return given, list(range(len(names)))
    key = (lambda p: p.name) if fmt == "opensfm" else (lambda p: p.stem)
    lookup = {n: i for i, n in enumerate(names)}
    order = []
    for path in given:
        if key(path) not in lookup:
            raise UserError(f"{path}: no pose named {key(path)!r} in {pose_file}")
        order.append(lookup[key(path)])
    return given, order


def _refuse_repeats(files: list[Path], images: np.ndarray) -> None:
    """One photograph at two poses is refused, naming both (pixel for pixel the same)."""
    for a in range(len(files)):
        for b in range(a + 1, len(files)):
            if np.array_equal(images[a], images[b]):
                same = files[a].resolve() == files[b].resolve()
                what = "given twice" if same else f"the same image as {files[a]} (no parallax)"
                raise UserError(f"{files[b]}: {what}")


def run_import(parsed: argparse.Namespace) -> int:
    from panogrf.app.poses.importers import read_poses
    from panogrf.app.scene.folder import write_new_scene

    args = from_args(ImportOptions, parsed)
    _check_out(args.out)
    poses = read_poses(args.format, args.pose_file)
    files, order = _match_images(args.format, args.pose_file, poses.names, args.images)
    if poses.names is None and len(files) != len(poses.c2w):
        raise UserError(
            f"{args.pose_file}: {len(poses.c2w)} poses but {len(files)} --images; "
            "give one panorama per line, in order"
        )
    if len(files) < 2:
        raise UserError(f"{args.pose_file}: a scene needs at least two panoramas")
    read = read_panoramas(files)
    images = read.images
    _refuse_repeats(files, images)
    c2w = poses.c2w[order]
    lines = [f"imported {len(files)} poses from {args.pose_file} ({args.format})"]
    if note := read.note(files):
        lines.append(note)
    if not args.keep_world:
        with np.errstate(all="ignore"):  # absurd positions: refused below, in one line
            up = sc.camera_up(c2w)
            tilt = [np.degrees(np.arccos(np.clip(m[:3, 1] @ up, -1, 1))) for m in c2w]
            c2w = sc.canonical_frame(c2w, up)
        lines.append(
            "levelled: world up = the cameras' mean up axis; camera tilts from it (deg): "
            + ", ".join(f"{t:.2f}" for t in tilt)
        )
    if args.distance:
        i, j, m = sc.parse_distance(args.distance, len(c2w))
        s = sc.scale_from_distance(c2w, i, j, m)
        lines.append(f"scale: views {i} and {j} are {m} m apart (factor {s:.4g})")
    elif args.scale:
        s = args.scale
        lines.append(f"scale: factor {s:.4g} from --scale")
    else:
        s = 1.0
        lines.append("scale: the tool's own units, taken as metres (no --distance or --scale)")
    c2w = sc.scale_centres(c2w, s)
    from panogrf.app.scene.pose_check import poses_problems

    problems = poses_problems(c2w)  # never write a scene its own check rejects (issue 57, S3)
    if problems:
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        raise UserError(f"{args.pose_file}: the imported poses make no scene: {problems[0]}{more}")
    meta = {"poses": {"imported": args.format}}
    copies = [None if r else f for f, r in zip(files, read.resized, strict=True)]
    names = _view_names([Path(f) for f in files])
    write_new_scene(args.out, c2w, images, names=names, metadata=meta, files=copies)
    lines += [f"  {n}" for n in poses.notes]
    lines.append(f"baselines (m): {rep._baselines(c2w)}")
    lines.append(f"wrote {args.out}")
    print("\n".join(lines))
    return 0


@dataclass(frozen=True, kw_only=True)
class ImportOptions:
    """`panogrf scene import`'s options."""

    pose_file: Path = option(help="", positional=True, metavar="POSE_FILE")
    format: str = option(help="", choices=("tum", "opensfm", "colmap"))
    images: list[Path] | None = option(
        None,
        help="the panoramas: TUM in line order; OpenSfM by file name (default: images/ beside "
        "the JSON); COLMAP by stem (the <panorama> of <panorama>/<face>.png)",
        parse=user_path,
        nargs="+",
    )
    out: Path = option(help="scene folder to write")
    distance: str | None = option(
        None, help="I,J=METRES: views I and J are this far apart", at_most_one="scale"
    )
    scale: float | None = option(
        None,
        help="multiply the tool's units by this (a positive number)",
        parse=number(float, 0.0, low_open=True),
        at_most_one="scale",
    )
    keep_world: bool = option(False, help="keep the tool's world frame (no levelling)")


def _add_import(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "import",
        help="a scene folder from panoramas and a pose file of another tool",
        description=(
            "Write a scene folder from panoramas and their poses in a TUM trajectory "
            "(stella_vslam / OpenVSLAM), an OpenSfM reconstruction.json (spherical cameras) or "
            "a COLMAP images.txt of cube faces. Conventions: see `panogrf.app.poses.importers`."
            "\n\n" + _CONVENTIONS
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=(
            "examples:\n"
            "  panogrf scene import --format tum keyframe_trajectory.txt --images a.jpg b.jpg "
            "--out myroom --distance 0,1=2.5\n"
            "  panogrf scene import --format opensfm project/reconstruction.json --out myroom\n"
            "  panogrf scene import --format colmap sparse/images.txt --images a.jpg b.jpg "
            "--out myroom"
        ),
    )
    add_options(parser, ImportOptions)
    parser.set_defaults(func=run_import)


# --- from-panoramas -----------------------------------------------------------------------


def run_from_panoramas(parsed: argparse.Namespace) -> int:
    from panogrf.app.files.images import write_json_atomic
    from panogrf.app.poses.colmap import estimate_poses_colmap
    from panogrf.app.scene.folder import write_new_scene

    args = from_args(FromPanoramasOptions, parsed)
    files = list(args.panoramas)
    if len(files) < 2:
        raise UserError(f"{files[0]}: one panorama; poses need at least two of the same place")
    _check_out(args.out)
    read = read_panoramas(files, least_rows=32)  # smaller: cube faces of a few pixels
    images = read.images
    _refuse_repeats(files, images)
    n = len(files)
    heights = sc.parse_heights(args.camera_height, n) if args.camera_height else None
    distance = sc.parse_distance(args.distance, n) if args.distance else None
    est = estimate_poses_colmap([img.transpose(1, 2, 0) for img in images])
    lines = [f"{n} panoramas ({images.shape[3]}x{images.shape[2]})", *rep.pose_report(files, est)]
    if note := read.note(files):
        lines.insert(1, note)
    keep = np.flatnonzero(est.registered)
    if len(keep) < 2:
        print("\n".join(lines))
        best = max(est.pairs, key=lambda p: p.inliers)
        if best.reason.startswith("no parallax"):
            raise UserError(
                f"{files[best.i]}, {files[best.j]}: taken from one spot (the matches agree with "
                "a turn alone, no parallax); take the photos a step or more apart (1-3 m indoors)"
            )
        raise UserError(
            f"{files[best.i]}, {files[best.j]}: no pair of the {n} panoramas could be posed "
            f"(at best {best.inliers} of {best.matches} matches agree, between these two); "
            + rep.ADVICE
        )
    if distance is not None:
        i, j, m = distance
        if not (est.registered[i] and est.registered[j]):
            bad = i if not est.registered[i] else j
            raise UserError(
                f"{files[bad]}: --distance {args.distance} names view {bad}, which could not be "
                "posed (see the report above)"
            )
        distance = (int(np.searchsorted(keep, i)), int(np.searchsorted(keep, j)), m)
    with np.errstate(over="ignore", invalid="ignore"):  # an absurd scale: refused just below
        metric = sc.make_metric(
            est.c2w[keep], est.points, None if heights is None else heights[keep], distance
        )
    from panogrf.app.scene.pose_check import poses_problems

    problems = poses_problems(metric.c2w)  # never write a scene its own check rejects
    same = re.match(r"frames\[(\d+)\] and frames\[(\d+)\]: views at the same position",
                    problems[0] if problems else "")  # fmt: skip
    # As posed, before the scale, a copy sits on its photo (within 1 % of the views' spread).
    centres = est.c2w[keep][:, :3, 3]
    spread = np.ptp(centres, axis=0).max()
    if same and np.linalg.norm(np.subtract(*centres[[int(same[1]), int(same[2])]])) < 1e-2 * spread:
        a, b = (files[keep[int(same[k])]] for k in (1, 2))
        print("\n".join(lines))
        raise UserError(
            f"{a}, {b}: posed at one spot (under 1 mm apart): the same photo twice, or taken "
            "without a step between; leave one out"
        )
    if problems:
        given = "--distance" if args.distance else "--camera-height" if heights is not None else ""
        by = f"{given} {args.distance or args.camera_height}: " if given else ""
        raise UserError(f"{by}the scaled poses make no scene: {problems[0]}")
    lines += metric.lines
    lines.append(f"median residual over all points: {rep._deg(est.residual_deg)}")
    names = _view_names([files[k] for k in keep])
    lines.append(f"baselines (m): {rep._baselines(metric.c2w)}")
    if len(keep) < n:
        lines.append(rep.left_out_line(files, est.registered))
    kept = read.kept(keep)  # at the smallest kept photo's size
    size = f"{kept.images.shape[3]}x{kept.images.shape[2]}"
    lines.append(f"wrote {args.out} ({size}; the report: {args.out / rep.REPORT})")
    meta = {
        "poses": {
            "estimated_from": [str(files[k]) for k in keep],
            "residual_deg": None if est.residual_deg is None else round(est.residual_deg, 4),
            "scale": next(x for x in metric.lines if x.startswith("scale:")),
            "report": rep.REPORT,
        }
    }
    copies = [None if r else files[k] for k, r in zip(keep, kept.resized, strict=True)]
    write_new_scene(args.out, metric.c2w, kept.images, names=names, metadata=meta, files=copies)
    report = rep._report_json(files, est, lines)
    report["scale"] = metric.lines
    try:
        write_json_atomic(args.out / rep.REPORT, report)
    except OSError as exc:
        lines[-1] = f"wrote {args.out} (the report could not be saved: {exc.strerror or exc})"
    print("\n".join(lines))
    return 0


@dataclass(frozen=True, kw_only=True)
class FromPanoramasOptions:
    """`panogrf scene from-panoramas`' options."""

    panoramas: list[Path] = option(
        help="", positional=True, metavar="PANORAMA", nargs="+", parse=user_path
    )
    out: Path = option(help="scene folder to write")
    camera_height: str | None = option(
        None,
        help="camera height above the floor: one value for all, or one per panorama (a,b,c)",
        metavar="METRES",
        at_most_one="scale",
    )
    distance: str | None = option(
        None, help="views I and J are this far apart", metavar="I,J=METRES", at_most_one="scale"
    )
    quiet: bool = option(False, help="no progress of the stages on stderr")


def _add_from_panoramas(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "from-panoramas",
        help="a posed scene folder from plain 360-degree photos (poses estimated)",
        description=(
            "Estimate the relative poses of panoramas of one place from their pixels (SIFT on "
            "cube faces, pooled and guided matching; COLMAP's geometric verification, global "
            "mapping and bundle adjustment on equirectangular cameras), make them upright "
            "(floor plane, else level cameras) and metric, and write a scene folder for view, "
            "render, depth and eval. The report (printed, and poses_report.json in the scene) "
            "lists matches, inliers and residuals per pair and per view, and which failed and "
            "why. Metric scale "
            "comes from --camera-height or --distance; without either the mean camera height "
            "is assumed to be 1.5 m (said in the report).\n\n" + _CONVENTIONS
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=(
            "example: panogrf scene from-panoramas a.jpg b.jpg c.jpg --out myroom "
            "--camera-height 1.6"
        ),
    )
    add_options(parser, FromPanoramasOptions)
    parser.set_defaults(func=run_from_panoramas)
