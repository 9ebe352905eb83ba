"""Routes in the predictor on the shared Lankershim scenes: every route a car can still take is a
mode, known without its recorded future; the learned route weights pick the route the car took
on held-out scenes; the user's split (skipped with a reason where ../shared/data is absent)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

pytest.importorskip(
    "commonroad", reason="the ngsim benchmark needs commonroad-io (mmdopt[commonroad])"
)
pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


@pytest.fixture(scope="module")
def urban(shared_data):
    d = shared_data / "ngsim_urban"
    if not (d / "USA_Lanker-2_5_T-1.xml").is_file():
        pytest.skip(f"Lankershim scenes not found in {d}")
    return d


def _junction_car(sc, k):
    """A car recorded at step k with more than one route."""
    from mmdopt.bench.ngsim.scene import candidate_routes

    for v in np.flatnonzero(np.isfinite(sc.xy[:, k, 0]) & (sc.lane_of[:, k] >= 0)):
        if len(candidate_routes(sc, int(v), k)) > 1:
            return int(v)
    pytest.fail("no car with two routes at this step")


def test_routes_and_the_predictor_context_never_see_the_future(urban):
    """Erasing a car's recorded future changes neither its routes nor its context centre line
    (the lane predictors' input): at a junction they do not know which way it will go."""
    from mmdopt.bench.ngsim.scene import candidate_routes, context_at, load_scenario

    sc = load_scenario(str(urban / "USA_Lanker-2_5_T-1.xml"))
    k = 20
    v = _junction_car(sc, k)
    cut = dataclasses.replace(sc, xy=sc.xy.copy(), lane_of=sc.lane_of.copy())
    cut.xy[v, k + 1 :] = np.nan
    cut.lane_of[v, k + 1 :] = -1
    a, b = candidate_routes(sc, v, k), candidate_routes(cut, v, k)
    assert len(a) == len(b) > 1
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    times = np.linspace(0, 5, 51)
    ca, cb = context_at(sc, [v], k, times), context_at(cut, [v], k, times)
    np.testing.assert_array_equal(ca.centerline, cb.centerline)
    # every route has the context's shape and starts behind the car and passes by it
    for r in a:
        assert r.shape == ca.centerline.shape[1:]
        assert np.min(np.linalg.norm(r - sc.xy[v, k], axis=-1)) < 4.0


def test_learned_route_weights_pick_the_route_taken_on_held_out_scenes(urban):
    """On the two default held-out Lankershim scenes (never in the weights' fit), argmax
    P(route) is the route the car then took for at least 85 % of the cars with several."""
    from mmdopt.bench.ngsim.routes import (
        load_route_weights,
        route_probabilities,
        route_windows,
        taken_route,
    )

    w = load_route_weights()
    assert "USA_Lanker-2_5_T-1.xml" not in w.info.get("train_files", [])
    rows = [
        r
        for f in ("USA_Lanker-2_5_T-1.xml", "USA_Lanker-2_10_T-1.xml")
        for r in route_windows([urban / f], stride=10)
        if len(r[3]) > 1
    ]
    assert len(rows) >= 20
    hits = []
    for _, _, h, rs, fut, dt in rows:
        (p,) = route_probabilities(h[None], [rs], dt, w)
        assert p.sum() == pytest.approx(1.0) and np.all(p >= 0)
        hits.append(int(np.argmax(p)) == taken_route(rs, fut))
    assert np.mean(hits) >= 0.85


def test_route_mixture_splits_the_draws_over_the_routes(urban):
    from mmdopt.bench.ngsim.routes import RouteMixture
    from mmdopt.bench.ngsim.scene import candidate_routes, context_at, history_at, load_scenario
    from mmdopt.predict import LaneAware

    sc = load_scenario(str(urban / "USA_Lanker-2_5_T-1.xml"))
    k = 20
    v = _junction_car(sc, k)
    rs = np.stack(candidate_routes(sc, v, k))[:2]
    ctx = context_at(sc, [v], k, np.linspace(0, 5, 51))
    hist = history_at(sc, [v], k, 10)
    key = __import__("jax").random.PRNGKey(3)
    inner = LaneAware()
    # all the weight on one route: the inner predictor's draws along that route
    one = RouteMixture(inner, (rs,), (np.array([0.0, 1.0]),)).sample(hist, ctx, 40, key)
    alone = inner.sample(hist, dataclasses.replace(ctx, centerline=rs[1:2]), 40, key)
    assert one.shape == alone.shape == (1, 40, 51, 2)
    end = lambda d: np.median(d[0, :, -1], axis=0)  # noqa: E731
    assert np.linalg.norm(end(one) - end(alone)) < 2.0
    # half and half: the draws end near both routes, and the same key gives the same draws
    mix = RouteMixture(inner, (rs,), (np.array([0.5, 0.5]),))
    a, b = mix.sample(hist, ctx, 40, key), mix.sample(hist, ctx, 40, key)
    np.testing.assert_array_equal(a, b)
    d = np.stack([np.min(np.linalg.norm(a[0, :, -1, None] - r[None], axis=-1), 1) for r in rs])
    near = np.argmin(d, 0)
    assert 10 <= np.sum(near == 0) <= 30
    with pytest.raises(ValueError, match="probabilities"):
        RouteMixture(inner, (rs,), (np.array([0.7, 0.7]),))
    with pytest.raises(ValueError, match="routes"):
        RouteMixture(inner, (rs[0],), (np.array([1.0]),))


def test_the_split_is_the_users(urban, shared_data):
    from mmdopt.bench.ngsim.data import split_files

    train, test = split_files(urban)
    assert [f.name for f in test] == ["USA_Lanker-2_10_T-1.xml", "USA_Lanker-2_5_T-1.xml"]
    assert len(train) == 12 and not set(train) & set(test)
    train, test = split_files(urban, holdout=["USA_Lanker-2_1[0-3]*", "USA_Lanker-1_2_T-1.xml"])
    assert {f.name for f in test} == {
        "USA_Lanker-1_2_T-1.xml",
        *(f"USA_Lanker-2_{n}_T-1.xml" for n in (10, 11, 12, 13)),
    }
    with pytest.raises(ValueError, match="'nothing\\*' matches none"):
        split_files(urban, holdout=["nothing*"])


def test_predictor_eval_names_a_holdout_that_matches_nothing(urban, capsys):
    from mmdopt.bench.cli import main

    with pytest.raises(SystemExit) as e:
        main(["predictor", "eval", "--data", str(urban), "--holdout", "nothing*"])
    assert e.value.code == 2
    assert "--holdout" in capsys.readouterr().err
