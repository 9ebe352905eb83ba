"""Bad-input corpus: every public entry point of ``frenet`` and ``mmdopt`` fed wrong
shapes, NaN/inf, wrong types and out-of-range values.  Each case asserts the exact outcome: the
error type and the argument its message names (or, for planning, the plan's status).

The planner cases share one tiny compiled config (module scope) to stay fast.
"""

from __future__ import annotations

import dataclasses
import math
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import frenet
import mmdopt
from mmdopt import algorithm as alg
from mmdopt.collision import ReducedObstacles, SurrogateConfig, reduced_obstacles
from mmdopt.reduced_set import ReducedSet, ReducedSetConfig

NAN, INF = float("nan"), float("inf")
TINY = mmdopt.MMDOptConfig().replace(
    n_samples=60, n_cem=20, n_elite=10, iterations=2, n_brake=5, reduced_set_size=5
)
K = TINY.trajectory.num_steps
PATH = frenet.ReferencePath.straight(200.0)
ROAD = mmdopt.Road()
EGO = frenet.EgoState(s=0.0, d=0.0, vs=10.0)
KEY = jax.random.PRNGKey(0)


def _obstacles(O=1, n=12, x0=40.0, y0=3.5, v=5.0, seed=0):
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, TINY.trajectory.horizon, K)
    xs = x0 + v * t[None, None, :] + rng.normal(0, 0.3, (O, n, 1))
    ys = np.broadcast_to(y0 + rng.normal(0, 0.1, (O, n, 1)), xs.shape)
    return np.stack([xs, ys], -1)


OBS = _obstacles()


def _rs(idx, w, O=1):
    idx = np.asarray(idx)
    w = np.asarray(w, dtype=float)
    return ReducedSet(
        indices=jnp.asarray(idx),
        weights=jnp.asarray(w),
        alpha=jnp.zeros((O, OBS.shape[1])),
        mmd2=jnp.zeros((O,)),
        bandwidth=jnp.ones((O,)),
        method="mmd",
    )


GOOD_IDX = np.arange(5)[None]
GOOD_W = np.full((1, 5), 0.2)


def check(fn, exc, pattern):
    with pytest.raises(exc) as info:
        fn()
    msg = str(info.value)
    assert re.search(pattern, msg), f"message {msg!r} does not name {pattern!r}"


