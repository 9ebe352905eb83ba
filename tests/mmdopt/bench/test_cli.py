"""The ``mmdopt`` command line: demo, the synthetic sweep (contract columns, resume), bad options,
and a 5-scene smoke run of the whole pipeline with its own bar."""

import argparse
import csv
import json
import os
import subprocess
import sys

import pytest

from mmdopt.bench import cli

CONTRACT = (
    "scene",
    "method",
    "collision_free",
    "n_validation",
    "progress_m",
    "feasible",
    "plan_time_s",
)


def _run(argv, capsys):
    rc = cli.main(argv)
    return rc, capsys.readouterr()


def _exit_code(argv, capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(argv)
    return e.value.code, capsys.readouterr().err


@pytest.mark.parametrize(
    "argv, option",
    [
        (["bench", "synthetic", "--scenes", "0", "--out", "x"], "--scenes"),
        (["bench", "synthetic", "--scenes", "two", "--out", "x"], "--scenes"),
        (["bench", "synthetic", "--out", "x", "--methods", "mmd,bogus"], "--methods"),
        (["bench", "synthetic", "--out", "x", "--preset", "paper1000"], "--preset"),
        (["bench", "synthetic", "--out", "x", "--backend", "nope"], "--backend"),
        (["bench", "synthetic", "--out", "x", "--scene-params", "/no/such.json"], "--scene-params"),
        (["bench", "synthetic", "--out", "x", "--jobs", "-1"], "--jobs"),
        (["bench", "synthetic"], "--out"),
        (["bench", "timing", "--out", "x", "--sizes", "10,zero"], "--sizes"),
        (["bench", "warp"], "warp"),
        (["demo", "--methods", ""], "--methods"),
        (["demo", "--risks", "0.5"], "--risks"),
        (["demo", "--risks", "0.01,low"], "--risks"),
        (["demo", "--risks", "0.01,0.01"], "--risks"),
    ],
)
def test_bad_options_exit_2_naming_the_option(argv, option, capsys):
    code, err = _exit_code(argv, capsys)
    assert code == 2
    assert option in err


def test_unknown_scene_param_key_is_a_clear_error(tmp_path, capsys):
    f = tmp_path / "p.json"
    f.write_text(json.dumps({"n_samples": 10, "speed_sigma": 2.0}))
    code, err = _exit_code(
        ["bench", "synthetic", "--out", str(tmp_path / "o"), "--scene-params", str(f)], capsys
    )
    assert code == 2 and "--scene-params" in err and "speed_sigma" in err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    "overrides, named",
    [
        ({"w_mmd": 1.0, "margin_sideways": 0.3}, "margin_sideways"),
        ({"iterations": 2.5}, "iterations"),
        ({"baseline_margin_scale": -1.0}, "baseline_margin_scale"),
        ({"reduced_set": {"betta": 1.0}}, "betta"),
        ([1, 2], "JSON object"),
    ],
)
def test_bad_planner_config_is_a_clear_error(tmp_path, capsys, overrides, named):
    f = tmp_path / "c.json"
    f.write_text(json.dumps(overrides))
    code, err = _exit_code(
        ["bench", "synthetic", "--out", str(tmp_path / "o"), "--config", str(f)], capsys
    )
    assert code == 2 and "--config" in err and named in err
    assert not (tmp_path / "o").exists()


def test_planner_config_file_overrides_fields():
    import mmdopt

    cfg = cli.load_planner_config_from_dict(
        {"baseline_margin_scale": 1, "w_mmd": 2e4, "reduced_set": {"iterations": 20}}
    )
    assert isinstance(cfg, mmdopt.MMDOptConfig)
    assert cfg.baselines.baseline_margin_scale == 1.0 and isinstance(
        cfg.baselines.baseline_margin_scale, float
    )
    assert cfg.cost.w_mmd == 2e4 and cfg.selection.reduced_set.iterations == 20
    assert (
        cfg.cem.n_samples == mmdopt.MMDOptConfig().cem.n_samples
    )  # untouched fields keep defaults


