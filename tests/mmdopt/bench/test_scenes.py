"""Synthetic scene generator: reproducibility, intent statistics, stream independence, overrides."""

import itertools
import json

import numpy as np
import pytest

from mmdopt.bench import scenes as scenarios
from mmdopt.bench.scenes import SceneParams, load_scene_params, make_scene, make_scenes

SMALL = SceneParams(n_samples=40, n_validation=200)


def _binomial_ok(k: int, n: int, p: float, z: float = 5.0) -> bool:
    """|k − np| within z standard deviations (false-failure rate < 1e-6 at z = 5)."""
    return abs(k - n * p) <= z * np.sqrt(n * p * (1 - p)) + 1


def test_same_seed_same_scene_and_different_seed_differs():
    a, b = make_scene(3, seed=7, params=SMALL), make_scene(3, seed=7, params=SMALL)
    for name in ("obstacles", "validation", "intents", "speed_setpoints"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert (a.x0, a.y0, a.p, a.planner_seed) == (b.x0, b.y0, b.p, b.planner_seed)
    c = make_scene(3, seed=8, params=SMALL)
    assert not np.array_equal(a.obstacles, c.obstacles)
    assert a.planner_seed != c.planner_seed


def test_scene_does_not_depend_on_how_many_scenes_are_generated():
    many = make_scenes(4, seed=1, params=SMALL)
    one = make_scene(2, seed=1, params=SMALL)
    np.testing.assert_array_equal(many[2].obstacles, one.obstacles)
    np.testing.assert_array_equal(many[2].validation, one.validation)
    # every scene draws its own obstacle start, lane and probability
    assert len({(s.x0, s.y0, s.p) for s in many}) == 4


def test_shapes_frame_and_ego():
    s = make_scene(0, params=SMALL)
    assert s.obstacles.shape == (1, 40, 100, 2)
    assert s.validation.shape == (1, 200, 100, 2)
    # the obstacle starts at its drawn (x0, y0) and every sample ends at its intent's offset
    np.testing.assert_allclose(
        s.obstacles[0, :, 0], np.broadcast_to([s.x0, s.y0], (40, 2)), atol=1e-8
    )
    targets = np.asarray(s.params.intent_offsets)[s.intents]
    np.testing.assert_allclose(s.obstacles[0, :, -1, 1], targets, atol=0.05)
    assert 45 <= s.x0 <= 75 and s.y0 in (-3.0, 0.0) and 0.05 <= s.p <= 0.30
    ego = s.ego()
    assert (ego.s, ego.d, ego.vs) == (0.0, 0.0, 10.0)


def test_intent_frequencies_match_probabilities():
    params = SceneParams(n_samples=2000, n_validation=20000, p_range=(0.2, 0.2))
    s = make_scene(0, seed=3, params=params)
    assert s.p == pytest.approx(0.2)
    for intents in (s.intents, s.validation_intents):
        assert _binomial_ok(int(np.sum(intents == 0)), intents.size, 0.2)
    # three intents with fixed probabilities
    p3 = SceneParams(
        n_samples=10,
        n_validation=20000,
        intent_offsets=(0.0, 3.5, -3.5),
        intent_probs=(0.5, 0.3, 0.2),
    )
    v = make_scene(1, params=p3).validation_intents
    for i, p in enumerate((0.5, 0.3, 0.2)):
        assert _binomial_ok(int(np.sum(v == i)), v.size, p)


def test_speed_setpoints_are_gaussian_with_the_configured_moments():
    s = make_scene(0, params=SceneParams(n_samples=10, n_validation=20000))
    v = s.validation_speed_setpoints
    assert abs(v.mean() - 5.0) < 5 * np.sqrt(2.0 / v.size)
    assert abs(v.var() - 2.0) < 0.1
    assert v.min() >= 0.1


def test_validation_samples_are_independent_of_planning_samples():
    a = make_scene(5, params=SceneParams(n_samples=50, n_validation=100))
    b = make_scene(5, params=SceneParams(n_samples=50, n_validation=300))
    c = make_scene(5, params=SceneParams(n_samples=80, n_validation=100))
    # each role has its own stream: changing one set's size leaves the other untouched
    np.testing.assert_array_equal(a.obstacles, b.obstacles)
    np.testing.assert_array_equal(a.validation, c.validation)
    np.testing.assert_array_equal(a.validation_intents, b.validation_intents[:100])
    np.testing.assert_allclose(a.validation, b.validation[:, :100], atol=1e-9)
    # ... and the two sets are not copies of each other (speed draws uncorrelated)
    va, vp = a.validation_speed_setpoints[:50], a.speed_setpoints
    assert not np.any(np.isclose(va, vp))
    assert abs(np.corrcoef(va, vp)[0, 1]) < 5 / np.sqrt(50)


def test_reference36_grid_and_paper100_preset():
    ref = scenarios.preset("reference36")
    scenes = make_scenes(
        params=SceneParams(layout="grid", num_scenes=36, n_samples=5, n_validation=5)
    )
    assert len(scenes) == 36 == ref.num_scenes
    got = {(s.x0, s.y0, round(s.p, 2)) for s in scenes}
    want = set(
        itertools.product((45.0, 60.0, 75.0), (-3.0, 0.0), (0.05, 0.1, 0.15, 0.2, 0.25, 0.3))
    )
    assert got == want
    with pytest.raises(ValueError, match="only 36"):
        scenarios.num_scenes(ref, 37)
    assert scenarios.num_scenes(scenarios.preset("paper100")) == 100
    assert scenarios.preset("lanechange").ego_y_ub > 3.5
    with pytest.raises(ValueError, match="unknown preset"):
        scenarios.preset("nope")


def test_reference_sanity_numbers_scene_45_m3_10():
    """As in the reference code: on 45_−3_10 about 90 % of the samples end in the left lane,
    final speed ≈ 5 m/s."""
    s = scenarios.demo_scene()
    assert (s.x0, s.y0, s.p) == (45.0, -3.0, 0.10)
    end_y = s.validation[0, :, -1, 1]
    assert _binomial_ok(int(np.sum(np.abs(end_y - 3.5) < 0.1)), end_y.size, 0.9)
    vx_end = np.diff(s.validation[0, :, -2:, 0], axis=1)[:, 0] / (15 / 99)
    assert 4.5 < vx_end.mean() < 5.5


def test_json_overrides_are_honoured(tmp_path):
    f = tmp_path / "p.json"
    f.write_text(
        json.dumps(
            dict(
                n_samples=20,
                n_validation=30,
                x0_range=[50, 50],
                y0_choices=[0.0],
                intent_offsets=[0.0, -3.5],
                intent_probs=[0.5, 0.5],
                speed_mean=8.0,
                speed_var=0.0,
                ego_y_lb=-3.8,
                obstacle_speed=7.0,
            )
        )
    )
    params = load_scene_params(f)
    s = make_scene(0, params=params)
    assert s.obstacles.shape == (1, 20, 100, 2) and s.validation.shape == (1, 30, 100, 2)
    assert (s.x0, s.y0) == (50.0, 0.0)
    np.testing.assert_allclose(s.speed_setpoints, 8.0)
    np.testing.assert_allclose(s.intent_probs, [0.5, 0.5])
    assert set(np.round(s.obstacles[0, :, -1, 1], 1)) <= {0.0, -3.5}
    assert params.ego_y_lb == -3.8
    # the obstacle's initial speed is honoured
    v0 = (s.obstacles[0, :, 1, 0] - s.obstacles[0, :, 0, 0]) / (15 / 99)
    np.testing.assert_allclose(v0, 7.0, atol=0.2)
    # a preset as the base
    assert load_scene_params(f, base="reference36").layout == "grid"


@pytest.mark.parametrize(
    "payload, match",
    [
        ({"n_sample": 10}, "unknown scene parameter.*n_sample"),
        ({"n_samples": 0}, "n_samples"),
        ({"intent_probs": [0.5, 0.6]}, "sum to 1"),
        ({"intent_probs": [1.0]}, "intent_probs has 1"),
        ({"p_range": [0.3, 0.1]}, "p_range"),
        ({"speed_var": -1}, "speed_var"),
        ({"ego_y_lb": 1.0}, "ego"),
        ({"layout": "spiral"}, "layout"),
        ([1, 2], "JSON object"),
    ],
)
def test_bad_overrides_are_rejected(tmp_path, payload, match):
    f = tmp_path / "bad.json"
    f.write_text(json.dumps(payload))
    with pytest.raises(ValueError, match=match):
        load_scene_params(f)


def test_unreadable_params_file(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        load_scene_params(tmp_path / "missing.json")
    f = tmp_path / "broken.json"
    f.write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        load_scene_params(f)


def test_params_round_trip_through_dict():
    p = SceneParams(intent_probs=(0.3, 0.7), n_validation=10)
    assert SceneParams.from_dict(p.to_dict()) == p
    json.dumps(p.to_dict())


# ------------------------------------------------------------------ the journal version's families
@pytest.mark.parametrize("name", scenarios.JOURNAL_FAMILIES)
def test_journal_families_draw_distinct_starts_from_their_grids(name):
    params = scenarios.preset(name).replace(num_obstacles=3, n_samples=30, n_validation=60)
    s = make_scene(4, seed=11, params=params)
    assert s.obstacles.shape == (3, 30, 100, 2) and s.validation.shape == (3, 60, 100, 2)
    lay = s.layout
    assert len(set(lay.x0)) == 3 and set(lay.x0) <= set(params.x0_choices)
    assert set(lay.y0) <= {0.0, 3.5} and s.params.footprint == (4.25, 2.75)
    np.testing.assert_array_equal(make_scene(4, seed=11, params=params).validation, s.validation)
    if params.motion == "static":
        # standing still: every sample keeps its (noisy) start over the horizon
        np.testing.assert_array_equal(s.validation[:, :, 0], s.validation[:, :, -1])
        assert np.all(lay.speed == 0)
    else:
        assert len(set(lay.speed)) == 3 and set(lay.speed) <= set(params.obstacle_speed_choices)
        assert len(set(lay.p)) == 3 and set(lay.p) <= set(params.p_choices)
        # every future starts at its obstacle's start and ends in one of the two lanes
        np.testing.assert_allclose(s.validation[:, :, 0, 0], np.repeat(lay.x0[:, None], 60, 1))
        assert np.all(np.min(np.abs(s.validation[..., -1, 1, None] - [0.0, 3.5]), -1) < 0.05)


def test_static_noise_modes_and_dynamic_speed_modes_have_their_weights():
    bim = scenarios.preset("static-bimodal").replace(num_obstacles=1, n_validation=20000)
    s = make_scene(0, seed=2, params=bim)
    dx = s.validation[0, :, 0, 0] - s.layout.x0[0]
    # the modes are centred at −1 m (p = 0.8, std 0.5) and +1 m (p = 0.2, std 0.1)
    assert _binomial_ok(int(np.sum(dx > 0.5)), dx.size, 0.2)
    cut = scenarios.preset("cutin-low").replace(num_obstacles=1, n_validation=20000)
    s = make_scene(0, seed=2, params=cut)
    v = s.validation_speed_setpoints
    from scipy.stats import norm

    # P(|v − 7| < 0.4) under the three modes (0.4 / 0.2 / 0.4 at 5 / 7 / 3 m/s, std 1.5 / 0.1 / 3)
    p7 = sum(w * (norm.cdf((7.4 - m) / sd) - norm.cdf((6.6 - m) / sd))
             for w, m, sd in cut.speed_modes)  # fmt: skip
    assert _binomial_ok(int(np.sum(np.abs(v - 7.0) < 0.4)), v.size, p7)
    # the lane intent: the ego lane with the scene's p
    assert _binomial_ok(int(np.sum(s.validation_intents == 0)), v.size, s.p)


def test_a_family_forecast_draws_every_obstacle_from_the_scenes_model():
    import jax

    params = scenarios.preset("cutin-high").replace(num_obstacles=3, n_samples=20)
    s = make_scene(1, seed=3, params=params)
    fc = s.forecast()
    out = fc.predictor.sample(fc.history, fc.context, 400, jax.random.PRNGKey(0))
    assert out.shape == (3, 400, 100, 2)
    np.testing.assert_allclose(out[:, :, 0], s.validation[:, :400, 0], atol=1e-9)
    # intents as in the validation futures, from an independent stream
    assert not np.array_equal(out[:, :20], s.obstacles)
    ego_lane = np.abs(out[..., -1, 1]) < 0.05
    for o in range(3):
        assert _binomial_ok(int(ego_lane[o].sum()), 400, s.layout.p[o])


@pytest.mark.parametrize(
    "change, match",
    [
        ({"num_obstacles": 6}, "num_obstacles"),
        ({"num_obstacles": 3, "p_choices": [0.1, 0.2]}, "p_choices has 2 values"),
        ({"speed_modes": [[0.5, 5.0, 1.0], [0.4, 3.0, 1.0]]}, "sum to 1"),
        ({"position_modes": [[1.0, 0.0, 0.0, -1.0, 0.1]]}, "standard deviations"),
        ({"footprint": [4.0]}, "footprint"),
    ],
)
def test_bad_family_parameters_name_the_field(change, match):
    with pytest.raises(ValueError, match=match):
        scenarios.preset("cutin-low").update(change)
    with pytest.raises(ValueError, match="grid layout has one obstacle"):
        make_scene(0, params=scenarios.preset("reference36").replace(num_obstacles=2))
