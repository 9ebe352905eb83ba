"""The core install (``pip install -e .``) works without the optional packages.

matplotlib and tqdm (the ``demo`` extra) and pandas are hidden from a fresh interpreter by a
meta-path finder; the method still imports and plans, the CLI still prints its help, and a command
that needs a missing package exits 2 with one line naming the extra.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OPTIONAL = ("matplotlib", "tqdm", "pandas")

_BLOCK = textwrap.dedent(
    f"""
    import importlib.abc, sys

    OPTIONAL = {OPTIONAL!r}

    class _Block(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.partition(".")[0] in OPTIONAL:
                raise ImportError(f"No module named {{name!r}} (hidden by the test)")
            return None

    sys.meta_path.insert(0, _Block())
    """
)


def _run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", _BLOCK + textwrap.dedent(code)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )


@pytest.mark.slow
def test_core_imports_and_plans_without_optional_packages():
    r = _run(
        """
        import jax
        import numpy as np

        import frenet
        import mmdopt
        import mmdopt.bench
        import mmdopt.bench.cli
        import solvers

        cfg = mmdopt.MMDOptConfig().replace(
            n_samples=40, n_cem=20, n_elite=10, iterations=2, n_brake=2
        )
        t = np.linspace(0.0, 15.0, 100)  # the planner's default grid: 15 s, 100 points
        obs = np.zeros((1, 20, t.size, 2))
        obs[..., 0] = 60.0 + 5.0 * t
        obs[..., 1] = np.linspace(-0.5, 0.5, 20)[:, None]
        p = mmdopt.plan(
            frenet.EgoState(), mmdopt.Road(), obs, config=cfg, key=jax.random.PRNGKey(0)
        )
        assert np.all(np.isfinite(p.x)), p.status
        loaded = sorted(m for m in sys.modules if m.partition(".")[0] in OPTIONAL)
        assert not loaded, loaded
        print("planned", p.status)
        """
    )
    assert r.returncode == 0, r.stderr[-3000:]
    assert "planned" in r.stdout


def test_cli_help_works_and_demo_names_the_extra_without_optional_packages(tmp_path):
    r = _run(
        """
        from mmdopt.bench.cli import main

        sys.exit(main(["--help"]))
        """
    )
    assert r.returncode == 0, r.stderr[-3000:]
    assert "usage: mmdopt" in r.stdout
    r = _run(
        f"""
        from mmdopt.bench.cli import main

        sys.exit(main(["demo", "--out", {str(tmp_path / "demo")!r}]))
        """
    )
    assert r.returncode == 2, r.stderr[-3000:]
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert "matplotlib" in lines[0] and '".[demo]"' in lines[0]
    assert not (tmp_path / "demo").exists()
