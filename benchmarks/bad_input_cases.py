"""The cases of the bad-input battery (`bad_inputs.py` runs them): bad and edge inputs of every
command, by category, with the files each needs and the checks of what it must leave behind."""

from __future__ import annotations

import json
import math
import shutil
import signal
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PANOGRF = [str(ROOT / ".venv" / "bin" / "panogrf")]
DEMO = ROOT / "assets" / "demo"
C2W = "1 0 0 8.5 0 1 0 1.5 0 0 1 2.0 0 0 0 1"  # inside the demo room
QUICK = ["--method", "nearest", "--height", "32"]  # no network: the plumbing is what is tested


@dataclass
class Case:
    name: str
    category: str
    argv: list[str]
    """Arguments after `panogrf`; ``{w}`` is the working folder."""
    expect: str = "error"
    """"error" (refused with a message) or "ok" (exit 0)."""
    setup: Callable[[Path], None] | None = None
    check: Callable[[Path, str], str | None] | None = None
    """(working folder, stdout) -> a problem, or None; its failure counts as `loss`."""
    loss: str = "silent"
    """What a failed check is: "silent" (a wrong result) or "data loss"."""
    says: str = ""
    """Text the message must hold (else `failed`)."""
    slow: bool = False
    closed_stdout: bool = False
    exit_codes: tuple[int, ...] = (0,)
    """The exit statuses of success (expect "ok")."""


# -- setups ----------------------------------------------------------------------------------


def write(rel: str, text: str | bytes) -> Callable[[Path], None]:
    def setup(w: Path) -> None:
        p = w / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(text if isinstance(text, bytes) else text.encode())

    return setup


def mkdir(rel: str) -> Callable[[Path], None]:
    return lambda w: (w / rel).mkdir(parents=True, exist_ok=True)


def edit_scene(change: Callable[[dict, Path], None]) -> Callable[[Path], None]:
    """Change scene/transforms.json (and files) with ``change(data, scene_folder)``."""

    def setup(w: Path) -> None:
        path = w / "scene" / "transforms.json"
        data = json.loads(path.read_text())
        change(data, w / "scene")
        path.write_text(json.dumps(data))

    return setup


