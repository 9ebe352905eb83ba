"""Bad-input corpus for the ``mmdopt`` command line: every bad option or file exits
with status 2, one ``error: argument --OPTION: …`` message naming the option (and the key of a
bad ``--config``), no traceback, and nothing written into ``--out`` (no ``run.json`` that would
lock the folder)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from mmdopt.bench import cli
from mmdopt.bench.executors import check_manifest
from mmdopt.bench.scenes import SceneParams
from mmdopt.bench.synthetic import manifest_aliases, sweep_manifest

REPO = Path(__file__).resolve().parents[2]


def run_main(argv, capsys):
    try:
        rc = cli.main([str(a) for a in argv])
    except SystemExit as e:
        rc = e.code
    cap = capsys.readouterr()
    assert "Traceback" not in cap.err and "Traceback" not in cap.out
    return rc, cap.err


def expect_error(argv, capsys, *named):
    rc, err = run_main(argv, capsys)
    assert rc == 2, err
    for n in named:
        assert n in err, f"{n!r} not named in {err!r}"
    return err


# ------------------------------------------------------------------------------------ --config
CONFIGS = [
    ("nested str int", '{"reduced_set": {"population": "20"}}', "reduced_set.population"),
    ("nested float for int", '{"reduced_set": {"iterations": 2.5}}', "reduced_set.iterations"),
    ("nested bool for int", '{"reduced_set": {"n_elite": true}}', "reduced_set.n_elite"),
    ("nested str float", '{"reduced_set": {"beta": "0.1"}}', "reduced_set.beta"),
    ("nested optional str", '{"reduced_set": {"bandwidth": "x"}}', "reduced_set.bandwidth"),
    ("nested optional bool", '{"reduced_set": {"alpha_scale": true}}', "reduced_set.alpha_scale"),
    ("nested weights int", '{"reduced_set": {"weights": 3}}', "reduced_set.weights"),
    ("nested weights mode", '{"reduced_set": {"weights": "softmax"}}', "weights"),
    ("nested unknown", '{"reduced_set": {"foo": 1}}', "reduced_set.foo"),
    ("nested NaN", '{"reduced_set": {"beta": NaN}}', "reduced_set.beta"),
    ("nested Infinity", '{"reduced_set": {"sigma0": Infinity}}', "reduced_set.sigma0"),
    ("nested elite >= population", '{"reduced_set": {"n_elite": 200}}', "n_elite"),
    ("nested negative ridge", '{"reduced_set": {"ridge": -1}}', "ridge"),
    ("nested not object", '{"reduced_set": 3}', "reduced_set"),
    ("admm_rho str", '{"admm_rho": "abc"}', "admm_rho"),
    ("admm_rho negative", '{"admm_rho": -1}', "admm_rho"),
    ("admm_rho NaN", '{"admm_rho": NaN}', "admm_rho"),
    ("w_mmd NaN", '{"w_mmd": NaN}', "w_mmd"),
    ("w_mmd Infinity", '{"w_mmd": Infinity}', "w_mmd"),
    ("v_des -Infinity", '{"v_des": -Infinity}', "v_des"),
    ("bandwidth null", '{"bandwidth": null}', "bandwidth"),
    ("bandwidth str", '{"bandwidth": "wide"}', "bandwidth"),
    ("gamma 0", '{"gamma": 0}', "gamma"),
    ("n_samples float", '{"n_samples": 1.5}', "n_samples"),
    ("n_samples str", '{"n_samples": "100"}', "n_samples"),
    ("n_samples bool", '{"n_samples": true}', "n_samples"),
    ("n_elite 1", '{"n_elite": 1}', "n_elite"),
    ("dtype int", '{"dtype": 32}', "dtype"),
    ("dtype float16", '{"dtype": "float16"}', "dtype"),
    ("constraint_points", '{"constraint_points": "edges"}', "constraint_points"),
    ("unknown key", '{"w_magic": 1}', "w_magic"),
    ("list", "[1, 2]", "JSON object"),
    ("string", '"w_mmd"', "JSON object"),
    ("truncated", '{"w_mmd": ', "not valid JSON"),
    ("empty", "", "not valid JSON"),
    ("not utf-8", b"\xff\xfe\x00", "cannot be read"),
    # found when the planning problem is built, before run.json is written
    ("reduced_set_size > samples", '{"reduced_set_size": 500}', "reduced_set_size"),
    ("num_steps mismatch", '{"num_steps": 50}', "num_steps"),
    ("horizon 0", '{"horizon": 0}', "horizon"),
]


@pytest.mark.parametrize("name,text,key", CONFIGS, ids=[c[0] for c in CONFIGS])
def test_bad_config_is_exit_2_naming_the_key_and_locks_nothing(name, text, key, tmp_path, capsys):
    cfg = tmp_path / "cfg.json"
    if isinstance(text, bytes):
        cfg.write_bytes(text)
    else:
        cfg.write_text(text)
    out = tmp_path / "out"
    expect_error(
        ["bench", "synthetic", "--scenes", "1", "--out", out, "--config", cfg, "--no-progress"],
        capsys,
        "--config",
        key,
    )
    assert not (out / "run.json").exists()


def test_bad_config_for_reduced_set_benchmark(tmp_path, capsys):
    cfg = tmp_path / "cfg.json"
    cfg.write_text('{"reduced_set": {"population": "20"}}')
    out = tmp_path / "out"
    expect_error(
        ["bench", "reduced-set", "--scenes", "1", "--out", out, "--config", cfg],
        capsys,
        "--config",
        "reduced_set.population",
    )
    assert not (out / "run_reduced_set.json").exists()


# ----------------------------------------------------------------------------------- options
def _file(tmp_path):
    f = tmp_path / "a_file"
    f.write_text("x")
    return f


OPTIONS = [
    ("out is a file", lambda t: ["bench", "synthetic", "--out", _file(t)], "--out"),
    ("out under a file", lambda t: ["bench", "synthetic", "--out", _file(t) / "sub"], "--out"),
    ("reduced-set out file", lambda t: ["bench", "reduced-set", "--out", _file(t)], "--out"),
    ("timing out file", lambda t: ["bench", "timing", "--out", _file(t)], "--out"),
    ("figure out file", lambda t: ["bench", "figure", "--out", _file(t)], "--out"),
    ("demo out file", lambda t: ["demo", "--out", _file(t)], "--out"),
    ("out missing", lambda t: ["bench", "synthetic"], "--out"),
    ("jobs 0", lambda t: ["bench", "synthetic", "--out", t, "--jobs", "0"], "--jobs"),
    ("jobs x", lambda t: ["bench", "synthetic", "--out", t, "--jobs", "x"], "--jobs"),
    ("jobs 1.5", lambda t: ["bench", "synthetic", "--out", t, "--jobs", "1.5"], "--jobs"),
    ("scenes 0", lambda t: ["bench", "synthetic", "--out", t, "--scenes", "0"], "--scenes"),
    ("scenes -3", lambda t: ["bench", "synthetic", "--out", t, "--scenes", "-3"], "--scenes"),
    ("seed -1", lambda t: ["bench", "synthetic", "--out", t, "--seed", "-1"], "--seed"),
    ("seed x", lambda t: ["bench", "synthetic", "--out", t, "--seed", "x"], "--seed"),
    (
        "methods unknown",
        lambda t: ["bench", "synthetic", "--out", t, "--methods", "mpc"],
        "--methods",
    ),
    ("methods empty", lambda t: ["bench", "synthetic", "--out", t, "--methods", ","], "--methods"),
    (
        "backend unknown",
        lambda t: ["bench", "synthetic", "--out", t, "--backend", "gurobi"],
        "--backend",
    ),
    (
        "executor unknown",
        lambda t: ["bench", "synthetic", "--out", t, "--executor", "dask"],
        "--executor",
    ),
    (
        "preset unknown",
        lambda t: ["bench", "synthetic", "--out", t, "--preset", "paper7"],
        "--preset",
    ),
    (
        "scene-params missing",
        lambda t: ["bench", "synthetic", "--out", t, "--scene-params", t / "no.json"],
        "--scene-params",
    ),
    (
        "config missing",
        lambda t: ["bench", "synthetic", "--out", t, "--config", t / "no.json"],
        "--config",
    ),
    (
        "random-sets 0",
        lambda t: ["bench", "reduced-set", "--out", t, "--random-sets", "0"],
        "--random-sets",
    ),
    (
        "rs methods unknown",
        lambda t: ["bench", "reduced-set", "--out", t, "--methods", "kmeans"],
        "--methods",
    ),
    (
        "timing samples below sizes",
        lambda t: ["bench", "timing", "--out", t, "--sizes", "10,20", "--samples", "5,50"],
        "--samples",
    ),
    (
        "timing sizes above 100",
        lambda t: ["bench", "timing", "--out", t, "--sizes", "10,200"],
        "--sizes",
    ),
    ("timing sizes 0", lambda t: ["bench", "timing", "--out", t, "--sizes", "0,10"], "--sizes"),
    ("timing sizes x", lambda t: ["bench", "timing", "--out", t, "--sizes", "a"], "--sizes"),
    ("timing repeats 0", lambda t: ["bench", "timing", "--out", t, "--repeats", "0"], "--repeats"),
    (
        "figure scene outside",
        lambda t: ["bench", "figure", "--out", t, "--scene", "100000", "--preset", "reference36"],
        "--scene",
    ),
    ("figure scene -1", lambda t: ["bench", "figure", "--out", t, "--scene", "-1"], "--scene"),
    ("demo methods unknown", lambda t: ["demo", "--out", t, "--methods", "x"], "--methods"),
    ("demo backend unknown", lambda t: ["demo", "--out", t, "--backend", "x"], "--backend"),
    ("no command", lambda t: [], "{demo,bench,predictor}"),
    ("bench no experiment", lambda t: ["bench"], "{synthetic,frontier,reduced-set"),
]


@pytest.mark.parametrize("name,argv,option", OPTIONS, ids=[c[0] for c in OPTIONS])
def test_bad_option_is_exit_2_naming_it(name, argv, option, tmp_path, capsys):
    expect_error(argv(tmp_path), capsys, option)


def test_scene_params_nan_is_refused(tmp_path, capsys):
    sp = tmp_path / "sp.json"
    sp.write_text('{"obstacle_speed": NaN}')
    expect_error(
        ["bench", "synthetic", "--out", tmp_path / "o", "--scene-params", sp],
        capsys,
        "--scene-params",
    )


# --------------------------------------------------------------------------- the sweep folder
RUN_JSON = [
    ("empty", ""),
    ("truncated", '{"seed": 0, "par'),
    ("list", "[]"),
    ("string", '"run"'),
    ("binary", b"\x00\xff\xfe"),
]


@pytest.mark.parametrize("name,text", RUN_JSON, ids=[c[0] for c in RUN_JSON])
def test_corrupt_run_json_is_exit_2_naming_the_file(name, text, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    run = out / "run.json"
    run.write_bytes(text if isinstance(text, bytes) else text.encode())
    err = expect_error(["bench", "synthetic", "--scenes", "1", "--out", out], capsys)
    assert str(run) in err and "corrupt" in err
    assert run.read_bytes() == (text if isinstance(text, bytes) else text.encode())  # untouched


def test_folder_of_other_settings_is_refused_naming_them(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    man = sweep_manifest(5, SceneParams(), "admm-fixed", None, "workers")
    (out / "run.json").write_text(json.dumps(man))
    err = expect_error(["bench", "synthetic", "--scenes", "1", "--out", out], capsys)
    assert "seed" in err and "different settings" in err


def test_empty_config_equals_no_config_in_the_manifest(tmp_path):
    params = SceneParams()
    none = sweep_manifest(0, params, "admm-fixed", None, "workers")
    empty = sweep_manifest(
        0, params, "admm-fixed", cli.load_planner_config_from_dict({}), "workers"
    )
    assert none == empty
    # a folder made without --config accepts --config {} and vice versa
    check_manifest(tmp_path, none)
    check_manifest(tmp_path, empty, aliases=manifest_aliases(None))
    # a folder written before the manifest had a workers key is accepted...
    old = dict(none)
    old.pop("workers")
    (tmp_path / "run.json").write_text(json.dumps(old))
    check_manifest(tmp_path, empty, aliases=manifest_aliases(None))
    # ...but not one that recorded the default config as {}: that default was the time-linear
    # margins, no longer the default
    (tmp_path / "run.json").write_text(json.dumps(dict(old, config={})))
    with pytest.raises(ValueError, match="config"):
        check_manifest(tmp_path, empty, aliases=manifest_aliases(None))
    # a different config is still refused
    with pytest.raises(ValueError, match="config"):
        other = cli.load_planner_config_from_dict({"w_mmd": 5.0})
        check_manifest(
            tmp_path,
            sweep_manifest(0, params, "admm-fixed", other, "workers"),
            aliases=manifest_aliases(other),
        )


def test_mixing_in_process_and_worker_results_is_refused(tmp_path):
    params = SceneParams()
    check_manifest(tmp_path, sweep_manifest(0, params, "admm-fixed", None, "in-process"))
    with pytest.raises(ValueError, match="workers"):
        check_manifest(tmp_path, sweep_manifest(0, params, "admm-fixed", None, "workers"))


# --------------------------------------------------------------------- as a user runs it
@pytest.mark.parametrize(
    "argv,option",
    [
        (["bench", "synthetic", "--out", "{file}"], "--out"),
        (["bench", "synthetic", "--out", "{dir}", "--config", "{nan_cfg}"], "w_mmd"),
    ],
    ids=["out-file", "config-nan"],
)
def test_module_entry_point_exit_2_without_traceback(argv, option, tmp_path):
    f = _file(tmp_path)
    nan_cfg = tmp_path / "cfg.json"
    nan_cfg.write_text('{"w_mmd": NaN}')
    args = [a.format(file=f, dir=tmp_path / "o", nan_cfg=nan_cfg) for a in argv]
    env = dict(os.environ, PYTHONPATH=str(REPO))
    r = subprocess.run(
        [sys.executable, "-m", "mmdopt", *args],
        capture_output=True,
        text=True,
        cwd=REPO,
        env=env,
        timeout=300,
    )
    assert r.returncode == 2, r.stderr
    assert option in r.stderr and "Traceback" not in r.stderr
    # the command's usage (its lines), then one line "mmdopt bench synthetic: error: …"
    lines = r.stderr.strip().splitlines()
    assert lines[0].startswith("usage: mmdopt bench synthetic "), r.stderr
    assert [x for x in lines if "error:" in x] == [lines[-1]], r.stderr
    assert lines[-1].startswith("mmdopt bench synthetic: error: argument "), r.stderr
