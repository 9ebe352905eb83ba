"""The schedule's shared tools: counting the planning samples a plan meets."""

from __future__ import annotations

import jax
import numpy as np

from mmdopt.config import MMDOptConfig
from mmdopt.schedule import obstacle_centres, sample_geometry, samples_met


def test_counting_from_the_plans_centres_equals_counting_from_the_samples():
    """The final check counts the samples each candidate meets from the circle centres the plan
    computed once; that gives the same (C, O, n) answer, bit for bit, as counting from the
    samples and their headings (``mmdopt.collision_free_count``), for 1–5 plans (padded to the
    count bucket) on samples that pass through, beside and far from the plans."""
    rng = np.random.default_rng(11)
    K, n = 30, 400
    t = np.linspace(0.0, 5.0, K)
    ahead = [20 + rng.normal(0, 6, (n, 1)) + 5 * t, rng.normal(0, 2.5, (n, 1)) + 0 * t]
    oncoming = [60 - 4 * t + rng.normal(0, 3, (n, 1)), rng.normal(3.5, 1, (n, 1)) + 0 * t]
    obs = np.stack([np.stack(ahead, -1), np.stack(oncoming, -1)])
    heading = rng.normal(0, 0.1, obs.shape[:-1])
    cfg = MMDOptConfig()
    for C in (1, 3, 5):
        s = np.stack([(6 + c) * t for c in range(C)])
        d = np.stack([0.5 * c * np.ones(K) for c in range(C)])
        with jax.enable_x64(True):
            want = samples_met(cfg, obs, heading, s, d)
            got = samples_met(cfg, obs, heading, s, d, obstacle_centres(obs, heading))
        assert got.shape == want.shape == (C, 2, n) and got.dtype == bool
        assert 0 < want.sum() < want.size
        assert np.array_equal(got, want)


def test_counting_from_the_sample_geometry_equals_counting_from_the_centres():
    """The sample geometry (positions and heading unit vectors, formed once per plan, what the
    conflict depth with the rules of the road reads) forms the same circle centres as
    :func:`obstacle_centres`, and the count of every sample a plan meets (the fused float32
    count of ``mmdopt.counting``) equals counting from those centres, with headings given and
    with headings from each sample's motion."""
    rng = np.random.default_rng(5)
    K, n = 25, 300
    t = np.linspace(0.0, 5.0, K)
    xy = np.stack([15 + rng.normal(0, 5, (n, 1)) + 4 * t, rng.normal(0, 2.0, (n, 1)) + 0 * t], -1)
    obs = np.stack([xy, xy[::-1] + [5.0, 1.0]])
    cfg = MMDOptConfig()
    s = np.stack([(5 + c) * t for c in range(3)])
    d = np.stack([0.7 * c * np.ones(K) for c in range(3)])
    for heading in (None, rng.normal(0, 0.2, obs.shape[:-1])):
        with jax.enable_x64(True):
            want = samples_met(cfg, obs, heading, s, d, obstacle_centres(obs, heading))
            geo = sample_geometry(obs, heading)
            got = samples_met(cfg, obs, heading, s, d)
            np.testing.assert_array_equal(
                np.asarray(geo.centres()), np.asarray(obstacle_centres(obs, heading))
            )
        assert 0 < want.sum() < want.size
        assert np.array_equal(got, want)
