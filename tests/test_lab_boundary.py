"""The product and the lab stay apart: the product never imports the lab (or the benchmarks),
its assets hold only the weights it reads, and the lab's ablation weights still load from the
repository."""

from __future__ import annotations

import ast
import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PRODUCT = ("app", "renderer", "model")
OUTSIDE = ("lab", "benchmarks", "tests", "scripts")


def _imports(path: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
    return found


def _outside(modules: set[str]) -> set[str]:
    return {m for m in modules if m.split(".")[0] in OUTSIDE or m.startswith("panogrf.lab")}


def test_product_never_imports_the_lab():
    files = [p for root in PRODUCT for p in (ROOT / root).rglob("*.py")]
    assert len(files) > 50
    bad = {str(p.relative_to(ROOT)): _outside(_imports(p)) for p in files}
    assert {k: v for k, v in bad.items() if v} == {}


def test_the_scan_catches_a_lab_import(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text("import os\nfrom lab.ablations import ABLATIONS\nimport benchmarks.gpu\n")
    assert _outside(_imports(probe)) == {"lab.ablations", "benchmarks.gpu"}


def test_assets_hold_only_the_weights_the_product_reads():
    from panogrf.app.weights import networks as dw

    read = {*dw.WEIGHTS.values(), dw.SELECTOR, dw.BLEND, *dw.RENDERER_WEIGHTS.values()}
    read.add("lpips_alex.safetensors")
    shipped = {p.name for p in (ROOT / "assets").glob("*.safetensors")}
    assert shipped == read
    assert not list((ROOT / "assets").rglob("renderer_tiny*"))


def test_lab_ablation_weights_load_from_the_repository(monkeypatch):
    spec = importlib.util.spec_from_file_location("lab_ablations", ROOT / "lab" / "ablations.py")
    ablations = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ablations)
    from panogrf.app.weights import networks as dw

    monkeypatch.setenv("PANOGRF_WEIGHTS", str(ablations.weights_folder()))
    for preset in ablations.ABLATIONS.values():
        net = dw.load_renderer(preset)
        assert net.config == dw.RENDERER_PRESETS[preset]
    assert dw.load_renderer.__wrapped__("panogrf").config == dw.RENDERER_PRESETS["panogrf"]


def test_no_product_module_over_400_lines():
    files = [p for root in PRODUCT for p in (ROOT / root).rglob("*.py")]
    long = {
        str(p.relative_to(ROOT)): n for p in files if (n := len(p.read_text().splitlines())) > 400
    }
    assert long == {}


def test_no_function_of_the_models_over_60_lines():
    """The networks and the depth chain (`model/`) read in pieces: no function over 60 lines."""
    long = {}
    for p in (ROOT / "model").rglob("*.py"):
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                if (n := node.end_lineno - node.lineno + 1) > 60:  # type: ignore[operator]
                    long[f"{p.relative_to(ROOT)}:{node.name}"] = n
    assert long == {}
