"""`panogrf compare` end to end through `panogrf.app.cli.main`, on tiny PNGs."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from panogrf.app.cli import main
from panogrf.model.metrics import psnr, ssim, ws_psnr

H, W = 32, 64  # 2:1, and large enough for LPIPS (>= 31 px)


def _rgb(seed: int, h: int = H, w: int = W) -> np.ndarray:
    """Smooth-ish random RGB uint8 [h, w, 3]."""
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 256, size=(h // 4, w // 4, 3), dtype=np.uint8)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def _write(path: Path, rgb: np.ndarray) -> Path:
    """Write RGB(A) or gray pixels (OpenCV wants BGR order)."""
    if rgb.ndim == 3 and rgb.shape[2] == 3:
        rgb = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    elif rgb.ndim == 3 and rgb.shape[2] == 4:
        rgb = cv2.cvtColor(rgb, cv2.COLOR_RGBA2BGRA)
    assert cv2.imwrite(str(path), rgb)
    return path


@pytest.fixture()
def pair(tmp_path: Path) -> tuple[Path, Path, np.ndarray, np.ndarray]:
    a, b = _rgb(0), _rgb(1)
    return _write(tmp_path / "a.png", a), _write(tmp_path / "b.png", b), a, b


def _json(capsys, *argv: str) -> dict:
    assert main(["compare", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_text_output(pair, capsys):
    pa, pb, _, _ = pair
    assert main(["compare", str(pa), str(pb)]) == 0
    out = capsys.readouterr().out
    for label in ("PSNR", "WS-PSNR", "SSIM", "LPIPS", "64x32, 8-bit RGB"):
        assert label in out


def test_json_matches_the_metrics(pair, capsys):
    pa, pb, a, b = pair
    result = _json(capsys, str(pa), str(pb))
    x = torch.from_numpy(a).permute(2, 0, 1).float() / 255
    y = torch.from_numpy(b).permute(2, 0, 1).float() / 255
    assert (result["width"], result["height"]) == (W, H)
    assert result["psnr"] == pytest.approx(float(psnr(x, y)), abs=1e-5)
    assert result["ws_psnr"] == pytest.approx(float(ws_psnr(x, y)), abs=1e-5)
    assert result["ssim"] == pytest.approx(float(ssim(x, y)), abs=1e-6)
    assert 0.0 < result["lpips"] < 1.5
    assert result["notes"] == []


def test_identical_images_give_null_psnr_in_json(pair, capsys):
    pa, _, _, _ = pair
    result = _json(capsys, str(pa), str(pa))
    assert result["psnr"] is None and result["ws_psnr"] is None
    assert result["ssim"] == pytest.approx(1.0) and result["lpips"] == pytest.approx(0.0)
    assert any("identical" in n for n in result["notes"])
    assert main(["compare", str(pa), str(pa)]) == 0
    assert "inf dB" in capsys.readouterr().out


def test_16bit_rgba_and_gray_are_converted(tmp_path, capsys):
    rgb = _rgb(2)
    a = _write(tmp_path / "a.png", rgb)
    # Same colours at 16 bits with an alpha channel: nearly identical after conversion.
    rgba16 = np.concatenate([rgb, np.full((H, W, 1), 255, np.uint8)], axis=2).astype(np.uint16)
    b = _write(tmp_path / "b16.png", rgba16 * 257)
    result = _json(capsys, str(a), str(b))
    assert result["psnr"] is None  # 8-bit v and 16-bit 257 v are the same value in [0, 1]
    assert any("alpha channel dropped" in n for n in result["notes"])

    gray = _write(tmp_path / "g.png", cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))
    result = _json(capsys, str(gray), str(a))
    assert result["psnr"] > 10.0


def test_non_2to1_reports_null_ws_psnr(tmp_path, capsys):
    a = _write(tmp_path / "a.png", _rgb(3, 40, 40))
    b = _write(tmp_path / "b.png", _rgb(4, 40, 40))
    result = _json(capsys, str(a), str(b))
    assert result["ws_psnr"] is None and result["psnr"] is not None
    assert any("2:1" in n for n in result["notes"])


def _one_line_error(capsys, argv: list[str], match: str) -> str:
    assert main(["compare", *argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("panogrf compare: error:") and match in err
    return err


def test_missing_file_is_one_line_error(pair, tmp_path, capsys):
    pa, _, _, _ = pair
    _one_line_error(capsys, [str(pa), str(tmp_path / "nope.png")], "nope.png: file not found")


def test_unreadable_and_size_mismatch_are_errors(pair, tmp_path, capsys):
    pa, _, _, _ = pair
    junk = tmp_path / "junk.png"
    junk.write_text("not a png")
    _one_line_error(capsys, [str(junk), str(pa)], "junk.png: not a readable image")
    small = _write(tmp_path / "small.png", _rgb(5, 16, 32))
    _one_line_error(
        capsys, [str(pa), str(small)], f"differ in size: {pa} is 64x32, {small} is 32x16"
    )


def test_bad_device_is_an_error(pair, capsys):
    pa, pb, _, _ = pair
    _one_line_error(capsys, [str(pa), str(pb), "--device", "bogus"], "--device 'bogus'")
    # Devices torch names but this tool does not run on: one line, as every command says it.
    for name in ("mps", "xpu", "meta", "hpu"):
        line = _one_line_error(capsys, [str(pa), str(pb), "--device", name], f"--device {name!r}")
        assert "cpu or cuda" in line


def test_help_describes_the_metrics(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["compare", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "WS-PSNR" in out and "LPIPS" in out and "--json" in out


def test_truncated_jpeg_is_refused(pair, tmp_path, capsys):
    pa, _, a, _ = pair
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(a, cv2.COLOR_RGB2BGR))
    cut = tmp_path / "cut.jpg"
    cut.write_bytes(buf.tobytes()[: len(buf) // 2])
    _one_line_error(capsys, [str(pa), str(cut)], "cut.jpg: truncated JPEG")