def truncated_jpeg(data: dict, scene: Path) -> None:
    import cv2

    img = cv2.imread(str(scene / data["frames"][1]["file_path"]))
    ok, buf = cv2.imencode(".jpg", img)
    (scene / "images" / "frame_001.jpg").write_bytes(buf.tobytes()[: len(buf) // 2])
    data["frames"][1]["file_path"] = "images/frame_001.jpg"


def wrong_size(data: dict, scene: Path) -> None:
    import cv2
    import numpy as np

    cv2.imwrite(str(scene / data["frames"][1]["file_path"]), np.zeros((50, 100, 3), np.uint8))


def camera_path(w: int, h: int, kind: str = "equirectangular", n: int = 3, **top) -> dict:
    poses = [[1, 0, 0, 8.5 + 0.1 * i, 0, 1, 0, 1.5, 0, 0, 1, 2.0, 0, 0, 0, 1] for i in range(n)]
    data = {"camera_type": kind, "render_width": w, "render_height": h, "fps": 30}
    data |= {"seconds": n / 30, "camera_path": [{"camera_to_world": p, "fov": 60} for p in poses]}
    return data | top


def path_file(w: int, h: int, kind: str = "equirectangular", n: int = 3, **top):
    return write("path.json", json.dumps(camera_path(w, h, kind, n, **top)))


def both(*setups: Callable[[Path], None]) -> Callable[[Path], None]:
    return lambda w: [s(w) for s in setups]


def dataset(index: str | bytes | None = "") -> Callable[[Path], None]:
    """ds/ holding the scene as ds/s and ``index`` as dataset.json: none for "", a folder for
    None."""

    def setup(w: Path) -> None:
        (w / "ds").mkdir()
        shutil.copytree(w / "scene", w / "ds" / "s")
        if index is None:
            (w / "ds" / "dataset.json").mkdir()
        elif index:
            write("ds/dataset.json", index)(w)

    return setup


# -- checks ----------------------------------------------------------------------------------


def strict_json(w: Path, out: str) -> str | None:
    try:
        json.loads(out, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
    except ValueError as exc:
        return f"stdout is not valid JSON: {exc}"
    return None


def frames_in(folder: str, n: int) -> Callable[[Path, str], str | None]:
    def check(w: Path, out: str) -> str | None:
        found = sorted((w / folder).glob("*.png"))
        return None if len(found) == n else f"{len(found)} frames in {folder}/, expected {n}"

    return check


def no_temporaries(w: Path, out: str) -> str | None:
    left = [p.name for p in w.rglob(".*") if p.is_file() and p.name != ".keep"]
    return f"temporaries left: {left}" if left else None


def unchanged(rel: str) -> Callable[[Path, str], str | None]:
    """The earlier good output (its bytes in ``rel + '.good'``) is intact; no temporaries."""

    def check(w: Path, out: str) -> str | None:
        good, now = (w / f"{rel}.good").read_bytes(), w / rel
        if not now.is_file() or now.read_bytes() != good:
            return f"{rel} was damaged"
        return no_temporaries(w / Path(rel).parent, out)

    return check


def unchanged_scene(w: Path, out: str) -> str | None:
    """The scene's transforms.json is still the bundled one's."""
    same = (w / "scene" / "transforms.json").read_bytes() == (DEMO / "transforms.json").read_bytes()
    return None if same else "scene/transforms.json was overwritten"


#: A geo-referenced world's map-grid offset (metres; issue 57, S1).
FAR = (5e5, 0.0, 5e6)
FAR_RENDER = ["--height", "64", "--json", "--quiet", "--no-refine-depth"]


def moved_far(data: dict, scene: Path) -> None:
    for frame in data["frames"]:
        for row, shift in zip(frame["transform_matrix"][:3], FAR, strict=True):
            row[3] += shift


def renders_as_near(w: Path, out: str) -> str | None:
    """The far scene's scored render (``--json``) is the same as the scene's at the origin."""
    args = ["render", str(DEMO), "--out", str(w / "near.png"), "--target-frame", "1"]
    near = subprocess.run([*PANOGRF, *args, *FAR_RENDER], capture_output=True, text=True)
    if near.returncode != 0:
        return f"the render at the origin failed: {near.stderr.strip()[-200:]}"
    a = json.loads(out)["metrics"]["ws_psnr"]
    b = json.loads(near.stdout)["metrics"]["ws_psnr"]
    return None if abs(a - b) < 0.05 else f"WS-PSNR {a:.2f} dB far, {b:.2f} dB at the origin"


def full_disk(out: str, first: list[str]) -> Callable[[Path], None]:
    """A tiny tmpfs at ``disk/`` holding a good ``out`` written by ``panogrf FIRST``, then full."""

    def setup(w: Path) -> None:
        disk = w / "disk"
        disk.mkdir()
        subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(disk)], check=True)
        argv = [a.format(w=w) for a in first]
        subprocess.run(PANOGRF + argv, cwd=w, capture_output=True, check=True)
        (w / f"{out}.good").write_bytes((w / out).read_bytes())
        with open(disk / "ballast", "wb", buffering=0) as f:
            try:
                while True:
                    f.write(b"\0" * 4096)
            except OSError:
                pass

    return setup


def cases() -> list[Case]:
    r, q = ["render", "scene", "--out"], QUICK
    tgt = ["--target-frame", "1"]
    path = ["render", "scene", "--camera-path", "path.json", "--method", "nearest"]
    ev = ["eval", "ds", "--out", "r.json", "--methods", "nearest", "--height", "32"]
    view = ["view", "scene", "--window", "headless", "--no-refine", "--frames", "2"]
    E, S, C, I, N, O, D, X = (
        "scene folder", "camera path", "command line", "image", "number", "output",
        "dataset.json", "script",
    )  # fmt: skip
    return [
        # scene folders
        Case("scene missing", E, ["scene", "check", "nope"]),
        Case("scene empty folder", E, ["scene", "check", "empty"], setup=mkdir("empty")),
        Case("scene is a file", E, ["scene", "check", "scene/transforms.json"]),
        Case("transforms not JSON", E, ["scene", "check", "scene"],
             setup=write("scene/transforms.json", "{")),
        Case("transforms not UTF-8", E, ["scene", "check", "scene"],
             setup=write("scene/transforms.json", b"\xff\xfe{")),
        Case("transforms w Infinity", E, ["scene", "check", "scene"],
             setup=edit_scene(lambda data, scene: data.update(w=math.inf))),
        Case("frame image missing", E, [*r, "x.png", *tgt, *q],
             setup=lambda w: (w / "scene/images/frame_002.png").unlink()),
        Case("frame image wrong size", E, ["scene", "check", "scene"],
             setup=edit_scene(wrong_size)),
        Case("truncated JPEG: scene check", I, ["scene", "check", "scene"],
             setup=edit_scene(truncated_jpeg)),
        Case("truncated JPEG: render", I, [*r, "x.png", *tgt, *q],
             setup=edit_scene(truncated_jpeg)),
        Case("scene check | closed pipe", C, ["scene", "check", "scene"], closed_stdout=True,
             expect="ok", exit_codes=(141,)),
        # images (compare)
        Case("compare missing image", I, ["compare", "scene/images/frame_000.png", "no.png"]),
        Case("compare different sizes", I, ["compare", "scene/images/frame_000.png", "s.png"],
             setup=lambda w: wrong_size({"frames": [{}, {"file_path": "s.png"}]}, w)),
        Case("compare truncated JPEG", I, ["compare", "scene/images/frame_000.png",
             "scene/images/frame_001.jpg"], setup=edit_scene(truncated_jpeg)),
        Case("compare --json identical", I, ["compare", "--json", "scene/images/frame_000.png",
             "scene/images/frame_000.png"], expect="ok", check=strict_json),
        # camera paths
        Case("path missing", S, [*path, "--out", "v.mp4"]),
        Case("path not JSON", S, [*path, "--out", "v.mp4"], setup=write("path.json", "[")),
        Case("path 40000x20000", S, [*path, "--out", "v.mp4"], setup=path_file(40000, 20000)),
        Case("path perspective 9000x100", S, [*path, "--out", "f"],
             setup=path_file(9000, 100, "perspective")),
        Case("path 4x2", S, [*path, "--out", "f"], setup=path_file(4, 2)),
        Case("path width != 2 x height", S, [*path, "--out", "f"], setup=path_file(64, 64)),
        Case("path NaN pose", S, [*path, "--out", "f"], setup=write("path.json", json.dumps(
             camera_path(64, 32) | {"camera_path": [{"camera_to_world": [math.nan] * 16}]}))),
        Case("path no cameras", S, [*path, "--out", "f"], setup=path_file(64, 32, n=0)),
        Case("path odd size to MP4", S, [*path, "--out", "v.mp4"],
             setup=path_file(66, 33, "perspective")),
        Case("path with --height", S, [*path, "--out", "f", "--height", "32"],
             setup=path_file(64, 32)),
        Case("path preview over GL texture limit", S, [*path[:4], "--quality", "preview",
             "--out", "f"], setup=path_file(8192, 4096)),
        Case("path to folder, stale frames", S, [*path, "--out", "f"], expect="ok",
             setup=both(path_file(64, 32), mkdir("f"), write("f/frame_00004.png", b"old")),
             check=frames_in("f", 3)),
        # command line and numbers
        Case("render --quality draft", C, [*r, "x.png", *tgt, "--height", "16", "--quality",
             "draft"], expect="ok"),
        Case("render --json at 8 rows", C, [*r, "x.png", *tgt, "--method", "nearest",
             "--height", "8", "--json"], expect="ok", check=strict_json),
        Case("render --json at 10 rows", C, [*r, "x.png", *tgt, "--method", "nearest",
             "--height", "10", "--json"], expect="ok", check=strict_json),
        Case("render --json at 64 rows", C, [*r, "x.png", *tgt, "--method", "nearest",
             "--height", "64", "--json"], expect="ok", check=strict_json),
        Case("render scored at 4096 rows", C, [*r, "x.png", *tgt, "--method", "nearest",
             "--height", "4096"], expect="ok", slow=True),
        Case("render preview over GL texture limit", C, [*r, "x.png", "--c2w", C2W,
             "--quality", "preview", "--height", "4096"]),
        Case("render --height -5", N, [*r, "x.png", *tgt, "--height", "-5"]),
        Case("render --height 100000", N, [*r, "x.png", *tgt, "--height", "100000"]),
        Case("render --threads -1", N, [*r, "x.png", *tgt, "--threads", "-1"]),
        Case("view --threads -1", N, [*view, "--threads", "-1"]),
        Case("eval --threads -1", N, [*ev, "--threads", "-1"], setup=dataset()),
        Case("render --target-frame 99", N, [*r, "x.png", "--target-frame", "99", *q]),
        Case("render --target-frame -1", N, [*r, "x.png", "--target-frame", "-1", *q]),
        Case("render --sources out of range", N, [*r, "x.png", *tgt, "--sources", "0,7", *q]),
        Case("render a scene 5e6 m from the origin", E, [*r, "x.png", *tgt, *FAR_RENDER],
             expect="ok", setup=edit_scene(moved_far), check=renders_as_near, slow=True),
        Case("render --c2w NaN", N, [*r, "x.png", "--c2w", C2W.replace("8.5", "nan"), *q]),
        Case("render --c2w 15 numbers", N, [*r, "x.png", "--c2w", C2W[:-2], *q]),
        Case("eval --height -5", N, [*ev[:-2], "--height", "-5"], setup=dataset()),
        Case("eval --limit 0", N, [*ev, "--limit", "0"], setup=dataset()),
        Case("reproject --occlusion-tol -1", N, ["scene", "reproject", "scene",
             "--occlusion-tol", "-1"]),
        Case("reproject --occlusion-tol nan", N, ["scene", "reproject", "scene",
             "--occlusion-tol", "nan"]),
        Case("view --size 10x10", N, [*view, "--size", "10x10"]),
        Case("view --frames 0", N, [*view[:-1], "0"]),
        Case("view --start-frame 9", N, [*view, "--start-frame", "9"]),
        Case("view --path-out onto the scene's transforms.json", O,
             [*view, "--path-out", "scene/transforms.json", "--script", "k,o"],
             check=unchanged_scene, loss="data loss", says="refusing"),
        Case("view --camera-path keyframe 1e12 m away", S,
             [*view, "--camera-path", "far.json"], setup=write("far.json", json.dumps({
                 **camera_path(64, 32), "keyframes": [{"matrix": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1,
                 0, 1e12, 0, 0, 1], "fov": 75}]})), says="farther than"),
        Case("unknown option: subcommand usage", C, [*view, "--bogus"],
             says="usage: panogrf view"),
        # outputs
        Case("render --out missing folder", O, [*r, "no/x.png", *tgt, *q]),
        Case("render --out a folder", O, [*r, "d.png", *tgt, *q], setup=mkdir("d.png")),
        Case("render --out unwritable", O, [*r, "/proc/x.png", *tgt, *q]),
        Case("render --out .txt", O, [*r, "x.txt", *tgt, *q]),
        Case("path --out MP4 is a folder", O, [*path, "--out", "v.mp4"],
             setup=both(path_file(64, 32), mkdir("v.mp4")), check=no_temporaries),
        Case("path --out folder is a file", O, [*path, "--out", "f"],
             setup=both(path_file(64, 32), write("f", "x"))),
        Case("eval --out unwritable", O, [*ev[:2], "--out", "/proc/r.json", *ev[4:]],
             setup=dataset()),
        Case("eval --out a folder", O, ev, setup=both(dataset(), mkdir("r.json"))),
        # dataset.json
        Case("dataset folder not a string", D, ev, setup=dataset('{"scenes": [{"folder": 5}]}')),
        Case("dataset scenes not a list", D, ev, setup=dataset('{"scenes": {"a": 1}}')),
        Case("dataset a list", D, ev, setup=dataset("[1]")),
        Case("dataset not JSON", D, ev, setup=dataset("{")),
        Case("dataset not UTF-8", D, ev, setup=dataset(b"\xff\xfe")),
        Case("dataset.json a folder", D, ev, setup=dataset(None)),
        Case("dataset missing folder", D, ev, setup=dataset('{"scenes": [{"folder": "x"}]}')),
        Case("dataset folder twice", D, ev,
             setup=dataset('{"scenes": [{"folder": "s"}, {"folder": "s"}]}')),
        # viewer scripts
        Case("script typo jump", X, [*view, "--script", "jump"]),
        Case("script typo zz*3", X, [*view, "--script", "zz*3"]),
        Case("script bad count w*x", X, [*view, "--script", "w*x"]),
        # round two (issue 57): numbers out of range, scenes that crashed the check
        Case("--scale 0", N, ["scene", "import", "t.txt", "--out", "s", "--scale", "0"],
             says="--scale"),
        Case("--scale nan", N, ["scene", "import", "t.txt", "--out", "s", "--scale", "nan"],
             says="--scale"),
        Case("--threads 100000", N, [*r, "x.png", *tgt, *q, "--threads", "100000"],
             says="--threads"),
        Case("--fixed-step -0.5", N, [*view, "--fixed-step=-0.5"], says="--fixed-step"),
        Case("--fixed-step inf", N, [*view, "--fixed-step", "inf"], says="--fixed-step"),
        Case("train --lr nan", N, ["train", "depth", "--data", "d", "--stage", "mono",
             "--out", "m.safetensors", "--lr", "nan"], says="--lr"),
        Case("dataset make --seed -5", N, ["dataset", "make", "--out", "d", "--seed=-5"],
             says="--seed"),
        Case("bench --time-budget -1", N, ["bench", "--time-budget=-1"], says="--time-budget"),
        Case("scene faces --size -5", N, ["scene", "faces", "scene/images/frame_000.png",
             "--out", "f", "--size", "-5"], says="--size"),
        Case("position 1e300", E, ["scene", "check", "scene"], says="farther than",
             setup=edit_scene(lambda d, s: d["frames"][0]["transform_matrix"][0].__setitem__(
                 3, 1e300))),
        Case("file name too long", E, ["scene", "check", "scene"], says="too long",
             setup=edit_scene(lambda d, s: d["frames"][0].__setitem__(
                 "file_path", "images/" + "x" * 300 + ".png"))),
        Case("transforms nested 200000 deep", E, ["scene", "check", "scene"],
             says="nested too deeply", setup=write("scene/transforms.json", "[" * 200_000)),
        Case("camera path nested 200000 deep", C, [*path, "--out", "v.mp4"],
             says="nested too deeply", setup=write("path.json", "[" * 200_000)),
        Case("faces of two panoramas of one name", O, ["scene", "faces",
             "scene/images/frame_000.png", "other/frame_000.png", "--out", "f"],
             says="share the name", setup=lambda w: (w / "other").mkdir() or shutil.copy(
                 w / "scene/images/frame_000.png", w / "other/frame_000.png")),
        Case("train --out /proc", O, ["train", "depth", "--data", "d", "--stage", "mono",
             "--out", "/proc/m.safetensors"], says="cannot write"),
        # data loss: full disk, kill -9
        Case("full disk: PNG", O, [*r, "disk/x.png", *tgt, *q], loss="data loss",
             setup=full_disk("disk/x.png", [*r, "disk/x.png", *tgt, *q]),
             check=unchanged("disk/x.png")),
        Case("full disk: MP4", O, [*path, "--out", "disk/v.mp4"], loss="data loss",
             setup=both(path_file(256, 128, n=30),
                        full_disk("disk/v.mp4", [*path, "--out", "disk/v.mp4"])),
             check=unchanged("disk/v.mp4")),
        Case("kill -9 then again: MP4", O, [*path, "--out", "v.mp4"], expect="ok",
             loss="data loss", setup=both(path_file(256, 128, n=60), killed(path + ["--out",
             "v.mp4"], ".v.*")), check=no_temporaries),
    ]  # fmt: skip


def killed(argv: list[str], writing: str) -> Callable[[Path], None]:
    """Start ``panogrf ARGV`` and kill -9 it once a file matching ``writing`` has data."""

    def setup(w: Path) -> None:
        proc = subprocess.Popen(PANOGRF + argv, cwd=w, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)  # fmt: skip
        deadline = time.monotonic() + 120
        while proc.poll() is None and time.monotonic() < deadline:
            if any(p.stat().st_size > 0 for p in w.glob(writing)):
                break
            time.sleep(0.05)
        proc.send_signal(signal.SIGKILL)
        proc.wait()

    return setup