# --------------------------------------------------------------------------------------- frenet
FRENET = [
    ("straight length 0", lambda: frenet.ReferencePath.straight(0.0), "length"),
    ("straight length -5", lambda: frenet.ReferencePath.straight(-5.0), "length"),
    ("straight length nan", lambda: frenet.ReferencePath.straight(NAN), "length"),
    ("straight length inf", lambda: frenet.ReferencePath.straight(INF), "length"),
    ("straight length str", lambda: frenet.ReferencePath.straight("ten"), "length"),
    ("straight heading nan", lambda: frenet.ReferencePath.straight(10.0, heading=NAN), "heading"),
    ("straight heading inf", lambda: frenet.ReferencePath.straight(10.0, heading=INF), "heading"),
    ("straight heading str", lambda: frenet.ReferencePath.straight(10.0, heading="a"), "heading"),
    (
        "straight heading array",
        lambda: frenet.ReferencePath.straight(10.0, heading=[0, 1]),
        "heading",
    ),
    ("straight start 1 value", lambda: frenet.ReferencePath.straight(10.0, start=(1.0,)), "start"),
    ("straight start nan", lambda: frenet.ReferencePath.straight(10.0, start=(NAN, 0)), "start"),
    ("straight start str", lambda: frenet.ReferencePath.straight(10.0, start="ab"), "start"),
    ("waypoints 1 point", lambda: frenet.ReferencePath.from_waypoints([[0, 0]]), "way-points"),
    (
        "waypoints 3 columns",
        lambda: frenet.ReferencePath.from_waypoints(np.zeros((3, 3))),
        "way-points",
    ),
    (
        "waypoints nan",
        lambda: frenet.ReferencePath.from_waypoints([[0, 0], [NAN, 1]]),
        "way-points",
    ),
    (
        "waypoints coincide",
        lambda: frenet.ReferencePath.from_waypoints([[1, 1], [1, 1]]),
        "zero-length",
    ),
    (
        "waypoints duplicate",
        lambda: frenet.ReferencePath.from_waypoints([[0, 0], [1, 0], [1, 0], [2, 0]]),
        "duplicate",
    ),
    (
        "waypoints spacing 0",
        lambda: frenet.ReferencePath.from_waypoints([[0, 0], [1, 0]], spacing=0),
        "spacing",
    ),
    (
        "to_frenet shapes 3 vs 4",
        lambda: PATH.to_frenet(np.zeros(3), np.zeros(4)),
        r"x/y.*x \(3,\).*y \(4,\)",
    ),
    ("to_frenet shapes 2x3 vs 2", lambda: PATH.to_frenet(np.zeros((2, 3)), np.zeros(2)), "x/y"),
    ("to_frenet x nan", lambda: PATH.to_frenet([NAN], [0.0]), "x/y"),
    ("to_frenet y inf", lambda: PATH.to_frenet([0.0], [INF]), "x/y"),
    ("to_frenet x str", lambda: PATH.to_frenet("a", 0.0), r"\bx\b"),
    ("to_frenet y None", lambda: PATH.to_frenet(0.0, None), "x/y"),
    (
        "to_frenet heading shape",
        lambda: PATH.to_frenet(np.zeros(3), np.zeros(3), np.zeros(4)),
        "heading",
    ),
    ("to_frenet heading nan", lambda: PATH.to_frenet([0.0], [0.0], [NAN]), "heading"),
    ("to_cartesian shapes", lambda: PATH.to_cartesian(np.zeros(3), np.zeros(4)), "s/d"),
    ("to_cartesian d nan", lambda: PATH.to_cartesian([1.0], [NAN]), "s/d"),
    (
        "to_cartesian heading shape",
        lambda: PATH.to_cartesian(np.zeros(2), np.zeros(2), np.zeros(5)),
        "heading",
    ),
    (
        "trajectory shapes",
        lambda: PATH.trajectory_to_cartesian(np.zeros(3), np.zeros(4), np.zeros(3), np.zeros(3)),
        "s/d/vs/vd",
    ),
    (
        "trajectory vs nan",
        lambda: PATH.trajectory_to_cartesian([0.0], [0.0], [NAN], [0.0]),
        "trajectory",
    ),
    ("point nan", lambda: PATH.point(NAN), r"\bs\b"),
    ("heading inf", lambda: PATH.heading([INF]), r"\bs\b"),
    ("curvature str", lambda: PATH.curvature("x"), r"\bs\b"),
    ("ego_state nan speed", lambda: PATH.ego_state(0.0, 0.0, NAN, 0.0), "ego state"),
]
for _f in ("s", "d", "vs", "vd", "as_", "ad"):
    FRENET += [
        (f"EgoState.{_f} nan", lambda f=_f: frenet.EgoState(**{f: NAN}), rf"EgoState\.{_f}\b"),
        (f"EgoState.{_f} inf", lambda f=_f: frenet.EgoState(**{f: -INF}), rf"EgoState\.{_f}\b"),
        (f"EgoState.{_f} str", lambda f=_f: frenet.EgoState(**{f: "x"}), rf"EgoState\.{_f}\b"),
    ]


@pytest.mark.parametrize("name,fn,pattern", FRENET, ids=[c[0] for c in FRENET])
def test_frenet_bad_inputs(name, fn, pattern):
    check(fn, ValueError, pattern)


