"""The benchmark scripts stay runnable: each parses its command line (a renamed API that a
script still imports shows up here, not on the day someone needs the figure)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# one interpreter for all of them: each ``--help`` imports the script and exits 0 after printing
_DRIVER = """
import contextlib, io, runpy, sys
failed = []
for name in sys.argv[1:]:
    sys.argv = [name, "--help"]
    out = io.StringIO()
    try:
        with contextlib.redirect_stdout(out):
            runpy.run_module(name, run_name="__main__")
        failed.append(f"{name}: returned without printing its usage")
    except SystemExit as e:
        if e.code not in (0, None) or "usage" not in out.getvalue():
            failed.append(f"{name}: exit {e.code!r}")
    except Exception as e:
        failed.append(f"{name}: {type(e).__name__}: {e}")
print("\\n".join(failed))
"""


def test_every_benchmark_script_parses_its_command_line():
    names = sorted(
        f"benchmarks.{p.stem}" for p in (ROOT / "benchmarks").glob("*.py") if p.stem != "__init__"
    )
    assert len(names) > 10
    res = subprocess.run(
        [sys.executable, "-c", _DRIVER, *names],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.strip() == "", f"benchmarks that do not run:\n{res.stdout}"
