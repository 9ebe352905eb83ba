"""Figures of the real-traffic benchmark: one scene on the real road geometry, plan time vs O."""

from __future__ import annotations

from pathlib import Path

import jax
import numpy as np

import mmdopt
from mmdopt.bench.plots import method_colour, method_label, pyplot
from mmdopt.padding import pad_obstacles

from .inputs import NgsimParams, ngsim_config
from .metric import rect_corners
from .runner import build_task, cached_predictor, task_config
from .scene import future_at

__all__ = ["ngsim_scene_figure", "timing_vs_obstacles_figure"]


def ngsim_scene_figure(
    task: dict,
    path: str | Path,
    methods=("mmd", "degroot"),
    predictor: str = "learned",
    params: NgsimParams | None = None,
    config=None,
    n_draw: int = 20,
) -> Path:
    """Cartesian figure of one task: lanelets (boundaries, grey), every obstacle's recorded
    future (black) and ``n_draw`` predictor samples each (light red), the ego's recorded future
    (dashed) and each method's plan with footprints at 0, 2.5 and 5 s."""
    plt = pyplot()
    p = NgsimParams() if params is None else params
    cfg = ngsim_config() if config is None else config
    b = build_task(task, p, cfg)
    cfg = task_config(b, p, cfg)
    sc, v, k, times = b["scene"], b["v"], b["k"], b["times"]
    key = jax.random.PRNGKey(p.seed)
    samples = cached_predictor(predictor).sample(b["hist"], b["ctx"], p.n_samples, key)
    m = p.max_obstacles
    planned = pad_obstacles(samples, m, b["ego"], b["road"], times, bucket=m)
    fig, ax = plt.subplots(figsize=(8, 8))
    _draw_lanelets(ax, task["scenario"], sc)
    for o in range(samples.shape[0]):
        for j in range(min(n_draw, samples.shape[1])):
            ax.plot(samples[o, j, :, 0], samples[o, j, :, 1], color="tab:red", alpha=0.12, lw=0.7)
    ax.plot(
        [],
        [],
        color="tab:red",
        alpha=0.4,
        label=f"{predictor} predictor samples ({n_draw}/obstacle)",
    )
    others = np.flatnonzero(np.arange(len(sc.ids)) != v)
    fut = future_at(sc, others, k, times)
    for o in range(len(others)):
        ok = np.all(np.isfinite(fut[o]), -1)
        if ok.sum() > 1:
            ax.plot(fut[o, ok, 0], fut[o, ok, 1], color="k", lw=1.0, zorder=3)
        if ok[0]:
            i = others[o]
            c = rect_corners(*fut[o, 0], sc.heading[i, k], sc.length[i], sc.width[i])
            ax.fill(c[:, 0], c[:, 1], color="0.3", alpha=0.6, zorder=3)
    ax.plot([], [], color="k", lw=1.0, label="recorded futures (other vehicles)")
    rec = future_at(sc, [v], k, times)[0]
    ax.plot(
        rec[:, 0],
        rec[:, 1],
        "--",
        color="tab:green",
        lw=1.6,
        label="recorded human (ego car)",
        zorder=6,
    )
    pts = [rec]
    for m in methods:
        pl = mmdopt.plan(b["ego"], b["road"], planned, method=m, config=cfg, key=key)
        col = method_colour(m) or "tab:blue"
        ax.plot(pl.x, pl.y, color=col, lw=2.2, label=f"plan: {method_label(m)}", zorder=5)
        pts.append(pl.xy)
        for t_mark in (0.0, 2.5, 5.0):
            j = int(np.argmin(np.abs(times - t_mark)))
            c = rect_corners(pl.x[j], pl.y[j], pl.heading[j], sc.length[v], sc.width[v])
            ax.fill(c[:, 0], c[:, 1], facecolor="none", edgecolor=col, lw=1.2, zorder=5)
    allp = np.concatenate(pts, 0)
    lo, hi = allp.min(0) - 25.0, allp.max(0) + 25.0
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(
        f"{sc.name}, ego {task['ego_id']} at t0 = {task['t0']} s, "
        f"horizon {cfg.trajectory.horizon:g} s"
    )
    ax.legend(loc="upper left", fontsize=8, framealpha=0.9).set_zorder(100)  # over the road
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path


def _draw_lanelets(ax, scenario_path, sc) -> None:
    """The scene's lanelet network drawn by commonroad-io's ``MPRenderer`` on ``ax`` (lanelet
    surfaces and boundaries, under everything else); the lanelet boundary polylines of the
    loaded scene where the renderer is unavailable."""
    try:
        from commonroad.common.file_reader import CommonRoadFileReader
        from commonroad.visualization.mp_renderer import MPRenderer

        scenario, _ = CommonRoadFileReader(str(scenario_path)).open()
        rnd = MPRenderer(ax=ax)
        scenario.lanelet_network.draw(rnd)
        rnd.render()
        for c in [*ax.collections, *ax.patches, *ax.lines]:
            c.set_zorder(0)  # the road under the traffic and the plans
        ax.plot([], [], color="0.3", lw=0.8, label="lanelets (commonroad-io MPRenderer)")
    except ImportError:
        for lane in sc.lanes.values():
            for side in (lane.left, lane.right):
                ax.plot(side[:, 0], side[:, 1], color="0.6", lw=0.8, zorder=1)
        ax.plot([], [], color="0.6", lw=0.8, label="lanelet boundaries")


def timing_vs_obstacles_figure(rows, path: str | Path) -> Path:
    """Median plan time (s) against the number of obstacles, from
    :func:`~mmdopt.bench.ngsim.runner.timing_vs_obstacles` rows."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for m in sorted({r["method"] for r in rows}):
        rr = sorted((r for r in rows if r["method"] == m), key=lambda r: r["n_obstacles"])
        ax.plot(
            [r["n_obstacles"] for r in rr],
            [r["median_s"] for r in rr],
            "o-",
            color=method_colour(m),
            label=method_label(m),
        )
    ax.axhline(1.0, color="0.5", ls=":", label="1 s")
    ax.set_xlabel("obstacles planned against")
    ax.set_ylabel("median plan time (s)")
    ax.legend()
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path