# --------------------------------------------------------------------------------- MMDOptConfig
_CFG = mmdopt.MMDOptConfig()
FLOAT_LEAVES = [
    f.name
    for f in dataclasses.fields(mmdopt.MMDOptConfig)
    if isinstance(getattr(_CFG, f.name), float) and not f.metadata.get("static")
]
INT_FIELDS = [
    f.name
    for f in dataclasses.fields(mmdopt.MMDOptConfig)
    if isinstance(getattr(_CFG, f.name), int) and not isinstance(getattr(_CFG, f.name), bool)
]
CONFIG = [(f"{n}={v}", {n: v}, n) for n in FLOAT_LEAVES for v in (NAN, INF)]
CONFIG += [(f"{n}=1.5", {n: 1.5}, n) for n in INT_FIELDS]
CONFIG += [(f"{n}='3'", {n: "3"}, n) for n in INT_FIELDS]
CONFIG += [
    ("n_elite > n_cem", dict(n_elite=30, n_cem=20), "n_elite"),
    ("n_elite 1", dict(n_elite=1), "n_elite"),
    ("n_brake -1", dict(n_brake=-1), "n_brake"),
    ("iterations 0", dict(iterations=0), "iterations"),
    ("reduced_set_size 0", dict(reduced_set_size=0), "reduced_set_size"),
    ("constraint_points", dict(constraint_points="edge"), "constraint_points"),
    ("dtype float16", dict(dtype="float16"), "dtype"),
    ("admm_rho -1", dict(admm_rho=-1.0), "admm_rho"),
    ("admm_rho nan", dict(admm_rho=NAN), "admm_rho"),
    ("gamma 0", dict(gamma=0.0), "gamma"),
    ("bandwidth -1", dict(bandwidth=-1.0), "bandwidth"),
    ("a 0", dict(a=0.0), r"\ba\b"),
    ("res_tol -1", dict(res_tol=-1.0), "res_tol"),
    ("eta 2", dict(eta=2.0), "eta"),
    ("baseline_margin_scale -1", dict(baseline_margin_scale=-1.0), "baseline_margin_scale"),
]


@pytest.mark.parametrize("name,kw,field", CONFIG, ids=[c[0] for c in CONFIG])
def test_planner_config_rejects(name, kw, field):
    check(lambda: mmdopt.MMDOptConfig().replace(**kw), ValueError, field)


# ---------------------------------------------------------------------------- ReducedSetConfig
_RSC = ReducedSetConfig()
RS_LEAVES = [
    f.name
    for f in dataclasses.fields(ReducedSetConfig)
    if not f.metadata.get("static") and f.name != "bandwidth"
]
RSCONFIG = [(f"{n}={v}", {n: v}, n) for n in RS_LEAVES for v in (NAN, INF)]
RSCONFIG += [(f"{n}='x'", {n: "x"}, n) for n in RS_LEAVES]
RSCONFIG += [
    ("population '20'", dict(population="20"), "population"),
    ("n_elite 2.5", dict(n_elite=2.5), "n_elite"),
    ("iterations 0", dict(iterations=0), "iterations"),
    ("n_elite >= population", dict(population=10, n_elite=10), "n_elite"),
    ("weights mode", dict(weights="softmax"), "weights"),
    ("weights int", dict(weights=3), "weights"),
    ("simplex_iterations 1.0", dict(simplex_iterations=1.0), "simplex_iterations"),
    ("sigma0 0", dict(sigma0=0.0), "sigma0"),
    ("ridge -1", dict(ridge=-1.0), "ridge"),
    ("smoothing 1", dict(smoothing=1.0), "smoothing"),
    ("cov_reg -0.1", dict(cov_reg=-0.1), "cov_reg"),
    ("beta -1", dict(beta=-1.0), "beta"),
    ("bandwidth nan", dict(bandwidth=NAN), "bandwidth"),
    ("alpha_scale 0", dict(alpha_scale=0.0), "alpha_scale"),
]


@pytest.mark.parametrize("name,kw,field", RSCONFIG, ids=[c[0] for c in RSCONFIG])
def test_reduced_set_config_rejects(name, kw, field):
    check(lambda: ReducedSetConfig(**kw), ValueError, field)


