"""Bad-input battery: every command fed bad and edge inputs, each run as `panogrf ...`.

Each case is a subprocess in a fresh working folder holding a copy of the demo scene. It is
classified as:

- ``ok``: the expected outcome; a refusal (non-zero exit, a message on stderr, no traceback)
  for bad inputs, exit 0 and a checked output for edge inputs that must work;
- ``traceback``: stderr holds a Python traceback;
- ``silent``: exit 0 where a refusal was due, or an output that fails its check;
- ``data loss``: an earlier good output damaged, or temporaries left under our naming;
- ``failed``: a refusal where success was due, or a refusal without a message.

Prints a Markdown table (case, exit code, message) last and writes the rows to
``lab/results/bad_inputs.json``. ``--slow`` adds the slow cases (4096-row scoring),
``-k WORD`` runs the cases whose name holds WORD. Full-disk cases mount a tiny tmpfs (root).
Usage: ``.venv/bin/python benchmarks/bad_inputs.py [--slow] [-k WORD]``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bad_input_cases import DEMO, PANOGRF, ROOT, Case, cases  # the list, beside this file

RESULTS = ROOT / "lab" / "results" / "bad_inputs.json"


# -- running ---------------------------------------------------------------------------------


def run_case(case: Case, timeout: float) -> dict:
    w = Path(tempfile.mkdtemp(prefix="panogrf_bad_"))
    try:
        shutil.copytree(DEMO, w / "scene")
        if case.setup is not None:
            case.setup(w)
        argv = [a.format(w=w) for a in case.argv]
        start = time.perf_counter()
        try:
            proc = subprocess.Popen(
                PANOGRF + argv,
                cwd=w,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                env=os.environ | {"OMP_NUM_THREADS": "1"},
            )
            if case.closed_stdout:
                proc.stdout.close()
                out, err = "", proc.communicate(timeout=timeout)[1].decode()
            else:
                out, err = (x.decode() for x in proc.communicate(timeout=timeout))
            code = proc.returncode
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            return row(case, None, "", "timed out", "failed", time.perf_counter() - start, None)
        seconds = time.perf_counter() - start
        verdict, problem = classify(case, code, out, err, w)
        return row(case, code, out, err, verdict, seconds, problem)
    finally:
        if (w / "disk").is_dir():
            subprocess.run(["umount", "-l", str(w / "disk")], check=False)
        shutil.rmtree(w, ignore_errors=True)


def classify(case: Case, code: int, out: str, err: str, w: Path) -> tuple[str, str | None]:
    """The verdict, and what the case's check found wrong (or None)."""
    if "Traceback" in err:
        return "traceback", None
    problem = case.check(w, out) if case.check is not None else None
    if problem:
        return case.loss, problem
    if case.expect == "error":
        if code == 0:
            return "silent", "exit 0 where a refusal was due"
        if not (err + out).strip() or case.says not in err + out:
            return "failed", f"no message{f' with {case.says!r}' if case.says else ''}"
    elif code not in case.exit_codes:
        return "failed", None
    return "ok", None


def message(err: str, out: str) -> str:
    lines = [x for x in err.splitlines() if x.strip() and "it/s" not in x and "frame/s" not in x]
    lines = lines or [x for x in out.splitlines() if x.strip()]
    if any(x.startswith("Traceback") for x in lines):
        return lines[-1].strip()
    first = next((i for i, x in enumerate(lines) if ": error:" in x or "INVALID" in x), None)
    if first is None:
        return (lines or [""])[-1].strip()
    return " ".join(x.strip() for x in lines[first : first + 2])


def row(case: Case, code, out: str, err: str, verdict: str, seconds: float, problem) -> dict:
    text = message(err, out)
    if problem:
        text = f"{problem}: {text}"
    return {
        "case": case.name,
        "category": case.category,
        "command": "panogrf " + " ".join(case.argv),
        "exit": code,
        "result": verdict,
        "message": text[:300],
        "seconds": round(seconds, 2),
    }


def table(rows: list[dict]) -> str:
    lines = ["| case | category | exit | result | message |", "|---|---|---|---|---|"]
    for r in rows:
        msg = r["message"].replace("|", "\\|")
        lines.append(f"| {r['case']} | {r['category']} | {r['exit']} | {r['result']} | {msg} |")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--slow", action="store_true", help="also run the slow cases")
    parser.add_argument("-k", default="", help="only cases whose name contains this")
    parser.add_argument("--timeout", type=float, default=300, help="seconds per case")
    args = parser.parse_args()
    chosen = [c for c in cases() if args.k in c.name and (args.slow or not c.slow)]
    rows = []
    for i, case in enumerate(chosen, 1):
        r = run_case(case, args.timeout)
        rows.append(r)
        print(f"[{i}/{len(chosen)}] {r['result']:<9} {r['case']} ({r['seconds']} s)", flush=True)
    counts = {
        k: sum(r["result"] == k for r in rows)
        for k in ("ok", "traceback", "silent", "data loss", "failed")
    }
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    summary = {"cases": len(rows), **counts, "slow_included": args.slow}
    RESULTS.write_text(json.dumps({"summary": summary, "rows": rows}, indent=2) + "\n")
    print()
    print(table(rows))
    print()
    print(
        f"{len(rows)} cases: {counts['ok']} ok, {counts['traceback']} tracebacks, "
        f"{counts['silent']} silent wrong results, {counts['data loss']} data loss, "
        f"{counts['failed']} failed"
    )
    return 0 if counts["ok"] == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
