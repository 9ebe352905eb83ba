"""Bad-input corpus for the inputs of the ``mmdopt`` commands that are files, folders or names
rather than one number: CommonRoad scenario files (``bench ngsim --scenarios``, ``predictor
--data``), the ngsim ``--config`` and its ``bench`` section, ``--out`` where nothing can be
written, ``--env`` of ``bench highway`` and ``--address``.  Each is exit status 2 with
``error: argument --OPTION: <reason>``, no traceback, and nothing written into ``--out``."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

from .test_cli_corpus import run_main

TINY = {
    "cem": {"n_samples": 60, "n_cem": 30, "n_elite": 10, "iterations": 3, "n_brake": 2},
    "selection": {"reduced_set_size": 5},
}


def expect_error(argv, capsys, *named):
    rc, err = run_main(argv, capsys)
    assert rc == 2, err
    assert "error: argument" in err, err
    for n in named:
        assert n in err, f"{n!r} not named in {err!r}"
    return err


def commonroad_xml(xs=(10.0, 250.0), steps=80, dt=0.1, speed=10.0) -> str:
    """A minimal valid CommonRoad 2020a scenario: one straight 1 km lanelet and a car at each
    start position ``xs`` driving along it for ``steps`` steps."""

    def pt(x, y):
        return f"<point><x>{x}</x><y>{y}</y></point>"

    def state(tag, k, x):
        return (
            f"<{tag}><position>{pt(x, 0.0)}</position><orientation><exact>0.0</exact>"
            f"</orientation><time><exact>{k}</exact></time><velocity><exact>{speed}</exact>"
            f"</velocity><acceleration><exact>0.0</exact></acceleration></{tag}>"
        )

    cars = []
    for i, x0 in enumerate(xs):
        traj = "".join(state("state", k, x0 + speed * dt * k) for k in range(1, steps + 1))
        cars.append(
            f'<dynamicObstacle id="{100 + i}"><type>car</type><shape><rectangle>'
            "<length>4.5</length><width>1.8</width></rectangle></shape>"
            f"{state('initialState', 0, x0)}<trajectory>{traj}</trajectory></dynamicObstacle>"
        )
    return (
        "<?xml version='1.0' encoding='UTF-8'?>\n"
        f'<commonRoad timeStepSize="{dt}" commonRoadVersion="2020a" author="t" affiliation="t" '
        'source="t" benchmarkID="ZAM_Test-1_1_T-1" date="2020-01-01">'
        "<location><geoNameId>-999</geoNameId><gpsLatitude>999</gpsLatitude>"
        "<gpsLongitude>999</gpsLongitude></location><scenarioTags><Highway/></scenarioTags>"
        f'<lanelet id="1"><leftBound>{pt(0, 2)}{pt(1000, 2)}</leftBound>'
        f"<rightBound>{pt(0, -2)}{pt(1000, -2)}</rightBound></lanelet>"
        + "".join(cars)
        + "</commonRoad>"
    )


GOOD = commonroad_xml()
#: (name, file name, content or a folder builder, words of the reason)
SCENARIOS = [
    ("truncated", "s.xml", GOOD[: len(GOOD) // 2], "not well-formed XML"),
    ("empty file", "s.xml", "", "empty"),
    ("not XML", "s.xml", "lanelet 1, obstacle 2\n", "not well-formed XML"),
    ("binary", "s.xml", b"\x00\xff\xfe\x00", "not well-formed XML"),
    ("other root", "s.xml", "<osm><lanelet/><dynamicObstacle/></osm>", "not a CommonRoad"),
    ("no lanelets", "s.xml", "<commonRoad><dynamicObstacle/></commonRoad>", "no lanelets"),
    ("no vehicles", "s.xml", "<commonRoad><lanelet/></commonRoad>", "no dynamic obstacles"),
    ("not .xml", "s.json", "{}", "not an .xml file"),
    ("empty folder", None, [], "it is empty"),
    ("folder without XML", None, [("a.txt", "x"), ("b.json", "{}")], "no .xml files"),
]
_needs_commonroad = pytest.mark.skipif(
    importlib.util.find_spec("commonroad") is None,
    reason="reading CommonRoad scenes needs commonroad-io (pip install 'mmdopt[commonroad]')",
)


def _scenario_path(tmp_path: Path, fname, content) -> Path:
    if fname is None:
        d = tmp_path / "scenes"
        d.mkdir()
        for n, text in content:
            (d / n).write_text(text)
        return d
    f = tmp_path / fname
    if isinstance(content, bytes):
        f.write_bytes(content)
    else:
        f.write_text(content)
    return f


@pytest.mark.parametrize("name,fname,content,reason", SCENARIOS, ids=[c[0] for c in SCENARIOS])
def test_bad_scenario_is_exit_2_naming_it_and_writes_nothing(
    name, fname, content, reason, tmp_path, capsys
):
    path = _scenario_path(tmp_path, fname, content)
    out = tmp_path / "out"
    argv = ["bench", "ngsim", "--scenarios", path, "--out", out, "--predictor", "cv"]
    err = expect_error(argv, capsys, "--scenarios", reason)
    assert str(path) in err
    assert not out.exists()  # nothing written, not even OUT/tasks


@_needs_commonroad
def test_scenes_without_a_task_say_why_and_write_nothing(tmp_path, capsys):
    """Two cars 240 m apart: a valid scenario, but no ego has a vehicle within range."""
    f = tmp_path / "far.xml"
    f.write_text(commonroad_xml(xs=(10.0, 250.0)))
    out = tmp_path / "out"
    argv = ["bench", "ngsim", "--scenarios", f, "--out", out, "--predictor", "cv"]
    err = expect_error(argv, capsys, "--scenarios", "no task selected", "range_m", "far.xml")
    assert "with a vehicle within range: 0" in err
    assert not out.exists()
    # too short for a single planning time: said so
    short = tmp_path / "short.xml"
    short.write_text(commonroad_xml(xs=(10.0, 30.0), steps=30))
    err = expect_error(argv[:3] + [short] + argv[4:], capsys, "--scenarios", "too short")
    assert not out.exists()


def test_without_commonroad_a_good_file_names_the_extra(tmp_path, capsys, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "commonroad.common.file_reader", None)  # not installed
    f = tmp_path / "s.xml"
    f.write_text(GOOD)
    out = tmp_path / "out"
    rc, err = run_main(
        ["bench", "ngsim", "--scenarios", f, "--out", out, "--predictor", "cv"], capsys
    )
    assert rc == 2 and "mmdopt[commonroad]" in err
    assert not out.exists()


def test_scenario_files_name_the_bad_path(tmp_path):
    from mmdopt.bench.ngsim.inputs import ScenarioError
    from mmdopt.bench.ngsim.scene import scenario_files

    (tmp_path / "empty").mkdir()
    with pytest.raises(ScenarioError, match="no .xml files .it is empty"):
        scenario_files([tmp_path / "empty"])
    with pytest.raises(ScenarioError, match="does not exist"):
        scenario_files([tmp_path / "nothing.xml"])
    assert issubclass(ScenarioError, ValueError)


# ------------------------------------------------------------------------- bench ngsim --config
NGSIM_CONFIGS = [
    ("unknown key", {"w_magic": 1}, "w_magic"),
    ("unknown nested key", {"cem": {"n_sample": 5}}, "n_sample"),
    ("bad planner value", {"trajectory": {"horizon": -1}}, "horizon"),
    ("bench not an object", {"bench": 3}, "bench"),
    ("bench unknown key", {"bench": {"egos": 3}}, "egos"),
    ("bench str for int", {"bench": {"history": "10"}}, "history"),
    ("bench float for int", {"bench": {"n_samples": 2.5}}, "n_samples"),
    ("bench every 0", {"bench": {"every": 0}}, "every"),
    ("bench range NaN", {"bench": {"range_m": float("nan")}}, "range_m"),
    ("bench flow without v_des", {"bench": {"v_des": None}}, "v_des"),
    ("list", [1, 2], "JSON object"),
]


@pytest.mark.parametrize("name,raw,key", NGSIM_CONFIGS, ids=[c[0] for c in NGSIM_CONFIGS])
def test_bad_ngsim_config_is_exit_2_naming_the_key(name, raw, key, tmp_path, capsys):
    cfg = tmp_path / "cfg.json"
    cfg.write_text(json.dumps(raw))
    scen = tmp_path / "s.xml"
    scen.write_text(GOOD)
    out = tmp_path / "out"
    argv = ["bench", "ngsim", "--scenarios", scen, "--out", out, "--config", cfg]
    expect_error(argv, capsys, "--config", key)
    assert not out.exists()


@pytest.mark.parametrize("text,reason", [("{", "not valid JSON"), (b"\xff\xfe", "cannot be read")])
def test_unreadable_ngsim_config(text, reason, tmp_path, capsys):
    cfg = tmp_path / "cfg.json"
    cfg.write_bytes(text if isinstance(text, bytes) else text.encode())
    scen = tmp_path / "s.xml"
    scen.write_text(GOOD)
    argv = ["bench", "ngsim", "--scenarios", scen, "--out", tmp_path / "o", "--config", cfg]
    expect_error(argv, capsys, "--config", reason)


def test_ngsim_config_reads_planner_fields_and_bench():
    from mmdopt.bench.ngsim.inputs import load_ngsim_config

    cfg, params = load_ngsim_config(
        {"cem": {"iterations": 4}, "safety": {"risk": 0.01}, "bench": {"history": 8}}
    )
    assert cfg.cem.iterations == 4 and cfg.safety.risk == 0.01 and params.history == 8
    assert cfg.trajectory.horizon == 5.0  # over the benchmark's preset, not the paper's


# ---------------------------------------------------------------------------- frontier --config
@pytest.mark.parametrize(
    "raw,key",
    [
        ({"trajectory": {"horizon": -1}}, "horizon"),
        ({"trajectory": {"num_steps": 50}}, "num_steps"),
        ({"x": 1}, "x"),
    ],
    ids=["horizon", "num_steps", "unknown"],
)
def test_frontier_config_errors_name_the_option(raw, key, tmp_path, capsys):
    cfg = tmp_path / "cfg.json"
    cfg.write_text(json.dumps(raw))
    out = tmp_path / "out"
    argv = ["bench", "frontier", "--scenes", "1", "--out", out, "--config", cfg, "--no-progress"]
    expect_error(argv, capsys, "--config", key)
    assert not out.exists()


# ------------------------------------------------------------------------------------- --out
def _unwritable(tmp_path: Path) -> list[Path]:
    f = tmp_path / "a_file"
    f.write_text("x")
    outs = [f / "sub", f / "deeper" / "sub"]
    if Path("/proc/self").exists():  # a folder nobody (not even root) can create entries in
        outs.append(Path("/proc/mmdopt_out"))
    return outs


@pytest.mark.parametrize(
    "argv",
    [
        ["bench", "frontier", "--scenes", "1", "--no-progress"],
        ["bench", "synthetic", "--scenes", "1", "--no-progress"],
        ["bench", "ngsim", "--scenarios", "{scen}"],
        ["bench", "highway", "--episodes", "1"],
        ["bench", "timing"],
        ["demo"],
    ],
    ids=["frontier", "synthetic", "ngsim", "highway", "timing", "demo"],
)
def test_unwritable_out_is_exit_2_up_front(argv, tmp_path, capsys):
    scen = tmp_path / "s.xml"
    scen.write_text(GOOD)
    for out in _unwritable(tmp_path):
        a = [str(scen) if x == "{scen}" else x for x in argv]
        expect_error([*a, "--out", out], capsys, "--out", str(out))


def test_predictor_out_is_checked_before_training(tmp_path, capsys):
    import time

    for out in _unwritable(tmp_path):
        t = time.perf_counter()
        expect_error(["predictor", "train", "--out", out / "w"], capsys, "--out")
        assert time.perf_counter() - t < 30  # refused at once, not after the training
        expect_error(["predictor", "eval", "--out", out / "t.json"], capsys, "--out")
    # an existing JSON file is overwritten by eval (not "exists and is not a folder")
    (tmp_path / "t.json").write_text("[]")
    from mmdopt.bench.inputs import check_out_file

    check_out_file(tmp_path / "t.json")
    with pytest.raises(ValueError, match="folder"):
        check_out_file(tmp_path)


def test_out_checks_leave_nothing_behind(tmp_path):
    from mmdopt.bench.inputs import check_out_folder

    check_out_folder(tmp_path / "a" / "b")
    check_out_folder(tmp_path)
    assert sorted(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------- predictor --data
@pytest.mark.parametrize(
    "make,reason",
    [
        (lambda d: None, "it is empty"),
        (lambda d: (d / "notes.txt").write_text("x"), "no .xml files"),
        (lambda d: (d / "USA_US101-1_1_T-1.xml").write_text(GOOD[:500]), "not well-formed XML"),
        (lambda d: (d / "USA_US101-1_1_T-1.xml").write_text(""), "empty"),
        (lambda d: (d / "scene.xml").write_text(GOOD), "USA_US101-N_K_T-1"),
        (lambda d: (d / "USA_US101-5_1_T-1.xml").write_text(GOOD), "no train recordings"),
    ],
    ids=["empty", "no-xml", "truncated", "empty-file", "other-name", "held-out-only"],
)
def test_bad_predictor_data_is_exit_2_naming_it(make, reason, tmp_path, capsys):
    d = tmp_path / "data"
    d.mkdir()
    make(d)
    out = tmp_path / "w" / "model"
    expect_error(["predictor", "train", "--data", d, "--out", out], capsys, "--data", reason)
    assert not out.parent.exists()


@_needs_commonroad
def test_predictor_data_without_windows_is_exit_2(tmp_path, capsys):
    pytest.importorskip("equinox", reason="training needs the learn extra")
    d = tmp_path / "data"
    d.mkdir()
    # 3 s recorded: shorter than a window's history + 5 s horizon
    (d / "USA_US101-1_1_T-1.xml").write_text(commonroad_xml(xs=(10.0, 30.0), steps=30))
    out = tmp_path / "w" / "model"
    argv = ["predictor", "train", "--data", d, "--out", out, "--steps", "1"]
    expect_error(argv, capsys, "--data", "no usable training windows")
    assert not out.parent.exists()


# ------------------------------------------------------------------------- --env and --address
def test_unknown_highway_env_is_exit_2_before_anything_is_written(tmp_path, capsys):
    from mmdopt.bench.highway.settings import highway_available

    if not highway_available():
        pytest.skip("highway-env is not installed")
    out = tmp_path / "out"
    argv = ["bench", "highway", "--env", "nosuch-v9", "--out", out, "--episodes", "1"]
    expect_error(argv, capsys, "--env", "nosuch-v9", "highway-v0")
    assert not out.exists()  # no run.json that would refuse the corrected command


def test_unknown_env_config_key_is_exit_2_before_anything_is_written(tmp_path, capsys):
    from mmdopt.bench.highway.settings import highway_available

    if not highway_available():
        pytest.skip("highway-env is not installed")
    out, cfg = tmp_path / "out", tmp_path / "env.json"
    cfg.write_text(json.dumps({"vehicles_density": 2, "vehicle_density": 2}))
    argv = ["bench", "highway", "--env-config", cfg, "--out", out, "--episodes", "1"]
    # the misspelt key is named, with the env's own keys to choose from
    expect_error(argv, capsys, "--env-config", "'vehicle_density'", "vehicles_density")
    assert not out.exists()
    cfg.write_text(json.dumps({"duration": 3}))  # set by --duration, not by the env's config
    expect_error(argv, capsys, "--env-config", "duration", "--duration")
    cfg.write_text("[2]")
    expect_error(argv, capsys, "--env-config", "JSON object")
    assert not out.exists()


@pytest.mark.parametrize(
    "argv",
    [
        ["bench", "synthetic", "--scenes", "1"],
        ["bench", "frontier", "--scenes", "1"],
        ["bench", "reduced-set", "--scenes", "1"],
        ["bench", "ngsim", "--scenarios", "{scen}"],
        ["bench", "highway"],
    ],
    ids=["synthetic", "frontier", "reduced-set", "ngsim", "highway"],
)
def test_address_without_ray_executor_is_refused(argv, tmp_path, capsys):
    scen = tmp_path / "s.xml"
    scen.write_text(GOOD)
    out = tmp_path / "out"
    a = [str(scen) if x == "{scen}" else x for x in argv]
    expect_error([*a, "--out", out, "--address", "auto"], capsys, "--address", "--executor ray")
    assert not out.exists()


def test_ray_client_address_without_the_client_names_the_extra(tmp_path, capsys):
    if importlib.util.find_spec("grpc") is not None:
        pytest.skip("Ray's client is installed")
    argv = ["bench", "synthetic", "--out", tmp_path / "o", "--executor", "ray"]
    expect_error([*argv, "--address", "ray://head:10001"], capsys, "--address", "ray[client]")


@pytest.mark.parametrize("address", ["bogus", "head:", ":6379", "head:99999", "head:port",
                                     "http://head:8265", "ray://head", "ray://"])  # fmt: skip
def test_malformed_address_is_exit_2_at_once_with_the_commands_usage(address, tmp_path, capsys):
    """A malformed ``--address`` (Ray retries one for half a minute) is refused when the
    command line is parsed, with the usage of the command, before anything is written."""
    out = tmp_path / "out"
    argv = ["bench", "frontier", "--executor", "ray", "--address", address, "--out", out]
    err = expect_error(argv, capsys, "--address", "auto, ray://HOST:PORT or HOST:PORT")
    assert err.startswith("usage: mmdopt bench frontier ")
    assert not out.exists()


@pytest.mark.parametrize("address", ["auto", "127.0.0.1:6379", "ray://head:10001", "[::1]:6379"])
def test_address_forms(address):
    from mmdopt.bench.executors import parse_ray_address

    assert parse_ray_address(address) in (None, ("127.0.0.1", 6379), ("head", 10001),
                                          ("::1", 6379))  # fmt: skip


def _closed_port() -> int:
    """A local TCP port where nothing listens (bound, then released)."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_address_where_no_cluster_answers_is_exit_2_before_anything_is_written(tmp_path, capsys):
    out = tmp_path / "out"
    address = f"127.0.0.1:{_closed_port()}"
    argv = ["bench", "frontier", "--executor", "ray", "--address", address, "--out", out]
    expect_error(argv, capsys, "--address", address, "no Ray cluster answers")
    assert not out.exists()


def test_executor_names_the_address_when_ray_cannot_connect(monkeypatch):
    """``run_tasks`` on an unreachable cluster, and a ``ConnectionError`` of ``ray.init``, are a
    ``ValueError`` naming ``--address`` (the CLI's exit 2), not Ray's traceback."""
    ray = pytest.importorskip("ray")
    from mmdopt.bench.executors import run_tasks

    address = f"127.0.0.1:{_closed_port()}"
    with pytest.raises(ValueError, match=f"--address.*{address}"):
        run_tasks(abs, [-1], executor="ray", address=address, progress=False)

    def refuse(**kw):
        raise ConnectionError("Could not find any running Ray instance.")

    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "init", refuse)
    with pytest.raises(ValueError, match="--address 'auto'.*any running Ray instance"):
        run_tasks(abs, [-1], executor="ray", address="auto", progress=False)