# ------------------------------------------------------------------------- reduced-set selection
S1 = OBS[0]  # (n, K, 2)
sel = mmdopt.select_reduced_set
SELECT = [
    ("method unknown", lambda: sel(KEY, S1, 5, "kmeans"), "method"),
    ("m = 0", lambda: sel(KEY, S1, 0), r"\bm\b"),
    ("m > n", lambda: sel(KEY, S1, 13), r"\bm\b"),
    ("m float", lambda: sel(KEY, S1, 5.0), r"\bm\b"),
    ("m bool", lambda: sel(KEY, S1, True), r"\bm\b"),
    ("samples None", lambda: sel(KEY, None, 5), "samples"),
    ("samples 2-D", lambda: sel(KEY, S1[:, :, 0], 5), "samples"),
    ("samples last axis 3", lambda: sel(KEY, np.zeros((12, K, 3)), 5), "samples"),
    ("samples empty", lambda: sel(KEY, np.zeros((0, K, 2)), 1), "samples"),
    ("samples nan", lambda: sel(KEY, np.where(np.arange(2) == 0, NAN, S1), 5), "samples"),
    ("samples inf", lambda: sel(KEY, S1 * INF, 5), "samples"),
    ("degroot without ego_guess", lambda: sel(KEY, S1, 5, "degroot"), "ego_guess"),
    (
        "degroot ego_guess shape",
        lambda: sel(KEY, S1, 5, "degroot", ego_guess=np.zeros((3, 2))),
        "ego_guess",
    ),
    (
        "degroot ego_guess nan",
        lambda: sel(KEY, S1, 5, "degroot", ego_guess=np.full((K, 2), NAN)),
        "ego_guess",
    ),
    ("config wrong type", lambda: sel(KEY, S1, 5, "mmd", {"beta": 1}), "config"),
    ("bandwidth -1", lambda: sel(KEY, S1, 5, "mmd", ReducedSetConfig(bandwidth=-1.0)), "bandwidth"),
    ("key int", lambda: sel(3, S1, 5), "key"),
    ("batched samples 3-D", lambda: mmdopt.select_reduced_sets(KEY, S1, 5), "samples"),
    ("batched zero obstacles", lambda: mmdopt.select_reduced_sets(KEY, OBS[:0], 5), "samples"),
]


@pytest.mark.parametrize("name,fn,pattern", SELECT, ids=[c[0] for c in SELECT])
def test_reduced_set_selection_rejects(name, fn, pattern):
    check(fn, ValueError, pattern)


# ------------------------------------------------------------------- collision and kernel inputs
def _ro(weights, O=1, m=4):
    c = jnp.zeros((O, m, 3, K, 2)) + 50.0
    return ReducedObstacles(centres=c, weights=jnp.asarray(weights, dtype=float))


