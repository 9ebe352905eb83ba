"""Where one CEM iteration of Algorithm 1 spends its time (demo scene, m = 20, float32).

Every stage is timed *inside* one jitted ``lax.scan`` over 20 stacked inputs, so the figures
carry no per-call dispatch cost.  The CEM state is a real one: the demo scene's plan after five
iterations.  Stages:

* ``project_rows``: planner + projection + residual, chunk by chunk (one chunk of
  ``n_cem + n_elite`` rows on this scene; inside ``run`` the elites' and brake rows' projections
  are reused and the chunk is ``n_elite + n_brake`` rows shorter: see the whole step);
* ``row costs``: cost of the rows a cached iteration of ``run`` scores
  (``n_cem − n_elite − n_brake``): trajectories, the ellipse values, the MMD term;
* ``ellipse + max over circles`` and ``mmd_cost from f``: the two halves of the collision term;
* ``whole step``: with the cost cache of ``run`` (elites and brake rows already scored), and
  without it (``update``).

    python benchmarks/cem_step_profile.py
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

import mmdopt
from mmdopt import algorithm as alg
from mmdopt import collision
from mmdopt.bench.scenes import demo_scene
from mmdopt.bench.synthetic import scene_config

R = 20


def in_graph_ms(f, xs, repeats: int = 40) -> float:
    """Median time of ``f`` per input inside one jitted scan over ``R`` stacked inputs (ms)."""
    g = jax.jit(lambda xs: lax.scan(lambda c, x: (c, f(x)), 0, xs)[1])
    jax.block_until_ready(g(xs))
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(g(xs))
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts)) / R * 1e3


def main(argv=None) -> None:
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args(argv)
    sc = demo_scene()
    cfg = scene_config(sc)
    p = mmdopt.plan(sc.ego(), sc.road(), sc.obstacles, config=cfg, key=jax.random.PRNGKey(0))
    rs = p.reduced_set
    obs = np.asarray(sc.obstacles, np.float64)
    sel = np.take_along_axis(obs, np.asarray(rs.indices)[:, :, None, None], axis=1)
    centres = collision.circle_centres(jnp.asarray(sel), collision.OBSTACLE_FOOTPRINT)
    obstacles = alg.ObstacleSet.create(cfg, centres, np.asarray(rs.weights, np.float64), "mmd")
    dt = jnp.float32
    problem = alg.Problem.create(cfg, sc.ego(), sc.road().bounds())
    planner = mmdopt.Planner(cfg)
    prob = planner.workspace(problem.bounds)
    st = planner.init(problem, jax.random.PRNGKey(0))
    for _ in range(5):
        st = planner.update(problem, st, obstacles)
    ego = problem.state
    ds = jnp.stack([alg._sample(cfg, k, st.mu, st.cov, st.elites, problem) for k in st.keys])
    out = {}
    out["project_rows"] = in_graph_ms(lambda d: alg.project_rows(cfg, prob, d, ego, dt)[2], ds)
    cx, cy, _, n_proj = alg.project_rows(cfg, prob, ds[0], ego, dt)
    nc = cfg.cem.n_elite + cfg.cem.n_brake
    E = alg.cost_chunk_size(cfg)
    cxc = jnp.stack([cx[nc : nc + E]] * R)
    cyc = jnp.stack([cy[nc : nc + E]] * R)
    rc = jnp.zeros((R, E), dt)
    out[f"row costs ({E} rows)"] = in_graph_ms(
        lambda c: alg._row_costs(cfg, prob, obstacles, c[0], c[1], c[2])[0], (cxc, cyc, rc)
    )
    P = jnp.asarray(prob.P, dt)
    a_plan = alg.planning_semi_axis(cfg, prob.t(), dt, 1.0)
    cen = obstacles.centres.astype(dt)
    b = cfg.safety.footprint.b + cfg.safety.margins.margin_lat

    def ell(c):
        f = collision.ellipse_values(c[0] @ P.T, c[1] @ P.T, cen, a_plan, b)
        return jnp.max(f, axis=3)

    out[f"ellipse + max over circles ({E} rows)"] = in_graph_ms(ell, (cxc, cyc))
    f0 = collision.ellipse_values(cxc[0] @ P.T, cyc[0] @ P.T, cen, a_plan, b)
    w = obstacles.weights.astype(dt)
    out[f"mmd_cost from f ({E} rows)"] = in_graph_ms(
        lambda f: collision.mmd_cost(f, w, cfg.cost.bandwidth, cfg.cost.f_scale, obstacles.n_terms),
        jnp.stack([f0] * R),
    )
    # the cache of run after one iteration: elites and brake rows scored and projected
    pcfg = cfg.program()
    _, cache = alg._step(
        prob, pcfg, problem, st, obstacles, None, alg._empty_cache(cfg, prob.nvar, dt)
    )

    def with_keys(k):
        return st._replace(keys=jnp.stack([k] * cfg.cem.iterations))

    out["whole step, cost cache (run)"] = in_graph_ms(
        lambda k: alg._step(prob, pcfg, problem, with_keys(k), obstacles, None, cache)[0].mu,
        st.keys,
    )
    out["whole step, no cache (update)"] = in_graph_ms(
        lambda k: alg._step(prob, pcfg, problem, with_keys(k), obstacles).mu, st.keys
    )
    active = jnp.mean(jnp.max(f0, axis=(2, 3)) > 0)
    print(
        f"# demo scene, m = {cfg.selection.reduced_set_size}, iteration 5: "
        f"{int(n_proj)} rows projected, "
        f"{float(active):.1%} of the (row, step) points active; jax {jax.__version__}, "
        f"{jax.devices()[0].platform}"
    )
    for k, v in out.items():
        print(f"  {k:40s} {v:6.2f} ms")


if __name__ == "__main__":
    main()