def test_module_entry_point_exit_status():
    env = dict(os.environ, MPLBACKEND="Agg")
    r = subprocess.run(
        [sys.executable, "-m", "mmdopt", "bench", "synthetic", "--scenes", "-3", "--out", "x"],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert r.returncode == 2 and "--scenes" in r.stderr
    r = subprocess.run(
        [sys.executable, "-m", "mmdopt", "--help"],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert r.returncode == 0 and "demo" in r.stdout and "bench" in r.stdout


# ------------------------------------------------------------------ with Algorithm 1


def _record_figures(monkeypatch) -> dict:
    """Every figure saved through ``Figure.savefig`` from now on, by file name."""
    from matplotlib.figure import Figure

    saved = {}
    orig = Figure.savefig

    def record(self, fname, *a, **k):
        saved[str(fname)] = self
        return orig(self, fname, *a, **k)

    monkeypatch.setattr(Figure, "savefig", record)
    return saved


@pytest.mark.slow
def test_demo_writes_png_and_prints_table(tmp_path, capsys, monkeypatch):
    """Both axes of the trade-off per (method, ε), compile time apart from plan time; the PNG is
    a readable figure (labels with units, legends: ``test_figures.assert_readable``)."""
    from tests.mmdopt.bench.test_figures import assert_readable

    saved = _record_figures(monkeypatch)
    rc, out = _run(["demo", "--out", str(tmp_path)], capsys)
    assert rc == 0
    png = tmp_path / "demo.png"
    assert png.is_file() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert str(png) in saved, "demo.png was not written through Figure.savefig"
    assert_readable(saved[str(png)], "demo.png")
    for word in (
        "method", "risk ε", "collision-free of 1000", "progress (m)", "plan_s (s)",
        "compile_s (s)", "mmd", "degroot", "How to read it", "matched safety",
    ):  # fmt: skip
        assert word in out.out
    rows = json.loads((tmp_path / "demo.json").read_text())
    assert {(r["method"], r["risk"]) for r in rows} == {
        (m, r) for m in ("mmd", "degroot") for r in cli.DEMO_RISKS
    }
    assert all(0 <= r["collision_free"] <= r["n_validation"] == 1000 for r in rows)
    for m in ("mmd", "degroot"):
        rr = [r for r in rows if r["method"] == m]
        assert len({r["compile_s"] for r in rr}) == 1  # one compile per method
        # the compile is not in the plan time: every plan is faster than the first call
        assert all(0 < r["plan_s"] < r["plan_s"] + r["compile_s"] for r in rr)
        assert max(r["plan_s"] for r in rr) < rr[0]["compile_s"]


@pytest.mark.slow
def test_synthetic_two_scenes_contract_and_resume(tmp_path, capsys, monkeypatch):
    """The result contract, the figure (``collision_free.png`` a readable figure:
    ``test_figures.assert_readable``), resuming, and a folder refusing other settings."""
    from tests.mmdopt.bench.test_figures import assert_readable
    from tests.mmdopt.bench.test_frontier import TINY

    saved = _record_figures(monkeypatch)
    small = tmp_path / "small.json"
    small.write_text(json.dumps({"n_validation": 300}))
    tiny = tmp_path / "tiny.json"  # the contract, not the planner: test_frontier's small one
    tiny.write_text(json.dumps(TINY))
    argv = [
        "bench",
        "synthetic",
        "--config",
        str(tiny),
        "--n-samples",  # fixed samples (the forecast path has tests of its own)
        "60",
        "--scenes",
        "2",
        "--seed",
        "3",
        "--out",
        str(tmp_path / "r"),
        "--methods",
        "mmd,degroot",
        "--jobs",
        "1",
        "--scene-params",
        str(small),
        "--no-progress",
    ]
    rc, out = _run(argv, capsys)
    assert rc == 0 and "4 plans computed, 0 reused" in out.out
    with open(tmp_path / "r" / "results.csv") as f:
        reader = csv.DictReader(f)
        rows = list(reader)
    assert set(CONTRACT) <= set(reader.fieldnames)
    assert len(rows) == 4 and {r["n_validation"] for r in rows} == {"300"}
    png = tmp_path / "r" / "collision_free.png"
    assert png.is_file() and str(png) in saved, "collision_free.png was not written by savefig"
    assert_readable(saved[str(png)], "collision_free.png")
    files = sorted((tmp_path / "r" / "scenes").glob("*.json"))
    mtimes = [f.stat().st_mtime_ns for f in files]
    rc, out = _run(argv, capsys)
    assert rc == 0 and "0 plans computed, 4 reused" in out.out
    assert [f.stat().st_mtime_ns for f in files] == mtimes
    # a different seed into the same folder is refused, naming the conflict
    i = argv.index("--seed") + 1
    code, err = _exit_code(argv[:i] + ["4"] + argv[i + 1 :], capsys)
    assert code == 2 and "different settings" in err


@pytest.mark.parametrize("first", ["--help", "-h"])
def test_qp_backends_takes_its_own_options_first(first, capsys):
    """``mmdopt bench qp-backends --help`` reaches the benchmark's parser (no ``--`` needed);
    an unknown option of another command is still exit 2 naming it."""
    with pytest.raises(SystemExit) as e:
        cli.main(["bench", "qp-backends", first])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "qp-backends" in out and "--backends" in out
    with pytest.raises(SystemExit) as e:
        cli.main(["bench", "timing", "--out", "x", "--bogus"])
    assert e.value.code == 2 and "--bogus" in capsys.readouterr().err


# ------------------------------------------------------------------ the parser without the method
#: modules the parser and ``--help`` / ``--version`` must not import: JAX and the method, the
#: figures, Ray, pandas, the progress bar, and the experiments
HEAVY = ("jax", "mmdopt.methods", "mmdopt.algorithm", "mmdopt.bench.frontier",
         "mmdopt.bench.synthetic", "mmdopt.bench.scenes", "mmdopt.bench.highway",
         "mmdopt.bench.ngsim", "matplotlib", "ray", "pandas", "tqdm")  # fmt: skip


def _python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)


def test_the_parser_and_its_help_import_neither_jax_nor_the_method():
    """``import mmdopt`` is lazy (PEP 562), so importing the CLI, building its parser and
    answering ``--help`` (of every level) and ``--version`` leave JAX, the method, matplotlib
    and Ray unimported: the first five minutes start at once."""
    code = f"""
import sys
from mmdopt.bench import cli
cli.build_parser()
for argv in (["--help"], ["--version"], ["bench", "--help"], ["demo", "--help"],
             ["bench", "frontier", "--help"], ["bench", "synthetic", "--help"]):
    try:
        cli.main(argv)
    except SystemExit as e:
        assert e.code == 0, (argv, e.code)
print("loaded:", sorted(m for m in {HEAVY!r} if m in sys.modules))
"""
    r = _python(code)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "loaded: []" in r.stdout, r.stdout[-2000:]


def test_the_package_imports_the_method_on_first_use():
    """``mmdopt.plan`` and ``from mmdopt import Road`` reach the method; ``import mmdopt``
    alone does not import JAX."""
    code = """
import sys
import mmdopt
assert "jax" not in sys.modules, "import mmdopt imported jax"
from mmdopt import Road
assert callable(mmdopt.plan) and mmdopt.algorithm.__name__ == "mmdopt.algorithm"
assert set(mmdopt.__all__) <= set(dir(mmdopt))
print("ok")
"""
    r = _python(code)
    assert r.returncode == 0 and "ok" in r.stdout, r.stderr[-3000:]


def test_the_help_literals_are_their_sources():
    """The names the parser lists without importing their modules are those modules' own."""
    import mmdopt.methods
    from mmdopt.algorithm import PLANNER_BACKEND
    from mmdopt.bench.frontier import DEFAULT_RISK_GRID
    from mmdopt.bench.scenes import PRESETS

    assert cli.PLAN_METHODS == tuple(mmdopt.methods.PLAN_METHODS)
    assert cli.DEFAULT_RISK_GRID == tuple(DEFAULT_RISK_GRID)
    assert cli.PRESETS == tuple(sorted(PRESETS))
    assert cli.PLANNER_BACKEND == PLANNER_BACKEND


def _help(parser, **names) -> str:
    return cli.command_parser(parser, argparse.Namespace(**names)).format_help()


def test_placeholder_commands_list_their_modules_help_and_build_when_chosen():
    """``bench highway``, ``bench ngsim`` and ``predictor`` are listed with their modules' help
    before they are built (the listings do not change when they are), and are the real parsers
    once chosen."""
    p = cli.build_parser()
    before = [_help(p), _help(p, command="bench")]
    cli.load_all_parsers(p)
    assert [_help(p), _help(p, command="bench")] == before
    assert "--episodes" in _help(p, command="bench", experiment="highway")
    assert "--scenarios" in _help(p, command="bench", experiment="ngsim")
    assert "--steps" in _help(p, command="predictor", predictor_command="train")
    args = cli.build_parser().parse_args(["bench", "highway", "--out", "x", "--seed", "4"])
    assert args.seed == 4 and callable(args.func)


@pytest.mark.parametrize(
    "argv, command, option",
    [
        (["bench", "frontier", "--out", "{out}", "--risks", "mmd=0.9"], "bench frontier",
         "--risks"),
        (["bench", "frontier", "--out", "{out}", "--scenes", "x"], "bench frontier", "--scenes"),
        (["bench", "synthetic", "--out", "{out}", "--config", "{cfg}"], "bench synthetic",
         "--config"),
        (["bench", "timing", "--out", "{out}", "--samples", "5", "--sizes", "10"],
         "bench timing", "--samples"),
        (["bench", "timing", "--out", "{out}", "--bogus"], "bench timing", "--bogus"),
        (["bench", "reduced-set", "--out", "/proc/mmdopt-no/x"], "bench reduced-set", "--out"),
        (["predictor", "eval", "--out", "/proc/mmdopt-no/x.json"], "predictor eval", "--out"),
    ],
)  # fmt: skip
def test_a_commands_error_prints_that_commands_usage(argv, command, option, tmp_path, capsys):
    cfg = tmp_path / "cfg.json"
    cfg.write_text('{"w_magic": 1}')
    argv = [a.format(out=tmp_path / "o", cfg=cfg) for a in argv]
    code, err = _exit_code(argv, capsys)
    assert code == 2 and option in err
    assert err.startswith(f"usage: mmdopt {command} "), err
    assert f"mmdopt {command}: error: " in err, err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("command", [["demo"], ["bench", "synthetic"], ["bench", "frontier"],
                                     ["bench", "reduced-set"], ["bench", "timing"],
                                     ["bench", "figure"]])  # fmt: skip
def test_backend_help_shows_its_default_and_the_installed_backends(command, capsys):
    import solvers

    with pytest.raises(SystemExit) as e:
        cli.main([*command, "--help"])
    assert e.value.code == 0
    text = " ".join(capsys.readouterr().out.split())  # the help's lines joined
    assert "--backend NAME projection QP backend (default: admm-fixed)" in text
    for name in solvers.available_backends():
        assert name in text


def test_config_help_shows_the_nested_form_and_the_example_reads(capsys):
    with pytest.raises(SystemExit):
        cli.main(["bench", "frontier", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert '{"cem": {"iterations": 10}}' in text and "baseline_margin_scale" not in text
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the flat form warns; the nested form does not
        assert cli.load_planner_config_from_dict({"cem": {"iterations": 10}}).cem.iterations == 10


def test_frontier_summary_says_its_counts_are_per_1000(tmp_path, capsys, monkeypatch):
    """The printed collision-free levels are per 1000 validation futures, and say so."""
    import mmdopt.bench.frontier as fr

    rows = [dict(method="mmd", risk=0.01, scene=s, collision_free=195, n_validation=200,
                 progress_m=90.0, plan_time_s=0.1, feasible=True, status="ok", risk_bound=0.01,
                 n_planning=40) for s in range(2)]  # fmt: skip
    res = dict(fr.summarise_frontier(rows, ["mmd"]), computed=2, reused=0, wall_s=1.0)
    monkeypatch.setattr(fr, "run_frontier", lambda *a, **k: res)
    monkeypatch.setattr(cli, "_checked_config", lambda *a: (None, None))
    rc, out = _run(["bench", "frontier", "--out", str(tmp_path / "o"), "--methods", "mmd"],
                   capsys)  # fmt: skip
    assert rc == 0
    assert "collision-free per 1000: mean" in out.out and "975.0" in out.out
    assert "of 1000" not in out.out
    assert "matched compute" in out.out  # the --budgets readout


@pytest.mark.slow
def test_frontier_measures_the_compile_apart_and_reads_older_folders(tmp_path, capsys):
    """``compile_s`` is the last column of ``frontier.csv`` (the contract columns first): the
    first task of the worker has the compile apart (>= 0), a later task 0.0; a folder whose
    rows predate the column resumes with NaN there and loads (``load_results``)."""
    from mmdopt.bench.frontier import FRONTIER_COLUMNS
    from mmdopt.bench.results import load_results
    from tests.mmdopt.bench.test_frontier import CONTRACT as FRONTIER_CONTRACT
    from tests.mmdopt.bench.test_frontier import TINY

    assert FRONTIER_COLUMNS[: len(FRONTIER_CONTRACT)] == FRONTIER_CONTRACT
    assert FRONTIER_COLUMNS[-1] == "compile_s"
    small, tiny = tmp_path / "scene.json", tmp_path / "cfg.json"
    small.write_text(json.dumps({"n_validation": 200, "n_samples": 40}))
    tiny.write_text(json.dumps(TINY))  # test_frontier's planner: its programs are compiled once
    out = tmp_path / "f"
    argv = ["bench", "frontier", "--scenes", "2", "--seed", "3", "--out", str(out),
            "--methods", "mmd", "--risks", "0.1", "--jobs", "1", "--n-samples", "40",
            "--scene-params", str(small), "--config", str(tiny), "--no-progress"]  # fmt: skip
    rc, _ = _run(argv, capsys)
    assert rc == 0
    with open(out / "frontier.csv") as f:
        reader = csv.DictReader(f)
        rows = sorted(reader, key=lambda r: int(r["scene"]))
    assert reader.fieldnames[: len(FRONTIER_COLUMNS)] == list(FRONTIER_COLUMNS)
    assert float(rows[0]["compile_s"]) >= 0.0 and float(rows[1]["compile_s"]) == 0.0
    assert all(float(r["plan_time_s"]) > 0 for r in rows)
    # rows written before the column existed
    for task in (out / "tasks").glob("*.json"):
        row = json.loads(task.read_text())
        del row["compile_s"]
        task.write_text(json.dumps(row))
    (out / "frontier.csv").unlink()
    rc, text = _run(argv, capsys)
    assert rc == 0 and "0 plans computed, 2 reused" in text.out
    df = load_results(out, "frontier")
    assert list(df.columns[: len(FRONTIER_COLUMNS)]) == list(FRONTIER_COLUMNS)
    assert df["compile_s"].isna().all() and len(df) == 2


def test_the_cli_keeps_compiled_programs_in_a_user_cache_unless_told_not_to(tmp_path, monkeypatch):
    """``mmdopt`` turns on JAX's persistent compilation cache in the user cache folder
    (``$XDG_CACHE_HOME/mmdopt/jax``); ``MMDOPT_COMPILE_CACHE`` moves it or (``0``) turns it
    off, as ``--no-compile-cache`` does; a ``JAX_COMPILATION_CACHE_DIR`` already set is kept."""
    import argparse

    assert cli.compile_cache_dir({"XDG_CACHE_HOME": str(tmp_path)}) == tmp_path / "mmdopt" / "jax"
    assert cli.compile_cache_dir({"MMDOPT_COMPILE_CACHE": "0"}) is None
    assert cli.compile_cache_dir({"MMDOPT_COMPILE_CACHE": str(tmp_path / "c")}) == tmp_path / "c"
    assert cli.enable_compile_cache(argparse.Namespace(no_compile_cache=True)) is None
    kept = tmp_path / "kept"
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(kept))
    assert cli.enable_compile_cache(argparse.Namespace(no_compile_cache=False)) == kept
    assert cli.build_parser().parse_args(["--no-compile-cache", "demo"]).no_compile_cache