EGO_XY = np.stack([np.linspace(0, 100, K), np.zeros(K)], -1)[None]
GOOD_RS = _rs(GOOD_IDX, GOOD_W)
COLLISION = [
    (
        "surrogate weights wrong length",
        lambda: mmdopt.mmd_surrogate(EGO_XY, _ro(np.full((1, 3), 1 / 3))),
        "obstacles.weights",
    ),
    (
        "surrogate weights nan",
        lambda: mmdopt.mmd_surrogate(EGO_XY, _ro([[NAN, 0.5, 0.25, 0.25]])),
        "obstacles.weights",
    ),
    (
        "surrogate weights negative",
        lambda: mmdopt.mmd_surrogate(EGO_XY, _ro([[-0.5, 0.5, 0.5, 0.5]])),
        "obstacles.weights",
    ),
    (
        "surrogate weights sum 2",
        lambda: mmdopt.mmd_surrogate(EGO_XY, _ro(np.full((1, 4), 0.5))),
        "obstacles.weights",
    ),
    (
        "surrogate weights sum 0",
        lambda: mmdopt.mmd_surrogate(EGO_XY, _ro(np.zeros((1, 4)))),
        "obstacles.weights",
    ),
    (
        "surrogate ego 2-D",
        lambda: mmdopt.mmd_surrogate(EGO_XY[0], _ro(np.full((1, 4), 0.25))),
        "ego_xy",
    ),
    (
        "surrogate ego wrong K",
        lambda: mmdopt.mmd_surrogate(EGO_XY[:, :10], _ro(np.full((1, 4), 0.25))),
        "obstacles.centres",
    ),
    (
        "surrogate ego nan",
        lambda: mmdopt.mmd_surrogate(EGO_XY * NAN, _ro(np.full((1, 4), 0.25))),
        "ego_xy",
    ),
    (
        "surrogate bandwidth 0",
        lambda: mmdopt.mmd_surrogate(
            EGO_XY, _ro(np.full((1, 4), 0.25)), SurrogateConfig(bandwidth=0.0)
        ),
        "bandwidth",
    ),
    ("surrogate obstacles dict", lambda: mmdopt.mmd_surrogate(EGO_XY, {"centres": 1}), "obstacles"),
    (
        "surrogate terms weights",
        lambda: mmdopt.mmd_surrogate_terms(EGO_XY, _ro(np.full((1, 4), 0.5)), SurrogateConfig()),
        "obstacles.weights",
    ),
    (
        "reduced_obstacles index 12",
        lambda: reduced_obstacles(OBS, _rs([[0, 1, 2, 3, 12]], GOOD_W)),
        "reduced.indices",
    ),
    (
        "reduced_obstacles index -1",
        lambda: reduced_obstacles(OBS, _rs([[0, 1, 2, 3, -1]], GOOD_W)),
        "reduced.indices",
    ),
    (
        "reduced_obstacles float index",
        lambda: reduced_obstacles(OBS, _rs(np.zeros((1, 5)) + 0.5, GOOD_W)),
        "reduced.indices",
    ),
    (
        "reduced_obstacles weights nan",
        lambda: reduced_obstacles(OBS, _rs(GOOD_IDX, np.full((1, 5), NAN))),
        "reduced.weights",
    ),
    (
        "reduced_obstacles weights sum",
        lambda: reduced_obstacles(OBS, _rs(GOOD_IDX, np.full((1, 5), 0.3))),
        "reduced.weights",
    ),
    (
        "reduced_obstacles weights len",
        lambda: reduced_obstacles(OBS, _rs(GOOD_IDX, np.full((1, 4), 0.25))),
        "reduced.weights",
    ),
    (
        "reduced_obstacles O mismatch",
        lambda: reduced_obstacles(_obstacles(O=2), GOOD_RS),
        "reduced.indices",
    ),
    ("reduced_obstacles list len", lambda: reduced_obstacles(OBS, [GOOD_RS, GOOD_RS]), "reduced"),
    ("reduced_obstacles not a set", lambda: reduced_obstacles(OBS, {"indices": 1}), "reduced"),
    ("count ego 1-D", lambda: mmdopt.collision_free_count(np.zeros(K), OBS), "ego_xy"),
    (
        "count K mismatch",
        lambda: mmdopt.collision_free_count(EGO_XY[0, :10], OBS),
        "validation_samples",
    ),
    ("count ego nan", lambda: mmdopt.collision_free_count(EGO_XY[0] * NAN, OBS), "ego_xy"),
    (
        "count samples inf",
        lambda: mmdopt.collision_free_count(EGO_XY[0], OBS * INF),
        "validation_samples",
    ),
    ("count a = 0", lambda: mmdopt.collision_free_count(EGO_XY[0], OBS, a=0.0), r"\ba\b"),
    (
        "mmd2_weighted wx length",
        lambda: mmdopt.mmd2_weighted(
            np.zeros((4, 2)), np.ones(3), np.zeros((5, 2)), np.ones(5), 1.0
        ),
        "wx",
    ),
    (
        "mmd2_weighted wy length",
        lambda: mmdopt.mmd2_weighted(
            np.zeros((4, 2)), np.ones(4), np.zeros((5, 2)), np.ones(2), 1.0
        ),
        "wy",
    ),
    (
        "mmd2_weighted d mismatch",
        lambda: mmdopt.mmd2_weighted(
            np.zeros((4, 2)), np.ones(4), np.zeros((5, 3)), np.ones(5), 1.0
        ),
        r"x and y",
    ),
    (
        "mmd2_to_dirac w length",
        lambda: mmdopt.mmd2_to_dirac(np.zeros(4), np.ones(3), 1.0),
        r"\bw\b",
    ),
    (
        "gram d mismatch",
        lambda: mmdopt.gaussian_gram(np.zeros((4, 2)), np.zeros((3, 3))),
        r"x and y",
    ),
]


@pytest.mark.parametrize("name,fn,pattern", COLLISION, ids=[c[0] for c in COLLISION])
def test_collision_and_kernel_inputs(name, fn, pattern):
    check(fn, ValueError, pattern)


# -------------------------------------------------------------------------- Road and plan inputs
ROADS = [("Road.path str", dict(path="straight"), "Road.path")]
for _f in ("y_lb", "y_ub", "v_min", "v_max", "vy_max", "ax_max", "ay_max"):
    ROADS += [
        (f"Road.{_f} nan", {_f: NAN}, rf"Road\.{_f}\b"),
        (f"Road.{_f} str", {_f: "x"}, rf"Road\.{_f}\b"),
    ]
