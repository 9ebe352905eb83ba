"""Figures a reader understands: every panel of every PNG the CLI writes has labelled
axes (the value axes with their unit) and a legend for its marks and colours.

The figures are inspected as matplotlib objects: ``Figure.savefig`` is wrapped to record each
figure it writes (the real PNG is still written).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure

from mmdopt.bench import plots
from mmdopt.bench.scenes import demo_scene

UNIT = re.compile(r"\([^)]*\)")  # "x (m)", "progress (m)", "... (of 1000)", "... (%)"


@pytest.fixture
def saved(monkeypatch):
    """{path: Figure} of every figure saved while the test runs."""
    out: dict[str, Figure] = {}
    orig = Figure.savefig

    def record(self, fname, *a, **k):
        out[str(Path(fname))] = self
        return orig(self, fname, *a, **k)

    monkeypatch.setattr(Figure, "savefig", record)
    return out


def assert_readable(fig: Figure, name: str) -> None:
    assert fig.axes, f"{name}: no panels"
    for i, ax in enumerate(fig.axes):
        where = f"{name}, panel {i} ({ax.get_title()!r})"
        assert ax.get_xlabel().strip(), f"{where}: no x label"
        assert ax.get_ylabel().strip(), f"{where}: no y label"
        assert UNIT.search(ax.get_ylabel()), f"{where}: y label {ax.get_ylabel()!r} has no unit"
        leg = ax.get_legend() or (fig.legends[0] if fig.legends else None)
        assert leg is not None, f"{where}: no legend"
        texts = [t.get_text() for t in leg.get_texts()]
        assert texts and all(t.strip() for t in texts), f"{where}: empty legend entries"


def _rows():
    rng = np.random.default_rng(0)
    return [
        dict(
            scene=i,
            method=m,
            collision_free=int(rng.integers(900, 1001)),
            n_validation=1000,
            progress_m=float(rng.uniform(80, 150)),
        )
        for i in range(6)
        for m in ("mmd", "degroot")
    ]


def test_collision_free_figure(tmp_path, saved):
    p = plots.collision_box_violin(_rows(), tmp_path / "collision_free.png", ["mmd", "degroot"])
    fig = saved[str(p)]
    assert_readable(fig, "collision_free.png")
    assert "of 1000" in fig.axes[0].get_ylabel()
    legend = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert "mean" in legend and "median" in legend


def test_reduced_set_figure_explains_the_grey_dots(tmp_path, saved):
    rng = np.random.default_rng(1)
    per_scene = {m: list(rng.integers(950, 1001, 4)) for m in ("mmd", "herding", "degroot")}
    rnd = [list(rng.integers(850, 1001, 5)) for _ in range(4)]
    p = plots.reduced_set_figure(per_scene, rnd, tmp_path / "reduced_set.png", n_validation=1000)
    fig = saved[str(p)]
    assert_readable(fig, "reduced_set.png")
    legend = [t.get_text() for t in fig.axes[1].get_legend().get_texts()]
    assert any("random reduced set" in t for t in legend)


def test_timing_figure(tmp_path, saved):
    rows = [
        dict(reduced_set_size=m, n_samples=n, reduced_set_s=1e-3 * m, algorithm1_s=0.1 + 1e-3 * n)
        for m, n in ((5, 100), (10, 100), (20, 100), (10, 50), (10, 200))
    ]
    p = plots.timing_figure(rows, tmp_path / "timing.png")
    assert_readable(saved[str(p)], "timing.png")


@pytest.mark.slow  # compiles Algorithm 1 for two methods (~20-40 s on a loaded 2-core machine)
def test_scene_figure_has_a_legend_per_panel(tmp_path, saved, capsys):
    """``mmdopt bench figure`` (the built-in demo scene, de Groot and MMD-Opt): the PNG it writes
    is readable, every panel's legend names what is drawn, and the x axis spans what is drawn."""
    from mmdopt.bench import cli

    assert cli.main(["bench", "figure", "--out", str(tmp_path)]) == 0
    (png,) = tmp_path.glob("scene_*.png")
    assert str(png) in saved, f"{png} was not written through Figure.savefig"
    fig = saved[str(png)]
    assert_readable(fig, png.name)
    legend = " ".join(t.get_text() for t in fig.axes[1].get_legend().get_texts())
    for what in ("planning samples", "reduced set", "validation sample", "ego plan"):
        assert what in legend
    # the x axis spans what is drawn (the samples end near 150 m), not a fixed 200 m
    obs_end = float(np.asarray(demo_scene().obstacles)[..., 0].max())
    for ax in fig.axes:
        assert ax.get_xlim()[1] <= obs_end + 5.0 + 1e-9


