"""The learned highway predictor (mmdopt.bench.highway: LearnedPredictor, training): samples on a
real highway-env scene with histories recorded by the scene source, the training command end to
end, the lane context of merge-v0's ramp.

Skipped when highway-env is not installed (``pip install -e ".[highway]"``).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from mmdopt.bench import highway as hw

pytestmark = pytest.mark.skipif(
    not hw.highway_available(),
    reason='highway-env/gymnasium not installed (pip install ".[highway]")',
)


def test_learned_predictor_samples_futures_from_the_recorded_histories():
    settings = hw.HighwaySettings(
        duration=1.0, dt=0.5, n_samples=8, predictor="learned", forecast=False
    )
    src = hw.HighwaySource(settings, 0, hw.highway_config(), method="idm")
    try:
        src.run_idm()  # 1 s of traffic: ten frames recorded by the predictor
        targets = src._targets()
        obs = src.observe()
        O, n, K = len(targets), 8, len(src.t_grid)
        assert O > 0 and obs.obstacles.shape == (O, n, K, 2)
        assert np.all(np.isfinite(obs.obstacles))
        now = np.array([v.position for v in targets])
        assert np.allclose(obs.obstacles[:, :, 0], now[:, None], atol=1e-6)
        # the history is what the cars did over the last 0.9 s, not an extrapolation
        h = src.predictor._history(targets[0])
        assert h.shape == (10, 2) and np.allclose(h[-1], now[0])
        travelled = np.linalg.norm(h[-1] - h[0])
        assert travelled == pytest.approx(0.9 * targets[0].speed, rel=0.2)
        # cars drive forward along their lanes: 5 s ahead, the samples are near where the
        # current speed takes them, and on the road (highway-v0's four lanes run along +x with
        # centres y = 0 … 12 m, 4 m wide; a car is 2 m wide)
        speed = np.array([v.speed for v in targets])
        ahead = obs.obstacles[:, :, -1, 0] - now[:, 0:1]
        assert np.all(np.abs(np.median(ahead, 1) - 5.0 * speed) < 0.25 * 5.0 * speed + 5.0)
        y = obs.obstacles[..., 1]
        assert y.min() >= -1.0 - 1e-9 and y.max() <= 13.0 + 1e-9
        assert obs.info["predict_s"] > 0
    finally:
        src.close()


def test_cars_seen_for_less_than_the_history_are_extrapolated_backwards():
    p = hw.make_predictor("learned")
    src = hw.HighwaySource(hw.HighwaySettings(duration=1.0), 1, hw.highway_config(), method="idm")
    try:
        road = src.env.road
        targets = src._targets()[:2]
        out = p(road, src.ego, targets, src.t_grid, 8, np.random.default_rng(0))
        assert out.shape == (2, 8, len(src.t_grid), 2) and np.all(np.isfinite(out))
        v = targets[0]
        h = p._history(v)  # nothing recorded before now: constant velocity backwards
        assert np.allclose(h[0], v.position - 0.9 * np.asarray(v.velocity), atol=1e-9)
    finally:
        src.close()


def test_merge_ramp_centerline_follows_the_ramp_then_goes_straight():
    from mmdopt.bench.highway.training import lane_centerline, rollout

    rec = rollout("merge-v0", 7, duration=1.0)
    ramp = next(i for i, li in enumerate(rec.lane[-1]) if li[0] == "j")
    cl = lane_centerline(rec.network, rec.lane[-1][ramp], rec.xy[ramp, -1])
    assert np.all(np.linalg.norm(np.diff(cl, axis=0), axis=-1) > 1.0)  # no repeated points
    # on the ramp (y = 14.5), then up the sine lane onto the merging lane (y = 8), which ends
    # at x = 310: the centre line goes on straight instead of jumping to another lane
    assert cl[0, 1] == pytest.approx(14.5) and cl[-1, 1] == pytest.approx(8.0)
    assert cl[-1, 0] > 310.0


def test_predictor_train_highway_end_to_end(tmp_path, capsys):
    from mmdopt.bench.cli import main

    out = tmp_path / "w"
    argv = ["predictor", "train", "--source", "highway", "--episodes", "1", "--duration", "7"]
    rc = main(argv + ["--steps", "20", "--no-eval", "--out", str(out)])
    assert rc == 0 and "wrote" in capsys.readouterr().out
    info = json.loads(out.with_suffix(".json").read_text())["info"]
    assert "--source highway" in info["command"]
    assert all(int(e["seeds"].split("-")[0]) >= 100_000 for e in info["envs"])
    p = hw.LearnedPredictor(weights=out)
    assert p._model.config.horizon == pytest.approx(5.0)
    with pytest.raises(SystemExit):  # --data belongs to the NGSIM source
        main(argv + ["--data", str(tmp_path), "--out", str(out)])
    assert "--data" in capsys.readouterr().err


def test_a_car_whose_lane_ends_is_predicted_to_leave_it_before_the_end():
    """merge-v0: a car on the ramp (whose way leads into the acceleration lane, x 230-310 m)
    has every sample in the neighbouring main lane by the lane's end, merging at starts spread
    over the way there; a car on a main lane is left as predicted."""
    import gymnasium as gym

    from mmdopt.bench.highway.predictors import _merge_before_lane_end

    env = gym.make("merge-v0").unwrapped
    env.reset(seed=0)
    net = env.road.network
    rng = np.random.default_rng(0)
    x = np.linspace(200.0, 330.0, 27)
    ramp = np.zeros((50, x.size, 2))
    ramp[..., 0], ramp[..., 1] = x, 8.0
    _merge_before_lane_end(net, ("k", "b", 0), ramp, rng)
    at_end = ramp[:, x >= 310.0, 1]
    np.testing.assert_allclose(at_end, 4.0)  # the main lane next to the acceleration lane
    half_way = ramp[:, np.argmin(abs(x - 260.0)), 1]
    assert (half_way < 7.9).any() and (half_way > 7.9).any()  # some have merged, some not
    main = np.zeros((5, x.size, 2))
    main[..., 0], main[..., 1] = x, 4.0
    before = main.copy()
    _merge_before_lane_end(net, ("a", "b", 1), main, rng)
    np.testing.assert_array_equal(main, before)
    env.close()


def test_a_merging_car_yields_to_the_lane_it_enters():
    """merge-v0: a car slowing to 5 m/s on the acceleration lane, the ego beside it in the lane
    it enters.  Ego 8 m behind at a stop: no sample merges in front of it unless 10 m + 1 s
    ahead, so samples wait at the lane's end; ego far ahead: the merge is unhindered."""
    import gymnasium as gym

    from mmdopt.bench.highway.predictors import MERGE_SPACING_M, _merge_before_lane_end

    env = gym.make("merge-v0").unwrapped
    env.reset(seed=0)
    net = env.road.network
    t = np.linspace(0.0, 5.0, 26)
    x = 290.0 + 5.0 * t
    car = np.zeros((40, t.size, 2))
    car[..., 0], car[..., 1] = x, 8.0
    free = car.copy()
    blocked = car.copy()
    _merge_before_lane_end(
        net, ("b", "c", 2), blocked, np.random.default_rng(1), t_grid=t,
        through=np.array([[282.0, 4.0, 0.0]]),
    )  # fmt: skip
    # wherever a sample is in the ego's lane (within 2 m of y = 4), it is far enough ahead
    in_lane = np.abs(blocked[..., 1] - 4.0) < 2.0
    assert (blocked[..., 0][in_lane] - 282.0 >= MERGE_SPACING_M).all()
    _merge_before_lane_end(
        net, ("b", "c", 2), free, np.random.default_rng(1), t_grid=t,
        through=np.array([[400.0, 4.0, 20.0]]),
    )  # fmt: skip
    unhindered = car.copy()
    _merge_before_lane_end(net, ("b", "c", 2), unhindered, np.random.default_rng(1))
    np.testing.assert_allclose(free, unhindered)
    # the ego close behind holds every sample back for longer than the free road does
    assert blocked[..., 1].mean() > free[..., 1].mean()
    env.close()