ROADS += [
    ("y_lb > y_ub", dict(y_lb=1.0, y_ub=0.0), "y_lb"),
    ("v_min > v_max", dict(v_min=5.0, v_max=1.0), "v_min"),
    ("ax_max 0", dict(ax_max=0.0), "ax_max"),
]


@pytest.mark.parametrize("name,kw,pattern", ROADS, ids=[c[0] for c in ROADS])
def test_road_rejects(name, kw, pattern):
    check(lambda: mmdopt.Road(**kw), ValueError, pattern)


def _plan(obstacles=OBS, **kw):
    kw.setdefault("config", TINY)
    kw.setdefault("key", KEY)
    return mmdopt.plan(kw.pop("ego", EGO), kw.pop("road", ROAD), obstacles, **kw)


PLAN = [
    ("obstacles None", lambda: _plan(None), "obstacles"),
    ("obstacles str", lambda: _plan("cars"), "obstacles"),
    ("obstacles 3-D", lambda: _plan(OBS[0]), "obstacles"),
    ("obstacles last axis 3", lambda: _plan(np.zeros((1, 12, K, 3))), "obstacles"),
    ("obstacles zero samples", lambda: _plan(OBS[:, :0]), "obstacles"),
    ("obstacles wrong horizon", lambda: _plan(OBS[:, :, :50]), "num_steps"),
    ("obstacles nan", lambda: _plan(np.where(np.arange(2) == 0, NAN, OBS)), "obstacles"),
    ("obstacles inf", lambda: _plan(OBS + INF), "obstacles"),
    ("obstacles 1e300", lambda: _plan(OBS * 0 + 1e300), "obstacles"),
    ("obstacles 1e8", lambda: _plan(OBS + 1e8), "obstacles"),
    ("n < reduced_set_size", lambda: _plan(OBS[:, :3]), "reduced_set_size"),
    ("method unknown", lambda: _plan(method="mpc"), "method"),
    ("projector unknown", lambda: _plan(projector="gurobi"), "projector"),
    ("projector int", lambda: _plan(projector=3), "projector"),
    ("settings for admm-fixed", lambda: _plan(max_iter=10), "admm-fixed"),
    ("key int", lambda: _plan(key=7), "key"),
    ("key wrong shape", lambda: _plan(key=jnp.zeros(3, jnp.uint32)), "key"),
    ("config dict", lambda: _plan(config={"iterations": 2}), "config"),
    ("ego tuple", lambda: _plan(ego=(0, 0, 10)), "ego"),
    ("road path", lambda: _plan(road=PATH), "road"),
    ("warm_start dict", lambda: _plan(warm_start={}), "warm_start"),
    ("reduced_set for saa", lambda: _plan(method="saa", reduced_set=GOOD_RS), "reduced_set"),
    ("reduced_set dict", lambda: _plan(reduced_set={"indices": GOOD_IDX}), "reduced_set"),
    (
        "reduced_set index 12",
        lambda: _plan(reduced_set=_rs([[0, 1, 2, 3, 12]], GOOD_W)),
        "reduced_set.indices",
    ),
    (
        "reduced_set index -1",
        lambda: _plan(reduced_set=_rs([[-1, 1, 2, 3, 4]], GOOD_W)),
        "reduced_set.indices",
    ),
    (
        "reduced_set 1-D",
        lambda: _plan(reduced_set=_rs(np.arange(5), np.full(5, 0.2))),
        "reduced_set.indices",
    ),
    (
        "reduced_set float index",
        lambda: _plan(reduced_set=_rs(GOOD_IDX * 1.0, GOOD_W)),
        "reduced_set.indices",
    ),
    (
        "reduced_set weights len",
        lambda: _plan(reduced_set=_rs(GOOD_IDX, np.full((1, 4), 0.25))),
        "reduced_set.weights",
    ),
    (
        "reduced_set weights nan",
        lambda: _plan(reduced_set=_rs(GOOD_IDX, np.full((1, 5), NAN))),
        "reduced_set.weights",
    ),
    (
        "reduced_set weights negative",
        lambda: _plan(reduced_set=_rs(GOOD_IDX, [[0.6, 0.6, -0.2, 0.0, 0.0]])),
        "reduced_set.weights",
    ),
    (
        "reduced_set weights sum 2",
        lambda: _plan(reduced_set=_rs(GOOD_IDX, np.full((1, 5), 0.4))),
        "reduced_set.weights",
    ),
    (
        "plan_frenet nan",
        lambda: mmdopt.plan_frenet(EGO, ROAD, OBS * NAN, config=TINY),
        "obstacles_frenet",
    ),
    (
        "plan_frenet 3-D",
        lambda: mmdopt.plan_frenet(EGO, ROAD, OBS[0], config=TINY),
        "obstacles_frenet",
    ),
]