def test_demo_figure_has_a_safety_progress_panel(tmp_path, saved):
    """The scene panels and one safety-progress panel: one line per method through its risk
    levels, labelled as the console table (method key), axes trimmed to the points."""

    class _Plan:  # plan-shaped: the scene panels draw x, y, s, t and the reduced set
        def __init__(self, v):
            self.t = np.linspace(0.0, 15.0, 100)  # the scene's grid
            self.x = v * self.t
            self.y = np.zeros_like(self.t)
            self.s = self.x
            self.reduced_set = None

    scene = demo_scene()
    plans = {"mmd": _Plan(6.0), "degroot": _Plan(5.0)}
    points = [
        dict(method=m, risk=r, collision_free=cf, n_validation=1000, progress_m=pm)
        for m, r, cf, pm in (
            ("mmd", 0.02, 970, 96.1), ("mmd", 0.005, 977, 90.0), ("mmd", 0.001, 992, 78.7),
            ("degroot", 0.02, 989, 81.6), ("degroot", 0.005, 992, 76.7),
            ("degroot", 0.001, 996, 72.0),
        )
    ]  # fmt: skip
    p = plots.demo_figure(scene, plans, points, tmp_path / "demo.png", risk=0.005)
    fig = saved[str(p)]
    assert_readable(fig, "demo.png")
    trade = fig.axes[-1]
    labels = [t.get_text() for t in trade.get_legend().get_texts()]
    assert any("(mmd)" in t for t in labels) and any("(degroot)" in t for t in labels)
    assert "of 1000" in trade.get_ylabel() and "(m)" in trade.get_xlabel()
    lo, hi = trade.get_xlim()
    assert 60 < lo < 72.0 and 96.1 < hi < 110
    assert trade.get_ylim()[1] <= 1000 + 5
    notes = {t.get_text() for t in trade.texts}
    assert {"ε=0.02", "ε=0.005", "ε=0.001"} <= notes
    assert "ε = 0.005" in fig.axes[0].get_title()


@pytest.mark.slow
def test_every_png_the_cli_writes_is_readable(tmp_path, saved, capsys):
    """A tiny run of every CLI command that writes figures; each PNG on disk was inspected.
    Checked where those commands already run: the demo's (written by the quick start's first
    command) in ``test_cli``'s demo test, ``collision_free.png`` in its synthetic sweep test,
    ``timing.png`` in ``test_timing``'s ``bench timing`` test and ``bench figure``'s in
    :func:`test_scene_figure_has_a_legend_per_panel`; ``reduced_set.png`` here."""
    import json

    from mmdopt.bench import cli

    small = tmp_path / "small.json"
    small.write_text(json.dumps({"n_validation": 100}))
    tiny = tmp_path / "tiny.json"  # the figures are checked, not the planner: small sizes
    tiny.write_text(
        json.dumps({"n_samples": 60, "n_cem": 20, "n_elite": 8, "iterations": 3, "reselect": 0})
    )
    argv = ["bench", "reduced-set", "--out", str(tmp_path / "rs"), "--random-sets", "2",
            "--scenes", "1", "--jobs", "1", "--no-progress", "--scene-params", str(small),
            "--config", str(tiny)]  # fmt: skip
    assert cli.main(argv) == 0
    pngs = sorted(tmp_path.rglob("*.png"))
    assert [p.name for p in pngs] == ["reduced_set.png"]
    for png in pngs:
        assert str(png) in saved, f"{png} was not written through Figure.savefig"
        assert_readable(saved[str(png)], png.name)