@pytest.mark.parametrize("name,fn,pattern", PLAN, ids=[c[0] for c in PLAN])
def test_plan_rejects(name, fn, pattern):
    check(fn, ValueError, pattern)


# ------------------------------------------------------------------ the step API (Algorithm 1)
def _centres(O=1, J=4):
    return np.zeros((O, J, 3, K, 2)) + 50.0


PROBLEM = alg.Problem.create(TINY, EGO, ROAD.bounds())
WS = mmdopt.Planner(TINY).workspace(ROAD.bounds())
STEP = [
    (
        "ObstacleSet mode",
        lambda: alg.ObstacleSet.create(TINY, _centres(), np.full((1, 4), 0.25), "bogus"),
        "mode",
    ),
    (
        "ObstacleSet centres 4-D",
        lambda: alg.ObstacleSet.create(TINY, _centres()[0], np.full((1, 4), 0.25), "mmd"),
        "centres",
    ),
    (
        "ObstacleSet centres K",
        lambda: alg.ObstacleSet.create(TINY, _centres()[..., :10, :], np.full((1, 4), 0.25), "mmd"),
        "centres",
    ),
    (
        "ObstacleSet weights shape",
        lambda: alg.ObstacleSet.create(TINY, _centres(), np.full((1, 3), 1 / 3), "mmd"),
        "weights",
    ),
    (
        "ObstacleSet weights nan",
        lambda: alg.ObstacleSet.create(TINY, _centres(), np.full((1, 4), NAN), "mmd"),
        "weights",
    ),
    (
        "ObstacleSet centres inf",
        lambda: alg.ObstacleSet.create(TINY, _centres() + INF, np.full((1, 4), 0.25), "mmd"),
        "centres",
    ),
    (
        "ObstacleSet weights negative",
        lambda: alg.ObstacleSet.create(TINY, _centres(), np.array([[0.5, 0.5, 0.5, -0.5]]), "mmd"),
        "weights",
    ),
    (
        "ObstacleSet mask shape",
        lambda: alg.ObstacleSet.create(
            TINY, _centres(), np.full((1, 4), 0.25), "scenario", np.ones(4)
        ),
        "mask",
    ),
    ("init workspace", lambda: alg.init({}, TINY, PROBLEM, KEY), "ws"),
    ("init config", lambda: alg.init(WS, {}, PROBLEM, KEY), "config"),
    ("init problem", lambda: alg.init(WS, TINY, EGO, KEY), "problem"),
    ("init warm_start", lambda: alg.init(WS, TINY, PROBLEM, KEY, warm_start=3), "warm_start"),
    ("update state", lambda: alg.update(WS, TINY, PROBLEM, {}, None), "state"),
    (
        "update settings on admm-fixed",
        lambda: alg.update(WS, TINY, PROBLEM, None, None, "admm-fixed", rho=1.0),
        "admm-fixed",
    ),
    ("run config", lambda: alg.run(WS, {}, PROBLEM, None, KEY), "config"),
    ("run projector int", lambda: alg.run(WS, TINY, PROBLEM, None, KEY, projector=1), "projector"),
    ("shift config", lambda: alg.shift({}, None, 0.1), "config"),
    ("shift state", lambda: alg.shift(TINY, {}, 0.1), "state"),
    ("Planner config", lambda: mmdopt.Planner({}), "config"),
    ("Planner problem", lambda: mmdopt.Planner(TINY).init(EGO, KEY), "problem"),
]


@pytest.mark.parametrize("name,fn,pattern", STEP, ids=[c[0] for c in STEP])
def test_step_api_rejects(name, fn, pattern):
    check(fn, ValueError, pattern)


@pytest.fixture(scope="module")
def state():
    obs = alg.ObstacleSet.create(TINY, _centres(), np.full((1, 4), 0.25), "mmd")
    return mmdopt.Planner(TINY).init(PROBLEM, KEY), obs


@pytest.mark.parametrize("dt", [NAN, INF, -0.1], ids=["nan", "inf", "negative"])
def test_shift_rejects_bad_dt(state, dt):
    check(lambda: alg.shift(TINY, state[0], dt), ValueError, r"\bdt\b")


@pytest.mark.slow
def test_update_rejects_a_used_up_state(state):
    s, obs = state
    planner = mmdopt.Planner(TINY)
    for _ in range(TINY.cem.iterations):
        s = planner.update(PROBLEM, s, obs)
    check(lambda: planner.update(PROBLEM, s, obs), ValueError, "iterations")


def test_update_rejects_wrong_obstacles(state):
    check(
        lambda: mmdopt.Planner(TINY).update(PROBLEM, state[0], {"centres": 1}),
        ValueError,
        "obstacles",
    )


def test_shift_and_warm_start_reject_a_state_of_other_sizes(state):
    other = TINY.replace(num_segments=TINY.trajectory.num_segments + 1)
    check(lambda: alg.shift(other, state[0], 0.1), ValueError, "state.mu")
    obs = np.zeros((1, 8, TINY.trajectory.num_steps, 2))
    obs[..., 0] = 50.0
    check(
        lambda: mmdopt.plan(EGO, ROAD, obs, config=other, warm_start=state[0]),
        ValueError,
        "warm_start",
    )


# -------------------------------------------------------------- plans: statuses, never a bad 'ok'
def _status_ok(p):
    """The bar: a plan that says 'ok' (or only that the samples cannot confirm the risk level)
    has a finite cost, finite trajectory and is feasible."""
    if p.status in ("ok", "risk floor", "risk exceeded"):
        assert math.isfinite(p.cost) and not p.fallback
        assert all(np.all(np.isfinite(a)) for a in (p.x, p.y, p.s, p.d, p.vs))
    return p.status_text


@pytest.mark.slow
@pytest.mark.parametrize("method", ["mmd", "degroot", "saa"])
def test_obstacle_on_top_of_the_ego_is_unsafe_not_ok(method):
    # an obstacle that stays on the ego for the whole horizon: every plan collides
    t = np.linspace(0.0, TINY.trajectory.horizon, K)
    xs = 10.0 * t[None, None, :] + np.linspace(-0.2, 0.2, 12)[None, :, None]
    obs = np.stack([xs, np.zeros_like(xs)], -1)
    p = _plan(obs, method=method)
    assert _status_ok(p).startswith("unsafe:"), p.status
    assert "obstacle(s) [0]" in p.message and not p.fallback


def test_speed_above_limit_is_a_braking_fallback():
    p = _plan(ego=frenet.EgoState(vs=45.0))
    assert _status_ok(p).startswith("fallback:") and p.fallback
    assert np.all(np.isfinite(p.x))


def test_far_obstacle_plan_is_ok_with_finite_cost():
    p = _plan(_obstacles(x0=5e6))
    assert _status_ok(p).startswith("risk floor: asked 0.005"), p.status_text
    assert p.risk_bound == mmdopt.risk.risk_floor([p.diagnostics["n_planning_samples"]])


def test_given_reduced_set_plan_is_ok():
    p = _plan(reduced_set=GOOD_RS)
    assert _status_ok(p).startswith(("ok", "risk floor")), p.status_text
    assert np.allclose(np.asarray(p.reduced_set.weights), GOOD_W)


# ------------------------------------------------------------------------ bench timing (library)
@pytest.mark.parametrize(
    "kw,pattern",
    [
        (dict(sizes=[10, 20], samples=[5, 50]), "samples"),
        (dict(sizes=[10, 200], samples=[50]), "sizes"),
        (dict(sizes=[0], samples=[50]), "sizes"),
        (dict(sizes=[], samples=[50]), "sizes"),
    ],
    ids=["samples-below-sizes", "size-above-100", "size-0", "no-sizes"],
)
def test_timing_refuses_instead_of_dropping(tmp_path, kw, pattern):
    from mmdopt.bench.timing import run_timing

    check(lambda: run_timing(tmp_path, progress=False, **kw), ValueError, pattern)
    assert not (tmp_path / "timing.csv").exists()
